"""LTL over the finite horizon → mixed-integer linear constraints ([7] Wolff, [18] Kurtz & Lin).

The formula is put in negation normal form (``transform.nnf``, which also writes ``<->``, ``xor``,
``W`` and ``M`` with the operators below), then each subformula φ at step k gets a truth value
z_φ(k) that may only be 1 if φ holds, which is all that is needed with the root fixed to 1:

* atoms are the model's binaries themselves — a *decision* atom (η) is exact, so ``¬η`` is
  ``1 − η``; a *geometric* atom (θ, "x ∈ H") is linked one-sidedly (θ = 1 → x ∈ H, eq. 7) and is
  sound only in positive position, so a negated geometric atom is rejected;
* ∧ and ∨ get a continuous z ∈ [0, 1]: ``z ≤ z_i`` and ``z ≤ Σ z_i``;
* temporal operators are unrolled over k = 0..T with the LTLf recursions
  ``G a = a ∧ WX G a``, ``F a = a ∨ X F a``, ``a U b = b ∨ (a ∧ X(a U b))``,
  ``a R b = b ∧ (a ∨ WX(a R b))``; ``X a`` is false at T, ``WX a`` true at T.

Subformulas that must hold (below the root through ∧, G, WX, R's right side) are required
directly, without a truth variable. Identical subformulas at the same step share one variable.
All rows go to the program as one sparse block.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydrake.solvers import MathematicalProgram

from dualarm_mpc.logic.ltl import (
    Always,
    And,
    Atom,
    Const,
    Eventually,
    Formula,
    Next,
    Not,
    Or,
    Release,
    Until,
    WeakNext,
)
from dualarm_mpc.logic.transform import nnf
from dualarm_mpc.milp.linear import Rows, bound, new_variables
from dualarm_mpc.milp.solver import StandardForm


class EncodingError(ValueError):
    """A formula that cannot be encoded soundly (e.g. a negated geometric atom)."""


@dataclass(frozen=True)
class Literal:
    """The truth of an atom at one step: the program variable ``index``, or a constant when
    ``index`` is -1 (an atom fixed by the scenario, e.g. an object outside this step)."""

    index: int
    geometric: bool = False
    constant: bool = False


# The truth value of (subformula, step) as an affine form  const + coef · x[index].
Affine = tuple[float, float, int]
ONE: Affine = (1.0, 0.0, -1)
ZERO: Affine = (0.0, 0.0, -1)

AtomResolver = Callable[[Atom, int], Literal]


class Encoder:
    """Encodes formulas on one horizon of one program; atoms resolved by ``resolve(atom, k)``."""

    def __init__(self, prog: MathematicalProgram, horizon: int, resolve: AtomResolver) -> None:
        self.prog = prog
        self.T = horizon
        self.resolve = resolve
        self.rows = Rows()
        self._truth: dict[tuple[Formula, int], Affine] = {}
        # New variables are numbered after the program's and created by emit() at once (or
        # never: standard_form() reads the rows without touching the program).
        self._first = prog.num_vars()
        self._z: list[int] = []  # truth variables of ∧/∨ nodes, bounded to [0, 1]
        self._false: list[int] = []  # variables of requirements that cannot hold
        self._source = ""

    # -- public -------------------------------------------------------------------------------

    def require(self, formula: Formula, k: int = 0) -> None:
        """Constrain ``formula`` to hold at step ``k`` (root fixed to 1)."""
        self._source = str(formula)
        self._require(nnf(formula), k)

    def truth(self, formula: Formula, k: int = 0) -> Affine:
        """An affine truth value that can be 1 only if ``formula`` holds at ``k``."""
        self._source = str(formula)
        return self._value(nnf(formula), k)

    def require_at_least(self, m: int, formulas: list[Formula], k: int = 0) -> None:
        """Σ_j z_{φ_j}(k) ≥ m: the counting form of φ_task (eq. 13)."""
        terms = [self.truth(f, k) for f in formulas]
        self._row(terms, lb=m)

    def emit(self, description: str = "LTL") -> int:
        """Add the new variables and all rows to the program; returns the number of rows."""
        new_variables(self.prog, (self._new,), "ltl")
        bound(self.prog, np.asarray(self._z, int), 0.0, 1.0)
        self.rows.emit(self.prog, description)
        return self.rows.count

    def standard_form(self) -> StandardForm:
        """The rows over the program's variables and the new ones, as a standard form whose
        first columns are the program's (``StandardForm.extended`` adds it to the model's);
        the program itself is left as it was."""
        n = self._first + self._new
        A, lb, ub = self.rows.matrix(n)
        col_lb, col_ub = np.full(n, -np.inf), np.full(n, np.inf)
        col_lb[self._z], col_ub[self._z] = 0.0, 1.0
        return StandardForm(np.zeros(n), 0.0, A, lb, ub, col_lb, col_ub, np.zeros(n, bool))

    @property
    def _new(self) -> int:
        return len(self._z) + len(self._false)

    def _variable(self) -> int:
        return self._first + self._new

    # -- internals ----------------------------------------------------------------------------

    def _row(self, terms: list[Affine], lb: float = -np.inf, ub: float = np.inf,
             signs: list[float] | None = None) -> None:
        """Add ``lb ≤ Σ sign·term ≤ ub`` for affine terms."""
        signs = signs or [1.0] * len(terms)
        const = sum(s * t[0] for s, t in zip(signs, terms, strict=True))
        pairs = [(s * t[1], t[2]) for s, t in zip(signs, terms, strict=True) if t[2] >= 0]
        if not pairs:
            if not lb - 1e-9 <= const <= ub + 1e-9:
                self._infeasible()
            return
        self.rows.add_row(pairs, lb - const, ub - const)

    def _infeasible(self) -> None:
        # A requirement that is false whatever the plan: keep the program honest (infeasible).
        z = self._variable()
        self._false.append(z)
        self.rows.add_row([(1.0, z)], 1.0, 0.0)

    def _atom(self, atom: Atom, k: int, negated: bool) -> Affine:
        lit = self.resolve(atom, k)
        if lit.geometric and negated:
            raise EncodingError(
                f"{atom} appears negated in {self._source!r}: a geometric atom is linked to the "
                "state one-sidedly (eq. 7: θ = 1 → x ∈ H), so its negation cannot be encoded "
                "soundly; state the rule with the atom in positive position"
            )
        if lit.index < 0:
            value = float(lit.constant != negated)
            return (value, 0.0, -1)
        return (1.0, -1.0, lit.index) if negated else (0.0, 1.0, lit.index)

    def _require(self, f: Formula, k: int) -> None:
        T = self.T
        if isinstance(f, Const):
            if not f.value:
                self._infeasible()
        elif isinstance(f, And):
            for a in f.args:
                self._require(a, k)
        elif isinstance(f, Always):
            for t in range(k, T + 1):
                self._require(f.arg, t)
        elif isinstance(f, WeakNext):
            if k < T:
                self._require(f.arg, k + 1)
        elif isinstance(f, Next):
            if k < T:
                self._require(f.arg, k + 1)
            else:
                self._infeasible()
        elif isinstance(f, Release) and k == T:
            self._require(f.rhs, k)
        elif isinstance(f, Release):
            self._require(f.rhs, k)
            self._row([self._value(f.lhs, k), self._value(f, k + 1)], lb=1)
        elif isinstance(f, Or):
            self._row([self._value(a, k) for a in f.args], lb=1)
        elif isinstance(f, Eventually):
            self._row([self._value(f.arg, t) for t in range(k, T + 1)], lb=1)
        else:  # atoms, U: a truth value that must be 1
            self._row([self._value(f, k)], lb=1)

    def _value(self, f: Formula, k: int) -> Affine:
        key = (f, k)
        if key in self._truth:
            return self._truth[key]
        T = self.T
        if isinstance(f, Always | Eventually | Until | Release) and k < T and \
                (f, k + 1) not in self._truth:
            # the recursions reach k + 1 first: take the suffix from T back, so that the Python
            # stack is not T deep (solver.max_horizon allows 1000)
            for t in range(T, k, -1):
                self._value(f, t)
        if isinstance(f, Const):
            v = ONE if f.value else ZERO
        elif isinstance(f, Atom):
            v = self._atom(f, k, negated=False)
        elif isinstance(f, Not):
            if not isinstance(f.arg, Atom):
                raise EncodingError(f"not in negation normal form: {f}")
            v = self._atom(f.arg, k, negated=True)
        elif isinstance(f, Next | WeakNext) and k == T:
            v = ZERO if isinstance(f, Next) else ONE
        elif isinstance(f, Next | WeakNext):
            v = self._value(f.arg, k + 1)
        elif isinstance(f, And):
            v = self._and([self._value(a, k) for a in f.args])
        elif isinstance(f, Or):
            v = self._or([self._value(a, k) for a in f.args])
        elif isinstance(f, Always):
            now = self._value(f.arg, k)
            v = now if k == T else self._and([now, self._value(f, k + 1)])
        elif isinstance(f, Eventually):
            now = self._value(f.arg, k)
            v = now if k == T else self._or([now, self._value(f, k + 1)])
        elif isinstance(f, Until):
            now = self._value(f.rhs, k)
            if k < T:
                v = self._or([now, self._and([self._value(f.lhs, k), self._value(f, k + 1)])])
            else:
                v = now
        elif isinstance(f, Release):
            now = self._value(f.rhs, k)
            if k < T:
                v = self._and([now, self._or([self._value(f.lhs, k), self._value(f, k + 1)])])
            else:
                v = now
        else:
            raise EncodingError(f"cannot encode {type(f).__name__}: {f}")
        self._truth[key] = v
        return v

    def _new_truth(self) -> int:
        z = self._variable()
        self._z.append(z)
        return z

    def _and(self, terms: list[Affine]) -> Affine:
        if any(t == ZERO for t in terms):
            return ZERO
        terms = [t for t in terms if t != ONE]
        if not terms:
            return ONE
        if len(terms) == 1:
            return terms[0]
        z = self._new_truth()
        for t in terms:  # z ≤ t
            self.rows.add_row([(1.0, z), (-t[1], t[2])], ub=t[0])
        return (0.0, 1.0, z)

    def _or(self, terms: list[Affine]) -> Affine:
        if any(t == ONE for t in terms):
            return ONE
        terms = [t for t in terms if t != ZERO]
        if not terms:
            return ZERO
        if len(terms) == 1:
            return terms[0]
        z = self._new_truth()
        const = sum(t[0] for t in terms)  # z ≤ Σ t
        self.rows.add_row([(1.0, z)] + [(-t[1], t[2]) for t in terms], ub=const)
        return (0.0, 1.0, z)
