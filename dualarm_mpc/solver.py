"""The one solver boundary: a MathematicalProgram MILP in standard form, solved by a backend.

Drake's pip wheel has no MILP solver, so :func:`standard_form` reads a program's linear costs,
linear constraints, bounding boxes and binary variables in bulk as sparse matrices, and
:func:`solve_standard_form` hands them to the backend that :class:`SolveOptions` names: HiGHS
(the default), SCIP, Gurobi or CPLEX, each an adapter in ``backends.py`` that is imported only
when used. Every backend gets the same options and returns the same :class:`SolveResult`:
status, bound and gap are made here from what each solver said, one way for all. This module
knows nothing of LTL or robots.
"""

from __future__ import annotations

import enum
import errno
import importlib.util
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import LinearConstraint, LinearCost, MathematicalProgram
from pydrake.symbolic import Variable

# Backend name → (the Python module it needs, the pip extra that installs it).
BACKENDS = {"highs": ("highspy", None), "scip": ("pyscipopt", "scip"),
            "gurobi": ("gurobipy", "gurobi"), "cplex": ("cplex", "cplex")}


class SolverUnavailable(RuntimeError):
    """A backend that cannot solve here: unknown, not installed, no licence, or a model over
    its licence's size limit. The message is one line that says which and what to do."""


def installed_backends() -> list[str]:
    """The backends whose Python package is installed here (licences are not checked)."""
    return [name for name, (module, _) in BACKENDS.items()
            if importlib.util.find_spec(module) is not None]


def require_backend(name: str) -> None:
    """Raise :class:`SolverUnavailable` unless backend ``name`` is known and installed."""
    if name not in BACKENDS:
        raise SolverUnavailable(f"unknown solver {name!r} (one of {', '.join(BACKENDS)})")
    module, extra = BACKENDS[name]
    if importlib.util.find_spec(module) is None:
        raise SolverUnavailable(f"solver {name!r} is not installed here (pip install "
                                f"'dualarm_mpc[{extra}]'); installed: "
                                f"{', '.join(installed_backends())}")


class Status(enum.Enum):
    OPTIMAL = "optimal"
    FEASIBLE = "feasible"  # a solution with a gap above the asked one (stopped early)
    INFEASIBLE = "infeasible"
    UNBOUNDED = "unbounded"  # or infeasible, where an unbounded column leaves it open
    TIME_LIMIT = "time_limit"  # stopped with no solution
    ERROR = "error"

    @property
    def has_solution(self) -> bool:
        return self in (Status.OPTIMAL, Status.FEASIBLE)


@dataclass(frozen=True)
class SolveOptions:
    """What every backend gets: a time limit, the relative gap |objective − bound| / |objective|
    at which a solution counts as optimal (1 or more: the first solution), threads."""

    time_limit_s: float = 30.0
    mip_rel_gap: float = 1e-4
    threads: int = 1
    backend: str = "highs"  # a key of BACKENDS
    # HiGHS set for the search's programs, whose trees close in a few nodes: no sub-MIP or
    # rounding heuristics (RINS, RENS, feasibility jump, root reduced cost: half of their time),
    # no restart, pseudocost branching, light presolve, cuts at the root only (docs/search.md,
    # "Solver settings"). The monolithic reference keeps HiGHS's defaults; other backends
    # ignore the field.
    small_trees: bool = False
    # A deterministic work limit: branch-and-bound nodes per solve (HiGHS's mip_max_nodes; other
    # backends ignore it). Reached, the solve ends as at its time limit. The closed loop in
    # lockstep sets it in place of a wall-time limit, which would depend on the machine.
    node_limit: int | None = None
    # The skeleton search's deterministic work limit, shared by the searches under these
    # options (a replan's horizons): past it a search stops as at its time limit.
    work: WorkLimit | None = field(default=None, compare=False)
    # Only solutions below this objective are wanted: a program with none ends "infeasible",
    # which here means "nothing below the cutoff". Every backend prunes by it: HiGHS's
    # objective_bound, SCIP's objective limit, Gurobi's Cutoff, CPLEX's upper cutoff.
    cutoff: float = np.inf
    # Stops the solves under these options from another thread (a replan that ran out of time).
    interrupt: Interrupt | None = field(default=None, compare=False)


class WorkLimit:
    """A count of the programs solved under it, from any thread, and the most it allows. Read
    only where no solve under it runs, it stops a search at the same place on any machine."""

    def __init__(self, programs: int) -> None:
        self.limit, self.programs = programs, 0
        self._lock = threading.Lock()

    def spend(self) -> None:
        with self._lock:
            self.programs += 1

    def spent(self) -> bool:
        return self.programs >= self.limit


class Interrupt:
    """A stop request for running solves, from any thread: each solve under it stops as soon
    as its solver can and ends with status "time_limit" (or "feasible" with its incumbent).
    CPLEX is cancelled from the thread that sets it (:meth:`watch`); HiGHS, SCIP and Gurobi
    poll :meth:`is_set` from their own callbacks."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._running: dict[int, Callable[[], None]] = {}
        self._set = False

    def set(self) -> None:
        with self._lock:
            self._set = True
            for cancel in self._running.values():
                cancel()

    def is_set(self) -> bool:
        return self._set

    @contextmanager
    def watch(self, cancel: Callable[[], None]) -> Iterator[None]:
        """Call ``cancel`` (which stops a running solve) when set, while in the block; at once
        if set already."""
        key = id(cancel)
        with self._lock:
            self._running[key] = cancel
            if self._set:
                cancel()
        try:
            yield
        finally:
            with self._lock:
                del self._running[key]


@dataclass(frozen=True)
class SolveResult:
    status: Status
    objective: float  # inf when there is no solution
    bound: float  # the proven lower bound: inf when infeasible, -inf when unknown
    gap: float  # (objective − bound) / |objective|; inf when there is no solution
    wall_time_s: float
    x: np.ndarray | None  # values of the columns, or None
    message: str = ""  # the solver's own status
    backend: str = "highs"


@dataclass(frozen=True)
class StandardForm:
    """min c·x + c0 s.t. row_lb ≤ A x ≤ row_ub, col_lb ≤ x ≤ col_ub, x_i integer for i in ints."""

    c: np.ndarray
    c0: float
    A: sp.csr_matrix
    row_lb: np.ndarray
    row_ub: np.ndarray
    col_lb: np.ndarray
    col_ub: np.ndarray
    integer: np.ndarray  # bool mask

    def extended(self, other: StandardForm) -> StandardForm:
        """A copy with the rows and the new columns of ``other``, a form whose first columns
        are this one's (a specification encoded over the same variables)."""
        n, m = len(self.c), len(other.c)
        A = sp.vstack([sp.hstack([self.A, sp.csr_matrix((self.A.shape[0], m - n))]), other.A],
                      format="csr")
        return StandardForm(
            np.concatenate([self.c, other.c[n:]]), self.c0 + other.c0, A,
            np.concatenate([self.row_lb, other.row_lb]),
            np.concatenate([self.row_ub, other.row_ub]),
            np.concatenate([np.maximum(self.col_lb, other.col_lb[:n]), other.col_lb[n:]]),
            np.concatenate([np.minimum(self.col_ub, other.col_ub[:n]), other.col_ub[n:]]),
            np.concatenate([self.integer | other.integer[:n], other.integer[n:]]))

    def with_row(self, index: np.ndarray, lb: float = -np.inf, ub: float = np.inf) -> StandardForm:
        """A copy with the row ``lb ≤ Σ_i x[index_i] ≤ ub`` added."""
        row = sp.csr_matrix((np.ones(len(index)), (np.zeros(len(index), int), index)),
                            shape=(1, len(self.c)))
        return self.with_rows(row, np.array([lb]), np.array([ub]))

    def with_rows(self, rows: sp.spmatrix, lb: np.ndarray, ub: np.ndarray) -> StandardForm:
        """A copy with the rows ``lb ≤ rows·x ≤ ub`` added."""
        return replace(self, A=sp.vstack([self.A, rows], format="csr"),
                       row_lb=np.concatenate([self.row_lb, lb]),
                       row_ub=np.concatenate([self.row_ub, ub]))


def standard_form(prog: MathematicalProgram) -> StandardForm:
    """Read ``prog`` (linear costs and constraints only) into sparse matrices; anything else is
    refused with its kind, never dropped."""
    n = prog.num_vars()
    # Bounding boxes and linear equalities are LinearConstraints too: all read below.
    unsupported = sorted(
        {type(b.evaluator()).__name__ for b in prog.GetAllCosts()
         if not isinstance(b.evaluator(), LinearCost)}
        | {type(b.evaluator()).__name__ for b in prog.GetAllConstraints()
           if not isinstance(b.evaluator(), LinearConstraint)})
    if unsupported:
        raise ValueError(f"the solver boundary accepts linear costs and linear constraints only, "
                         f"not {', '.join(unsupported)}")
    c = np.zeros(n)
    c0 = 0.0
    for b in prog.linear_costs():
        idx = prog.FindDecisionVariableIndices(b.variables())
        np.add.at(c, idx, b.evaluator().a())
        c0 += b.evaluator().b()
    col_lb = np.full(n, -np.inf)
    col_ub = np.full(n, np.inf)
    for b in prog.bounding_box_constraints():
        idx = prog.FindDecisionVariableIndices(b.variables())
        e = b.evaluator()
        np.maximum.at(col_lb, idx, e.lower_bound())
        np.minimum.at(col_ub, idx, e.upper_bound())
    blocks, lbs, ubs = [], [], []
    for b in list(prog.linear_constraints()) + list(prog.linear_equality_constraints()):
        idx = np.asarray(prog.FindDecisionVariableIndices(b.variables()))
        e = b.evaluator()
        A = e.get_sparse_A().tocoo()
        blocks.append(sp.csr_matrix((A.data, (A.row, idx[A.col])), shape=(A.shape[0], n)))
        lbs.append(e.lower_bound())
        ubs.append(e.upper_bound())
    A = sp.vstack(blocks, format="csr") if blocks else sp.csr_matrix((0, n))
    integer = np.array([v.get_type() == Variable.Type.BINARY for v in prog.decision_variables()],
                       bool)
    col_lb[integer] = np.maximum(col_lb[integer], 0.0)
    col_ub[integer] = np.minimum(col_ub[integer], 1.0)
    return StandardForm(c, c0, A, np.concatenate(lbs) if lbs else np.zeros(0),
                        np.concatenate(ubs) if ubs else np.zeros(0), col_lb, col_ub, integer)


# A MIP start: values of all columns, or (indices, values) of some of them, which the solver
# completes by solving for the others.
Start = np.ndarray | tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class MipStart:
    """A MIP start as an adapter gets it: values (within bounds) of the columns ``index``, all
    of them when ``complete``."""

    index: np.ndarray
    value: np.ndarray
    complete: bool


@dataclass(frozen=True)
class Outcome:
    """What an adapter (``backends.py``) reports, in our words. ``status`` is TIME_LIMIT
    whenever the solver stopped early (time limit, interrupt, another limit), with or without
    a solution; UNBOUNDED covers "infeasible or unbounded". ``bound`` is the solver's proven
    lower bound (-inf if it has none)."""

    status: Status
    x: np.ndarray | None
    objective: float
    bound: float
    message: str


def solve(prog: MathematicalProgram, options: SolveOptions = SolveOptions(),
          start: Start | None = None) -> SolveResult:
    """Solve the MILP ``prog`` from an optional MIP ``start``."""
    return solve_standard_form(standard_form(prog), options, start)


def solve_standard_form(f: StandardForm, options: SolveOptions,
                        start: Start | None = None) -> SolveResult:
    """Solve ``f`` with ``options.backend``; raises :class:`SolverUnavailable` when that backend
    cannot (unknown, not installed, unlicensed, the model over its licence's size limit)."""
    from dualarm_mpc import backends

    require_backend(options.backend)
    t0 = time.perf_counter()
    out = getattr(backends, options.backend)(f, options, _start(f, start))
    return _result(f, options, out, time.perf_counter() - t0)


def _start(f: StandardForm, start: Start | None) -> MipStart | None:
    """``start`` as columns and values within their bounds."""
    if start is None:
        return None
    if isinstance(start, tuple):
        index = np.asarray(start[0], int)
        value = np.asarray(start[1], float)
    else:
        index, value = np.arange(len(f.c)), np.asarray(start, float)
    value = np.clip(value, f.col_lb[index], f.col_ub[index])
    return MipStart(index, value, complete=len(index) == len(f.c))


def _result(f: StandardForm, options: SolveOptions, out: Outcome, wall: float) -> SolveResult:
    """One backend's outcome as a :class:`SolveResult`, the same way for every backend:

    * "infeasible or unbounded" is infeasible when every column is bounded (then no objective
      is unbounded), else left as UNBOUNDED;
    * stopped early with a solution is FEASIBLE, or OPTIMAL when its gap is within the one
      asked (as each solver itself decides when it does not stop early; any solution when
      that is 1 or more); without one, TIME_LIMIT;
    * gap = (objective − bound) / |objective| with the bound no higher than the objective."""
    status, message = out.status, out.message
    if status is Status.UNBOUNDED and np.isfinite(f.col_lb).all() and \
            np.isfinite(f.col_ub).all():
        status, message = Status.INFEASIBLE, message + " (every column bounded: infeasible)"
    if status in (Status.OPTIMAL, Status.TIME_LIMIT) and out.x is not None:
        if not np.isfinite(out.x).all():
            return SolveResult(Status.ERROR, np.inf, -np.inf, np.inf, wall, None,
                               message + ", no finite solution", options.backend)
        objective = out.objective
        bound = min(out.bound, objective) if not np.isnan(out.bound) else -np.inf
        gap = (objective - bound) / max(abs(objective), 1e-10) if np.isfinite(bound) else np.inf
        if status is Status.TIME_LIMIT:  # a gap of 1 or more asks for any solution
            within = gap <= options.mip_rel_gap or options.mip_rel_gap >= 1
            status = Status.OPTIMAL if within else Status.FEASIBLE
        return SolveResult(status, objective, bound, gap, wall, out.x, message, options.backend)
    if status is Status.OPTIMAL:
        status, message = Status.ERROR, message + ", no solution"
    bound = {Status.INFEASIBLE: np.inf,
             Status.TIME_LIMIT: -np.inf if np.isnan(out.bound) else out.bound}.get(status, -np.inf)
    return SolveResult(status, np.inf, bound, np.inf, wall, None, message, options.backend)


def write_mps(f: StandardForm, path: str | Path) -> None:
    """Write ``f`` as an MPS file (through HiGHS), for any other solver to read; ``OSError``
    if the file is not whole."""
    import highspy

    from dualarm_mpc.backends import highs_model

    path = Path(path)
    if highs_model(f).writeModel(str(path)) == highspy.HighsStatus.kError or \
            not _ends(path, b"ENDATA\n"):
        raise _why_short(path)


def _ends(path: Path, tail: bytes) -> bool:
    """Whether file ``path`` ends with ``tail`` (HiGHS does not check its writes: a full disk
    or a file-size limit leaves a truncated file it reports written)."""
    try:
        with open(path, "rb") as file:
            file.seek(max(path.stat().st_size - len(tail), 0))
            return file.read() == tail
    except OSError:
        return False


def _why_short(path: Path) -> OSError:
    """The OS's reason a write to ``path`` fell short, which HiGHS does not tell: asked by
    appending a byte to the (failed, to be discarded) file."""
    try:
        with open(path, "ab") as file:
            file.write(b"\n")
    except OSError as err:
        return OSError(err.errno, err.strerror, str(path))
    return OSError(errno.EIO, "HiGHS could not write the whole MPS file", str(path))
