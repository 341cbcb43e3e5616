"""Direct evaluation of an LTLf formula on a finite trace: the independent oracle for every plan.

Every node type, Not, Implies, Equiv, Xor, WeakUntil and StrongRelease included, is evaluated
straight from its semantics on steps k = 0..T (T = horizon). Nothing here is shared with the
encoders, and no rewriting (such as NNF) happens first, so agreement between a plan and this module
is evidence, not an identity.

Semantics at step k, with T the last step::

    X a     k < T and a(k+1)                  WX a    k == T or a(k+1)
    G a     a(t) for all t in k..T            F a     a(t) for some t in k..T
    a U b   some t in k..T: b(t) and a(s) for all s in k..t-1
    a R b   all t in k..T: b(t) or a(s) for some s in k..t-1
    a W b   a U b, or a(t) for all t in k..T
    a M b   some t in k..T: a(t) and b(t) and b(s) for all s in k..t-1
    a <-> b a(k) == b(k)                      a xor b a(k) != b(k)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from dualarm_mpc.logic.ltl import (
    Always,
    And,
    Atom,
    Const,
    Equiv,
    Eventually,
    Formula,
    Implies,
    Next,
    Not,
    Or,
    Release,
    StrongRelease,
    Until,
    WeakNext,
    WeakUntil,
    Xor,
)

__all__ = ["Trace", "evaluate", "truth_table"]

Trace = Mapping[Atom, Sequence[bool]] | Callable[[Atom, int], bool]
"""Atom values per step: a mapping atom -> values for k = 0..T, or a function (atom, k) -> bool."""


def evaluate(formula: Formula, trace: Trace, horizon: int, k: int = 0) -> bool:
    """Truth of ``formula`` at step ``k`` of ``trace`` over steps 0..horizon."""
    _check_horizon(horizon)
    if not 0 <= k <= horizon:
        raise ValueError(f"step k={k} outside 0..{horizon}")
    return truth_table(formula, trace, horizon)[k]


def truth_table(formula: Formula, trace: Trace, horizon: int) -> list[bool]:
    """Truth of ``formula`` at each step k = 0..horizon.

    Each distinct subformula's truth vector is computed once (memoized on the node).
    Raises KeyError for an atom missing from a mapping trace, ValueError for a placeholder atom,
    a negative horizon, or a mapping entry shorter than horizon + 1.
    """
    _check_horizon(horizon)
    return list(_Evaluator(trace, horizon).vector(formula))


def _check_horizon(horizon: int) -> None:
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 0:
        raise ValueError(f"horizon must be an int >= 0, got {horizon!r}")


class _Evaluator:
    def __init__(self, trace: Trace, horizon: int) -> None:
        self.trace = trace
        self.T = horizon
        self.memo: dict[Formula, tuple[bool, ...]] = {}

    def vector(self, f: Formula) -> tuple[bool, ...]:
        v = self.memo.get(f)
        if v is None:
            v = self.memo[f] = self._compute(f)
        return v

    def _atom(self, atom: Atom) -> tuple[bool, ...]:
        if any(isinstance(e, str) for e in atom.index):
            raise ValueError(f"atom {atom} has unsubstituted placeholders; substitute first")
        steps = range(self.T + 1)
        if isinstance(self.trace, Mapping):
            if atom not in self.trace:
                raise KeyError(f"atom {atom} is not in the trace")
            values = self.trace[atom]
            if len(values) < self.T + 1:
                raise ValueError(
                    f"trace of {atom} has {len(values)} values, need {self.T + 1} (k = 0..{self.T})"
                )
            return tuple(bool(values[k]) for k in steps)
        return tuple(bool(self.trace(atom, k)) for k in steps)

    def _compute(self, f: Formula) -> tuple[bool, ...]:
        T = self.T
        steps = range(T + 1)
        match f:
            case Const(value):
                return (value,) * (T + 1)
            case Atom():
                return self._atom(f)
            case Not(arg):
                a = self.vector(arg)
                return tuple(not a[k] for k in steps)
            case And(args):
                vs = [self.vector(x) for x in args]
                return tuple(all(v[k] for v in vs) for k in steps)
            case Or(args):
                vs = [self.vector(x) for x in args]
                return tuple(any(v[k] for v in vs) for k in steps)
            case Implies(lhs, rhs):
                a, b = self.vector(lhs), self.vector(rhs)
                return tuple((not a[k]) or b[k] for k in steps)
            case Equiv(lhs, rhs):
                a, b = self.vector(lhs), self.vector(rhs)
                return tuple(a[k] == b[k] for k in steps)
            case Xor(lhs, rhs):
                a, b = self.vector(lhs), self.vector(rhs)
                return tuple(a[k] != b[k] for k in steps)
            case Next(arg):
                a = self.vector(arg)
                return tuple(k < T and a[k + 1] for k in steps)
            case WeakNext(arg):
                a = self.vector(arg)
                return tuple(k == T or a[k + 1] for k in steps)
            case Always(arg):
                a = self.vector(arg)
                return tuple(all(a[t] for t in range(k, T + 1)) for k in steps)
            case Eventually(arg):
                a = self.vector(arg)
                return tuple(any(a[t] for t in range(k, T + 1)) for k in steps)
            case Until(lhs, rhs):
                a, b = self.vector(lhs), self.vector(rhs)
                return tuple(
                    any(b[t] and all(a[s] for s in range(k, t)) for t in range(k, T + 1))
                    for k in steps
                )
            case Release(lhs, rhs):
                a, b = self.vector(lhs), self.vector(rhs)
                return tuple(
                    all(b[t] or any(a[s] for s in range(k, t)) for t in range(k, T + 1))
                    for k in steps
                )
            case WeakUntil(lhs, rhs):
                a, b = self.vector(lhs), self.vector(rhs)
                return tuple(
                    any(b[t] and all(a[s] for s in range(k, t)) for t in range(k, T + 1))
                    or all(a[t] for t in range(k, T + 1))
                    for k in steps
                )
            case StrongRelease(lhs, rhs):
                a, b = self.vector(lhs), self.vector(rhs)
                return tuple(
                    any(a[t] and b[t] and all(b[s] for s in range(k, t)) for t in range(k, T + 1))
                    for k in steps
                )
        raise TypeError(f"not a Formula: {f!r}")
