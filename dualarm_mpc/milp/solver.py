"""The one solver boundary: a MILP in standard form, what a solve of it is asked and answers.

Drake's pip wheel has no MILP solver, so :func:`standard_form` reads a program's linear costs,
linear constraints, bounding boxes and binary variables in bulk as sparse matrices, a
:class:`StandardForm`; ``backends.py`` solves it with the backend :class:`SolveOptions` names —
HiGHS (the default), SCIP, Gurobi or CPLEX — and every backend answers with the same
:class:`SolveResult`. This module knows nothing of LTL or robots, nor of any one solver.
"""

from __future__ import annotations

import enum
import importlib.util
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

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


class SizeLimit(SolverUnavailable):
    """A model over the backend's licence's size limit: the caller, who knows which program
    it built, says so (the consistency check's, and that solver.max_horizon sizes it)."""


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

    def stopped(self) -> bool:
        """Whether a stop was requested (``interrupt``): polled by the loops outside the
        solvers that can run long (the route bound, ``route.py``)."""
        return self.interrupt is not None and self.interrupt.is_set()


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
        """Whether a stop was requested."""
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
