"""CP-SAT as a second prover: a sound integer relaxation of a horizon's MILP.

HiGHS proves that a horizon has no plan by enumeration under an LP bound of zero
(docs/search.md, "Why not one MILP"), and on the hard horizons of (3,·) under rule 2 it runs out
of time. OR-Tools' CP-SAT learns clauses from its conflicts instead, and decides some of those
horizons in seconds; but it takes integers only. :class:`Relaxation` turns the standard form of
a horizon's program (``solver.StandardForm``: the MLD model, eqs. 1, 7–11, 14–16, pruning, and
the LTL rows of φ_task (13) and the rules) into an integer program that holds the image of every
point of the MILP, so that **the relaxation infeasible proves the MILP infeasible**: the horizon
has no plan. Its feasible points decide nothing: they need not be plans.

The relaxation, column by column (x_j ∈ [l_j, u_j]):

* a *fixed* column (l_j = u_j) is a constant;
* an *integer* column (η, θ) is itself, above its lower bound: y_j = x_j − l_j ∈ [0, u_j − l_j];
* a *truth* column (an LTL truth value z ∈ [0, 1] of ``encoding.py``) is a Boolean, mapped by
  z ↦ ⌈z⌉ (below);
* any other *continuous* column (positions, velocities, forces u and |u|) is an integer count of
  units s_j, a power of two with at least ``RESOLUTION`` units over [l_j, u_j] (8 µm on 1.2 m of
  hand range): y_j = round((x_j − l_j)/s_j) ∈ [0, N_j], N_j = ⌈(u_j − l_j)/s_j⌉, so
  x_j = l_j + s_j·y_j + e_j with |e_j| ≤ s_j/2.

Each row L ≤ Σ_j a_j·x_j ≤ U becomes, with the constants moved to its bounds (L', U'),

    L' − W ≤ Σ_j a_j·s_j·y_j ≤ U' + W,    W = Σ_continuous |a_j|·s_j/2 + TOL·(1 + Σ_j |a_j|),

the rounding error of its columns (TOL also lets in the points HiGHS accepts, which keep each
row and each integrality within its feasibility tolerance, 1e-6 at most); and, multiplied by a
power of two K and its coefficients rounded to integers b_j = round(K·a_j·s_j) with
δ_j = b_j − K·a_j·s_j,

    ⌈K·(L' − W) + Σ_j min(0, δ_j·N_j)⌉ ≤ Σ_j b_j·y_j ≤ ⌊K·(U' + W) + Σ_j max(0, δ_j·N_j)⌋,

since Σ_j δ_j·y_j lies between those sums for y_j ∈ [0, N_j], and an integer sum meets a real
bound exactly when it meets its ceiling or floor. K is the least power of two that keeps the
coefficients' error Σ|δ_j|·N_j/K within ``COEFFICIENT_SHARE`` of W, and no larger than keeps
Σ_j |b_j|·N_j within ``MAGNITUDE`` (exact in doubles, far inside CP-SAT's 64 bits); the bounds
are computed with a margin for the doubles' own rounding. A row of integer and truth columns
only, with integer coefficients and integer bounds, is kept as it is (W = 0): its sum is an
integer.

*Truth columns as Booleans.* ``encoding.py`` gives ∧ and ∨ a continuous z ∈ [0, 1] that may be
1 only if its subformula holds: rows z_p − Σ_c z_c − (η, θ terms) ≤ b and requirement rows
Σ_c z_c + (η, θ terms) ≥ b, integer coefficients and bounds. Map every truth column by z ↦ ⌈z⌉
and keep the integer columns. In a row Σ_c b_c·z_c − z_p + I ≥ L (I the integer part, L an
integer, b_c ≥ 1 integers, at most one truth column z_p with a negative coefficient, −1): if
z_p = 0 the left side only grows; if z_p > 0, then Σ_c b_c·z_c + I > L, so the integer
Σ_c b_c·⌈z_c⌉ + I ≥ Σ_c b_c·z_c + I is at least L + 1 = L + ⌈z_p⌉. Rows bounded above are the
same with the signs turned. So a column is taken as a Boolean only if every row it is in has
only integer and truth columns, integer coefficients and bounds, and at most one truth column
on the side that the ceiling could break, with coefficient 1 (checked here, to a fixed point:
a column that fails is a continuous column, which may fail its rows' other truth columns).

So every point of the MILP maps, column by column, to a point of the relaxation: if CP-SAT
proves the relaxation infeasible, the MILP is. CP-SAT runs on one worker with a fixed seed
(:meth:`Relaxation.solve`); :class:`Prover` runs it beside the skeleton search, on the horizons
the search has not decided (``sequential.py``).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from dualarm_mpc.milp.solver import Interrupt, SolveOptions, SolverUnavailable, StandardForm, Status
from dualarm_mpc.model.scenario import ortools_installed

RESOLUTION = 2**17  # units over a continuous column's range, at least
TOL = 1e-6  # a row's widening for the points solvers accept (their feasibility tolerance)
COEFFICIENT_SHARE = 1 / 64  # a row's coefficient rounding error, at most this share of W
MAGNITUDE = 2.0**52  # Σ_j |b_j|·N_j at most
SEED = 0  # CP-SAT's random seed: the same answer on every run


def require() -> None:
    """Raise :class:`~dualarm_mpc.milp.solver.SolverUnavailable` (one line) unless OR-Tools is
    installed."""
    if not ortools_installed():
        raise SolverUnavailable("the CP-SAT prover needs OR-Tools, which is not installed here "
                                "(pip install 'dualarm_mpc[ortools]', or solver.prover: none)")


@dataclass(frozen=True)
class Proof:
    """What CP-SAT said of a relaxation: INFEASIBLE (a proof that the MILP is), FEASIBLE (the
    relaxation has a point, which need not be a plan: nothing proven) or TIME_LIMIT."""

    status: Status
    wall_time_s: float
    message: str = ""
    binaries: int = 0  # the MILP's integer columns


class Relaxation:
    """The integer relaxation of a standard form (module docstring): a CP-SAT model whose
    variable j counts column j's units above its lower bound (a fixed column's is fixed at 0)."""

    def __init__(self, f: StandardForm) -> None:
        require()
        from ortools.sat.python import cp_model

        A = sp.csr_matrix(f.A)
        row_lb, row_ub = f.row_lb, f.row_ub
        A.eliminate_zeros()
        A.sum_duplicates()
        self.binaries = int(np.count_nonzero(f.integer))
        self.model = cp_model.CpModel()
        self.empty = _empty(f, A, row_lb, row_ub)
        lo = np.where(f.integer, np.ceil(f.col_lb - TOL), f.col_lb)
        # a continuous column's bounds crossed by their rounding (within TOL: _empty) fix it
        hi = np.where(f.integer, np.floor(f.col_ub + TOL), np.maximum(f.col_ub, f.col_lb))
        if not self.empty and np.any(hi < lo):
            self.empty = "an integer column has no integer within its bounds"
        if self.empty:  # no point at all: nothing to relax
            return
        fixed = hi == lo
        free = ~fixed & ~(np.isfinite(lo) & np.isfinite(hi))
        if free.any():
            raise ValueError(f"the CP-SAT relaxation needs every column bounded; column "
                             f"{int(np.flatnonzero(free)[0])} is not")
        self.fixed = fixed
        self.truth = _truth_columns(A, row_lb, row_ub, lo, hi, f.integer, fixed)
        self.continuous = ~fixed & ~f.integer & ~self.truth
        self.offset = lo
        self.unit = np.ones(len(lo))
        span = hi[self.continuous] - lo[self.continuous]
        self.unit[self.continuous] = 2.0 ** np.floor(np.log2(span / RESOLUTION))
        self.count = np.ceil((hi - lo) / self.unit)
        proto = self.model.proto
        for n in self.count.astype(np.int64).tolist():
            proto.variables.add().domain.extend([0, n])
        B, low, high = self._rows(A, row_lb, row_ub)
        ptr, cols, coefs = B.indptr.tolist(), B.indices.tolist(), B.data.tolist()
        for r, (a, b) in enumerate(itertools.pairwise(ptr)):
            c = proto.constraints.add().linear
            c.vars.extend(cols[a:b])
            c.coeffs.extend(coefs[a:b])
            c.domain.extend([low[r], high[r]])

    def _rows(self, A: sp.csr_matrix, L: np.ndarray, U: np.ndarray):
        """The rows L ≤ A·x ≤ U over the units (module docstring), all at once: their integer
        coefficients (a sparse matrix over the variables) and integer bounds, without the rows
        that every point of the variables' domains meets."""
        shift = A @ self.offset  # the constants and the offsets
        L, U = L - shift, U - shift
        weight = abs(A) @ np.ones(A.shape[1])
        row, col, a, per_row = _entries(A, self.fixed)
        g = a * self.unit[col]  # per unit
        N = self.count[col]
        m = A.shape[0]
        continuous = self.continuous[col]
        exact = (per_row(continuous) == 0) & (per_row(g != np.round(g)) == 0) & \
            _integral(L) & _integral(U)
        W = np.where(exact, 0.0, per_row(np.abs(g) * continuous) / 2 + TOL * (1 + weight))
        largest = np.zeros(m)
        np.maximum.at(largest, row, np.abs(g))
        e = np.zeros(m)
        # the largest coefficient about 1 (within what doubles hold: a tiny one rounds to 0,
        # its whole term then in the error)
        e[largest > 0] = np.clip(np.ceil(-np.log2(largest[largest > 0])), -600, 600)
        e[exact] = 0
        while True:
            K = 2.0 ** e
            Kg = K[row] * g
            error = per_row(np.abs(np.round(Kg) - Kg) * N) / K
            finer = ~exact & (error > COEFFICIENT_SHARE * W) & \
                (per_row(np.abs(np.round(2 * Kg)) * N) <= MAGNITUDE)
            if not finer.any():
                break
            e[finer] += 1
        b = np.round(Kg)
        delta = (b - Kg) * N
        reach = per_row(np.abs(b) * N)  # each row's sum lies in [−reach, reach]
        if reach.max(initial=0) > 2.0**62:
            raise ValueError("a row's coefficients span too many magnitudes for CP-SAT")
        bounds = np.abs(np.where(np.isfinite(L), L, 0)) + np.abs(np.where(np.isfinite(U), U, 0))
        # the doubles' own rounding in K·(L' − W) and in the shift: far below one unit
        margin = np.where(exact, 0.0, 1e-9 * K * (np.abs(shift) + W + bounds))
        with np.errstate(invalid="ignore"):
            low = np.ceil(K * (L - W) + per_row(np.minimum(delta, 0)) - margin)
            high = np.floor(K * (U + W) + per_row(np.maximum(delta, 0)) + margin)
        # beyond ±reach, a side every point meets, or none (one past it)
        low = np.clip(low, -reach, reach + 1)
        high = np.clip(high, -reach - 1, reach)
        keep = (largest > 0) & ((low > -reach) | (high < reach))
        B = sp.csr_matrix((b, (row, col)), shape=(m, A.shape[1]))[keep]
        B.eliminate_zeros()
        B.data = B.data.astype(np.int64)
        return B, low[keep].astype(np.int64).tolist(), high[keep].astype(np.int64).tolist()

    def point(self, x: np.ndarray) -> tuple[list[int], list[int]]:
        """The image of a point ``x`` of the MILP (a plan's solver values): the variables of
        the continuous and integer columns and their values; the truth columns are left out
        (their image, ⌈z⌉, is exact only for exact points)."""
        keep = np.flatnonzero(~self.fixed & ~self.truth)
        y = np.round((x[keep] - self.offset[keep]) / self.unit[keep])
        return keep.tolist(), np.clip(y, 0, self.count[keep]).astype(np.int64).tolist()

    def solve(self, options: SolveOptions, at: np.ndarray | None = None) -> Proof:
        """CP-SAT on the relaxation, on one worker with a fixed seed, within
        ``options.time_limit_s``, stopped by ``options.interrupt``; with ``at``, at the image
        of that point (:meth:`point`), whose truth columns CP-SAT completes."""
        from ortools.sat.python import cp_model

        t0 = time.perf_counter()
        if self.empty:
            return Proof(Status.INFEASIBLE, 0.0, f"CP-SAT relaxation: {self.empty}", self.binaries)
        model = self.model
        if at is not None:
            model = model.clone()
            for j, v in zip(*self.point(at), strict=True):
                domain = model.proto.variables[j].domain
                domain[0] = domain[1] = v
        solver = cp_model.CpSolver()
        solver.parameters.num_workers = 1
        solver.parameters.random_seed = SEED
        solver.parameters.max_time_in_seconds = float(options.time_limit_s)
        stop = options.interrupt
        if stop is not None and stop.is_set():
            return Proof(Status.TIME_LIMIT, 0.0, "CP-SAT not started: asked to stop",
                         self.binaries)
        if stop is None:
            status = solver.solve(model)
        else:
            with stop.watch(solver.stop_search):
                status = solver.solve(model)
        ours = {cp_model.INFEASIBLE: Status.INFEASIBLE, cp_model.FEASIBLE: Status.FEASIBLE,
                cp_model.OPTIMAL: Status.FEASIBLE, cp_model.UNKNOWN: Status.TIME_LIMIT}
        if status not in ours:
            raise RuntimeError(f"CP-SAT refused the relaxation: {solver.status_name(status)} "
                               f"({model.validate()})")
        return Proof(ours[status], time.perf_counter() - t0,
                     f"CP-SAT {solver.status_name(status)}, {solver.num_conflicts} conflicts, "
                     f"{solver.num_branches} branches", self.binaries)


class Prover:
    """CP-SAT beside the skeleton search, on a thread of its own (``sequential.py``): it tries
    to prove the horizons it is asked about infeasible (their programs ``form(T)``), each for a
    slice of time that grows fourfold every time it comes back to it (the least tried first, as
    the search's rounds), until :meth:`close`; :meth:`proofs` are those of the horizons proven
    to have no plan so far. The search of a horizon proven meanwhile is stopped
    (:meth:`searching`)."""

    def __init__(self, form: Callable[[int], StandardForm], options: SolveOptions,
                 first_slice_s: float = 1.0) -> None:
        require()  # here, not on its thread
        self._form, self._options = form, options
        self._first_slice = first_slice_s
        self._proven: dict[int, Proof] = {}
        self._asked: list[int] = []
        self._slice: dict[int, float] = {}
        self._searched: tuple[int, Interrupt] | None = None
        self._stop = Interrupt()
        self._wake = threading.Condition()
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="cpsat-prover", daemon=True)
        self._thread.start()

    def ask(self, horizons: Iterable[int]) -> None:
        """Prove these horizons (and no others), in this order where their slices are equal."""
        with self._wake:
            self._asked = list(horizons)
            self._wake.notify()

    @contextmanager
    def searching(self, horizon: int, options: SolveOptions) -> Iterator[SolveOptions]:
        """``options`` for the search of ``horizon``, with a stop request of its own that the
        prover sets once it proves the horizon (and ``options.interrupt`` sets too)."""
        stop = Interrupt()
        with self._wake:
            self._searched = (horizon, stop)
            if horizon in self._proven:
                stop.set()
        with options.interrupt.watch(stop.set) if options.interrupt else nullcontext():
            try:
                yield replace(options, interrupt=stop)
            finally:
                with self._wake:
                    self._searched = None

    def proofs(self) -> dict[int, Proof]:
        """The horizons proven to have no plan so far, and their proofs."""
        with self._wake:
            return dict(self._proven)

    def close(self) -> dict[int, Proof]:
        """Stop the prover; the horizons it proved, and their proofs."""
        with self._wake:
            self._stop.set()
            self._wake.notify()
        while self._thread.is_alive():
            self._thread.join(0.1)
            # again: a stop request that came as CP-SAT was starting is lost on it
            self._stop.set()
        if self._failure is not None:
            raise self._failure
        return self.proofs()

    def _next(self) -> tuple[int, float] | None:
        """The horizon to try next and its slice (the least tried first), if any."""
        ready = [T for T in self._asked if T not in self._proven]
        if not ready:
            return None
        T = min(ready, key=lambda T: self._slice.get(T, self._first_slice))
        return T, self._slice.setdefault(T, self._first_slice)

    def _run(self) -> None:
        relaxations: dict[int, Relaxation | None] = {}
        parent = self._options.interrupt
        try:
            with parent.watch(self._stop.set) if parent else nullcontext():
                while not self._stop.is_set():
                    with self._wake:
                        task = self._next()
                        if task is None:
                            if not self._stop.is_set():  # set under the lock by close()
                                self._wake.wait()
                            continue
                    T, span = task
                    if T not in relaxations:
                        try:
                            relaxations[T] = Relaxation(self._form(T))
                        except ValueError:  # a column it cannot bound: never proven
                            relaxations[T] = None
                    if relaxations[T] is None:
                        with self._wake:
                            self._asked.remove(T)
                        continue
                    proof = relaxations[T].solve(replace(self._options, time_limit_s=span,
                                                         interrupt=self._stop))
                    with self._wake:
                        self._slice[T] = 4 * span
                        if proof.status is Status.INFEASIBLE:
                            self._proven[T] = proof
                            if self._searched is not None and self._searched[0] == T:
                                self._searched[1].set()
        except BaseException as err:  # raised again by close()
            self._failure = err


def _empty(f: StandardForm, A: sp.csr_matrix, row_lb: np.ndarray, row_ub: np.ndarray) -> str:
    """Why ``f`` (with the rows A) has no point at all, if a column's or a row's bounds say so
    alone (e.g. a requirement the encoder found false whatever the plan); else ''."""
    if np.any(f.col_lb > f.col_ub + TOL):
        return "a column's bounds are empty"
    empty = np.flatnonzero(row_lb > row_ub + TOL)
    if len(empty):
        return f"row {int(empty[0])}'s bounds are empty"
    lo, hi = np.nan_to_num(f.col_lb, neginf=-1e300), np.nan_to_num(f.col_ub, posinf=1e300)
    pos, neg = A.maximum(0), A.minimum(0)
    with np.errstate(invalid="ignore", over="ignore"):
        most = pos @ hi + neg @ lo  # the rows' largest and least values over the columns
        least = pos @ lo + neg @ hi
    far = np.flatnonzero((most < row_lb - TOL) | (least > row_ub + TOL))
    if len(far):
        return f"row {int(far[0])} cannot be met within the columns' bounds"
    return ""


def _truth_columns(A: sp.csr_matrix, row_lb, row_ub, lo, hi, integer, fixed) -> np.ndarray:
    """The columns that may be Booleans (module docstring): continuous in [0, 1] and every row
    they are in safe for z ↦ ⌈z⌉, to a fixed point: a column that fails is continuous, and its
    rows are then no longer safe for the truth columns they hold."""
    truth = ~integer & ~fixed & (lo == 0) & (hi == 1)
    shift = A @ np.where(fixed, lo, 0.0)
    L, U = row_lb - shift, row_ub - shift
    row, col, a, per_row = _entries(A, fixed)
    # what does not depend on which columns are truth columns
    fit = _integral(L) & _integral(U) & (per_row(a != np.round(a)) == 0)
    while True:
        t = truth[col]
        above = per_row(t & (a > 0))  # truth columns the ceiling could push over U
        below = per_row(t & (a < 0))  # ... and under L
        safe = (fit & (per_row(~integer[col] & ~t) == 0)
                & (~np.isfinite(U) | (above == 0) | ((above == 1) & (per_row(t & (a == 1)) == 1)))
                & (~np.isfinite(L) | (below == 0) | ((below == 1) & (per_row(t & (a == -1)) == 1))))
        unsafe = ~safe & (per_row(t) > 0)
        if not unsafe.any():
            return truth
        truth[col[unsafe[row] & t]] = False


def _entries(A: sp.csr_matrix, fixed: np.ndarray):
    """A's entries in the columns not fixed: their rows, columns and coefficients, and a sum
    over each row of values given per entry."""
    live = A @ sp.diags((~fixed).astype(float))
    live.eliminate_zeros()
    row = np.repeat(np.arange(A.shape[0]), np.diff(live.indptr))

    def per_row(values: np.ndarray) -> np.ndarray:
        return np.bincount(row, values, minlength=A.shape[0])

    return row, live.indices, live.data, per_row


def _integral(v: np.ndarray) -> np.ndarray:
    """Whether each bound is infinite or an integer."""
    return ~np.isfinite(v) | (v == np.round(v))
