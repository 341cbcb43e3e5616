"""The one solver boundary: a MathematicalProgram MILP solved by HiGHS (or Drake's licensed ones).

Drake's pip wheel has no MILP solver, so :func:`solve` reads the program's linear costs, linear
constraints, bounding boxes and binary variables in bulk as sparse matrices and hands them to
``highspy``. Where a licensed Gurobi or MOSEK is available and asked for, Drake's own solver runs
instead. This module knows nothing of LTL or robots.
"""

from __future__ import annotations

import enum
import functools
import logging
import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import LinearConstraint, LinearCost, MathematicalProgram, SolverOptions
from pydrake.symbolic import Variable

log = logging.getLogger(__name__)


class Status(enum.Enum):
    OPTIMAL = "optimal"
    FEASIBLE = "feasible"  # a solution with a gap above the asked one (stopped early)
    INFEASIBLE = "infeasible"
    UNBOUNDED = "unbounded"  # or HiGHS could not tell unbounded from infeasible
    TIME_LIMIT = "time_limit"  # stopped with no solution
    ERROR = "error"

    @property
    def has_solution(self) -> bool:
        return self in (Status.OPTIMAL, Status.FEASIBLE)


@dataclass(frozen=True)
class SolveOptions:
    time_limit_s: float = 30.0
    mip_rel_gap: float = 1e-4
    threads: int = 1
    backend: str = "highs"  # or "gurobi" / "mosek" (Drake, licensed)
    # Stops the solves under these options from another thread (a replan that ran out of time).
    interrupt: Interrupt | None = field(default=None, compare=False)


class Interrupt:
    """A stop request for running solves, from any thread: each HiGHS run under it is
    cancelled through HiGHS's interrupt callback and ends with status "time_limit" (or
    "feasible" with its incumbent)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._running: set = set()
        self._set = False

    def set(self) -> None:
        with self._lock:
            self._set = True
            for h in self._running:
                h.cancelSolve()

    def is_set(self) -> bool:
        return self._set

    def attach(self, h) -> None:
        with self._lock:
            self._running.add(h)
            if self._set:
                h.cancelSolve()

    def detach(self, h) -> None:
        with self._lock:
            self._running.discard(h)


@dataclass(frozen=True)
class SolveResult:
    status: Status
    objective: float  # inf when there is no solution
    bound: float  # the proven lower bound
    gap: float  # relative gap; 0 when optimal, inf when no solution
    wall_time_s: float
    x: np.ndarray | None  # values of prog.decision_variables(), or None
    message: str = ""


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
        return replace(self, A=sp.vstack([self.A, row], format="csr"),
                       row_lb=np.append(self.row_lb, lb), row_ub=np.append(self.row_ub, ub))


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
        raise ValueError(f"the HiGHS adapter accepts linear costs and linear constraints only, "
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


# A MIP start: values of all decision variables, or (indices, values) of some of them, which
# HiGHS completes by solving for the others.
Start = np.ndarray | tuple[np.ndarray, np.ndarray]


def solve(prog: MathematicalProgram, options: SolveOptions = SolveOptions(),
          start: Start | None = None) -> SolveResult:
    """Solve the MILP ``prog`` from an optional MIP ``start``."""
    if options.backend != "highs":
        return _solve_with_drake(prog, options, start)
    return solve_standard_form(standard_form(prog), options, start)


@functools.cache
def _quiet_highs() -> type:
    """highspy's ``Highs`` that never prints: its constructor registers callbacks, the first
    HiGHS call that logs, so the banner reached stdout (once per process) before any option
    could be set."""
    import highspy  # local: the adapter is the only place that knows the solver

    class QuietHighs(highspy.Highs):
        def enableCallbacks(self) -> None:
            self.setOptionValue("output_flag", False)
            super().enableCallbacks()

    return QuietHighs


def solve_standard_form(f: StandardForm, options: SolveOptions,
                        start: Start | None = None) -> SolveResult:
    import highspy

    t0 = time.perf_counter()
    h = _quiet_highs()()
    h.setOptionValue("time_limit", float(options.time_limit_s))
    h.setOptionValue("mip_rel_gap", float(options.mip_rel_gap))
    h.setOptionValue("threads", int(options.threads))
    lp = highspy.HighsLp()
    n = len(f.c)
    lp.num_col_ = n
    lp.num_row_ = f.A.shape[0]
    lp.col_cost_ = f.c
    lp.offset_ = f.c0
    lp.col_lower_ = f.col_lb
    lp.col_upper_ = f.col_ub
    lp.row_lower_ = f.row_lb
    lp.row_upper_ = f.row_ub
    A = f.A.tocsc()
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = A.indptr
    lp.a_matrix_.index_ = A.indices
    lp.a_matrix_.value_ = A.data
    lp.a_matrix_.num_col_ = n
    lp.a_matrix_.num_row_ = f.A.shape[0]
    lp.integrality_ = [
        highspy.HighsVarType.kInteger if b else highspy.HighsVarType.kContinuous for b in f.integer
    ]
    h.passModel(lp)
    if isinstance(start, tuple):
        index, value = (np.asarray(a) for a in start)
        value = np.clip(value, f.col_lb[index], f.col_ub[index])
        h.setSolution(len(index), index.astype(np.int32), value.astype(float))
    elif start is not None:
        sol = highspy.HighsSolution()
        sol.col_value = list(np.clip(start, f.col_lb, f.col_ub))
        sol.value_valid = True
        h.setSolution(sol)
    stop = options.interrupt
    if stop is not None:
        h.HandleUserInterrupt = True
        stop.attach(h)
    try:
        h.run()
    finally:
        if stop is not None:
            stop.detach(h)
    wall = time.perf_counter() - t0
    status = h.getModelStatus()
    info = h.getInfo()
    M = highspy.HighsModelStatus
    has_solution = info.primal_solution_status == 2  # kSolutionStatusFeasible
    mip = bool(f.integer.any())
    if status == M.kOptimal:
        s = Status.OPTIMAL
    elif status == M.kInfeasible:
        s = Status.INFEASIBLE
    elif status in (M.kUnbounded, M.kUnboundedOrInfeasible):
        s = Status.UNBOUNDED  # HiGHS may hold a feasible point here: it is no solution
    elif status in (M.kTimeLimit, M.kIterationLimit, M.kSolutionLimit, M.kInterrupt):
        s = Status.FEASIBLE if has_solution else Status.TIME_LIMIT
    else:
        s = Status.ERROR
    if s.has_solution:
        x = np.asarray(h.getSolution().col_value)
        obj = float(info.objective_function_value)
    else:
        x, obj = None, np.inf
    # HiGHS's mip_dual_bound is meaningless for a pure LP: only its optimum is a proven bound.
    if s is Status.UNBOUNDED:
        bound = -np.inf
    elif mip:
        bound = float(info.mip_dual_bound)
    else:
        bound = {Status.OPTIMAL: obj, Status.INFEASIBLE: np.inf}.get(s, -np.inf)
    gap = 0.0 if s is Status.OPTIMAL else float(info.mip_gap) if s.has_solution and mip else np.inf
    return SolveResult(s, obj, bound, gap, wall, x, h.modelStatusToString(status))


def _solve_with_drake(prog, options: SolveOptions, start) -> SolveResult:
    """Drake's own Gurobi or MOSEK, where licensed (``backend`` = "gurobi" / "mosek")."""
    from pydrake.solvers import GurobiSolver, MosekSolver

    solver = {"gurobi": GurobiSolver, "mosek": MosekSolver}[options.backend]()
    if isinstance(start, tuple):
        dense = np.full(prog.num_vars(), np.nan)
        dense[start[0]] = start[1]
        start = dense
    if not (solver.available() and solver.enabled()):
        raise RuntimeError(
            f"solver backend {options.backend!r} is not available or not licensed here; "
            "use backend 'highs'"
        )
    opts = SolverOptions()
    names = {"gurobi": ("TimeLimit", "MIPGap", "Threads"),
             "mosek": ("MSK_DPAR_OPTIMIZER_MAX_TIME", "MSK_DPAR_MIO_TOL_REL_GAP",
                       "MSK_IPAR_NUM_THREADS")}[options.backend]
    for name, value in zip(names, (float(options.time_limit_s), float(options.mip_rel_gap),
                                   int(options.threads)), strict=True):
        opts.SetOption(solver.solver_id(), name, value)
    t0 = time.perf_counter()
    result = solver.Solve(prog, start, opts)
    return drake_result(options, result, prog.decision_variables(), time.perf_counter() - t0)


# Gurobi's optimization status codes. Drake passes a solution back for OPTIMAL and SUBOPTIMAL
# only: stopped at a limit, Gurobi's incumbent is lost, so the result is TIME_LIMIT.
_GUROBI = {2: Status.OPTIMAL, 3: Status.INFEASIBLE, 4: Status.UNBOUNDED, 5: Status.UNBOUNDED,
           7: Status.TIME_LIMIT, 8: Status.TIME_LIMIT, 9: Status.TIME_LIMIT,
           10: Status.TIME_LIMIT, 11: Status.TIME_LIMIT, 13: Status.FEASIBLE,
           16: Status.TIME_LIMIT}
# MOSEK's solution status codes (MSKsolstae). For a MIP, PRIM_FEAS is an incumbent where the
# search stopped early (Drake calls it "solution found"); UNKNOWN is either a limit without an
# incumbent or an infeasible MIP, which Drake does not tell apart (it keeps MOSEK's problem
# status to itself): see drake_result.
_MOSEK = {1: Status.OPTIMAL, 9: Status.OPTIMAL, 2: Status.FEASIBLE, 4: Status.FEASIBLE,
          5: Status.INFEASIBLE, 6: Status.UNBOUNDED}


def drake_result(options: SolveOptions, result, variables, wall: float) -> SolveResult:
    """A Drake MathematicalProgramResult of Gurobi or MOSEK as a :class:`SolveResult`, with the
    solver's own status: optimal (within ``mip_rel_gap``), stopped with an incumbent and its
    gap, stopped at the time limit, infeasible, unbounded, or an error."""
    details = result.get_solver_details()
    if options.backend == "gurobi":
        code = details.optimization_status
        status = _GUROBI.get(code, Status.ERROR) if not details.error_code else Status.ERROR
        message = f"Gurobi status {code}, error code {details.error_code}"
        bound = float(details.objective_bound)
    else:
        code = details.solution_status
        status = _MOSEK.get(code, Status.ERROR) if details.rescode == 0 else Status.ERROR
        if code == 0 and details.rescode == 0:
            # Stopped by the time limit, or an infeasible MIP that we cannot prove so.
            status = (Status.TIME_LIMIT if wall >= 0.99 * options.time_limit_s else Status.ERROR)
        message = f"MOSEK solution status {code}, response code {details.rescode}"
        bound = np.nan  # MOSEK's MIP bound does not come through Drake
    x = np.asarray(result.GetSolution(variables), float) if status.has_solution else None
    if x is not None and not np.isfinite(x).all():
        status, x = Status.ERROR, None
        message += ", no finite solution"
    objective = float(result.get_optimal_cost()) if status.has_solution else np.inf
    if status is Status.OPTIMAL:
        bound, gap = (objective if np.isnan(bound) else bound), 0.0
    elif status is Status.FEASIBLE:
        gap = (abs(objective - bound) / max(abs(objective), 1e-10) if np.isfinite(bound)
               else np.inf)
        bound = bound if np.isfinite(bound) else -np.inf
    else:
        bound = {Status.INFEASIBLE: np.inf}.get(status, -np.inf)
        gap = np.inf
    return SolveResult(status, objective, bound, gap, wall, x, message)
