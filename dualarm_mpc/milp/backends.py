"""The MILP solvers behind the boundary of ``solver.py``: one adapter per backend, and the solve.

Each adapter takes a :class:`~dualarm_mpc.milp.solver.StandardForm` into its solver's own API,
solves it under the :class:`~dualarm_mpc.milp.solver.SolveOptions` every backend gets (time limit,
relative gap, threads, a MIP start, a stop request) and reports an
:class:`~dualarm_mpc.milp.solver.Outcome`: what that solver said, in our words.
:func:`solve_standard_form` picks the adapter ``SolveOptions.backend`` names and makes every
backend's outcome a ``SolveResult`` the same way: status, bound and gap from what each solver said,
one way for all. Only HiGHS is a dependency: each other solver is imported inside its adapter, so a
machine without it never loads it. No adapter knows anything of LTL or robots.

Where a solver's free licence limits the model size (the pip packages of Gurobi and CPLEX), a
model over the limit raises :class:`~dualarm_mpc.milp.solver.SolverUnavailable` naming the limit.
"""

from __future__ import annotations

import errno
import functools
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from dualarm_mpc.milp.solver import (
    MipStart,
    Outcome,
    SizeLimit,
    SolveOptions,
    SolveResult,
    SolverUnavailable,
    StandardForm,
    Start,
    Status,
    require_backend,
    standard_form,
)

# The pip packages' free licences: (variables, linear constraints) a model may have.
GUROBI_LIMIT = (2000, 2000)  # Gurobi's size-limited licence, shipped with gurobipy
CPLEX_LIMIT = (1000, 1000)  # IBM ILOG CPLEX Community Edition, shipped with cplex


def _over_limit(solver: str, f: StandardForm, limit: tuple[int, int], rows: int) -> str:
    return (f"solver {solver!r}: this MILP has {len(f.c)} variables and {rows} constraints, over "
            f"the {limit[0]} variables and {limit[1]} constraints of the free licence that "
            f"comes with the {solver} pip package; use a full licence or another --solver")


def _rows(f: StandardForm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks of the equality rows, and of the other rows with a finite upper / lower side (a
    row bounded on both sides is in both); rows free on both sides are left out."""
    eq = f.row_lb == f.row_ub
    return eq, np.isfinite(f.row_ub) & ~eq, np.isfinite(f.row_lb) & ~eq


# --- HiGHS -------------------------------------------------------------------------------------


@functools.cache
def _quiet_highs() -> type:
    """highspy's ``Highs`` that never prints: its constructor registers callbacks, the first
    HiGHS call that logs, so the banner reached stdout (once per process) before any option
    could be set."""
    import highspy

    class QuietHighs(highspy.Highs):
        def enableCallbacks(self) -> None:
            self.setOptionValue("output_flag", False)
            super().enableCallbacks()

    return QuietHighs


def highs_model(f: StandardForm):
    """``f`` loaded into a silent HiGHS instance."""
    import highspy

    h = _quiet_highs()()
    A = f.A.tocsc()
    # The array overload of passModel takes numpy buffers as they are; filling a HighsLp's
    # fields converts them element by element (3.7 → 0.5 ms for a joint node program).
    status = h.passModel(len(f.c), A.shape[0], A.nnz, int(highspy.MatrixFormat.kColwise),
                         int(highspy.ObjSense.kMinimize), float(f.c0), f.c, f.col_lb, f.col_ub,
                         f.row_lb, f.row_ub, A.indptr.astype(np.int32),
                         A.indices.astype(np.int32), A.data, f.integer.astype(np.int32))
    if status == highspy.HighsStatus.kError:
        raise ValueError("HiGHS refused the model (passModel)")
    return h


def highs(f: StandardForm, options: SolveOptions, start: MipStart | None) -> Outcome:
    import highspy

    h = highs_model(f)
    h.setOptionValue("time_limit", float(options.time_limit_s))
    h.setOptionValue("mip_rel_gap", float(options.mip_rel_gap))
    h.setOptionValue("threads", int(options.threads))
    if options.node_limit is not None:
        h.setOptionValue("mip_max_nodes", int(options.node_limit))
    if options.small_trees:
        for name in ("rins", "rens", "feasibility_jump", "root_reduced_cost"):
            h.setOptionValue(f"mip_heuristic_run_{name}", False)
        h.setOptionValue("mip_allow_restart", False)
        # Branch on pseudocosts from the start, without strong branching to make them reliable:
        # the trees are small and their LP bounds weak (docs/search.md, "Solver settings").
        h.setOptionValue("mip_pscost_minreliable", 0)
        # Light presolve, and cuts at the root only: on programs this small the full presolve's
        # sweeps and the cuts separated at every node cost more than they save (docs/search.md,
        # "Solver settings").
        h.setOptionValue("presolve_mode", 2)
        h.setOptionValue("mip_allow_cut_separation_at_nodes", False)
    if np.isfinite(options.cutoff):
        h.setOptionValue("objective_bound", float(options.cutoff))
    if start is not None and start.complete:
        sol = highspy.HighsSolution()
        sol.col_value = list(start.value)
        sol.value_valid = True
        h.setSolution(sol)
    elif start is not None:  # HiGHS completes it by solving for the other columns
        h.setSolution(len(start.index), start.index.astype(np.int32), start.value)
    stop = options.interrupt
    if stop is not None:
        # Polled at HiGHS's MIP interrupt checks only: highspy's HandleUserInterrupt also
        # hooks every simplex check, each a call into Python that waits for the GIL
        # (bench/search-experiments.md, "Settings of the search").
        h.cbMipInterrupt += lambda event: event.interrupt() if stop.is_set() else None
    h.run()
    status = h.getModelStatus()
    info = h.getInfo()
    M = highspy.HighsModelStatus
    ours = {M.kOptimal: Status.OPTIMAL, M.kInfeasible: Status.INFEASIBLE,
            M.kUnbounded: Status.UNBOUNDED, M.kUnboundedOrInfeasible: Status.UNBOUNDED,
            M.kTimeLimit: Status.TIME_LIMIT, M.kIterationLimit: Status.TIME_LIMIT,
            M.kSolutionLimit: Status.TIME_LIMIT, M.kInterrupt: Status.TIME_LIMIT,
            }.get(status, Status.ERROR)
    # A point HiGHS holds next to "unbounded" is no solution.
    solved = info.primal_solution_status == 2 and ours in (Status.OPTIMAL, Status.TIME_LIMIT)
    x = np.asarray(h.getSolution().col_value) if solved else None
    objective = float(info.objective_function_value) if solved else np.inf
    # HiGHS's mip_dual_bound is meaningless for a pure LP: only its optimum is a proven bound.
    bound = float(info.mip_dual_bound) if f.integer.any() else \
        objective if ours is Status.OPTIMAL else -np.inf
    return Outcome(ours, x, objective, bound, h.modelStatusToString(status))


# --- SCIP (PySCIPOpt) --------------------------------------------------------------------------


@functools.cache
def _scip_stop_handler() -> type:
    """A SCIP event handler that interrupts the solve once ``stop`` (an Interrupt) is set:
    polled by SCIP's own thread at every node and LP, so a stop set before the solve began is
    not lost (SCIPsolve clears an earlier interruptSolve)."""
    from pyscipopt import SCIP_EVENTTYPE, Eventhdlr

    events = SCIP_EVENTTYPE.NODEFOCUSED | SCIP_EVENTTYPE.LPSOLVED | \
        SCIP_EVENTTYPE.PRESOLVEROUND

    class Stop(Eventhdlr):
        def __init__(self, stop) -> None:
            self.stop = stop

        def eventinit(self) -> None:
            self.model.catchEvent(events, self)

        def eventexit(self) -> None:
            self.model.dropEvent(events, self)

        def eventexec(self, event) -> None:
            if self.stop.is_set():
                self.model.interruptSolve()

    return Stop


def _scip_value(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None  # None: SCIP's infinity


def scip(f: StandardForm, options: SolveOptions, start: MipStart | None) -> Outcome:
    import pyscipopt as ps

    m = ps.Model()
    m.hideOutput()
    x = [m.addVar(lb=_scip_value(lb), ub=_scip_value(ub), vtype="I" if i else "C", obj=float(c))
         for lb, ub, i, c in zip(f.col_lb, f.col_ub, f.integer, f.c, strict=True)]
    A = f.A
    for r in np.flatnonzero(np.isfinite(f.row_lb) | np.isfinite(f.row_ub)):
        a, b = A.indptr[r], A.indptr[r + 1]
        terms = {ps.scip.Term(x[j]): float(v) for j, v in zip(A.indices[a:b], A.data[a:b],
                                                              strict=True)}
        m.addCons(ps.scip.ExprCons(ps.Expr(terms), lhs=_scip_value(f.row_lb[r]),
                                   rhs=_scip_value(f.row_ub[r])))
    if f.c0:
        m.addObjoffset(float(f.c0))
    if np.isfinite(options.cutoff):
        m.setObjlimit(float(options.cutoff))  # nothing below it: status "infeasible"
    m.setParam("limits/time", float(options.time_limit_s))
    # SCIP's gap is |p - d| / min(|p|, |d|); ours (HiGHS, Gurobi, CPLEX) |p - d| / |p|. For
    # 0 <= d <= p, ours <= g is SCIP's <= g / (1 - g); g >= 1 asks for any solution.
    g = float(options.mip_rel_gap)
    if g < 1:
        m.setParam("limits/gap", g / (1 - g))
    else:
        m.setParam("limits/solutions", 1)
    # SCIP's branch and bound runs on one thread whatever ``threads`` says (its concurrent
    # mode is experimental); the skeleton search solves its programs side by side instead.
    if start is not None:
        sol = m.createSol() if start.complete else m.createPartialSol()
        for j, v in zip(start.index, start.value, strict=True):
            m.setSolVal(sol, x[j], float(v))
        m.addSol(sol, free=True)
    if options.interrupt is not None:
        m.includeEventhdlr(_scip_stop_handler()(options.interrupt), "stop",
                           "interrupts the solve on a stop request")
    m.optimizeNogil()  # the GIL released: the search's other programs run meanwhile
    said = m.getStatus()
    if said in ("optimal", "gaplimit"):
        status = Status.OPTIMAL
    elif said == "infeasible":
        status = Status.INFEASIBLE
    elif said in ("unbounded", "inforunbd"):
        status = Status.UNBOUNDED
    elif said in ("timelimit", "userinterrupt", "sollimit", "bestsollimit", "nodelimit",
                  "totalnodelimit", "stallnodelimit", "memlimit", "restartlimit", "terminate"):
        status = Status.TIME_LIMIT
    else:
        status = Status.ERROR
    solved = m.getNSols() > 0 and status in (Status.OPTIMAL, Status.TIME_LIMIT)
    best = m.getBestSol() if solved else None
    values = np.array([m.getSolVal(best, v) for v in x]) if solved else None
    objective = float(m.getSolObjVal(best)) if solved else np.inf
    bound = m.getDualbound()
    bound = float(bound) if not m.isInfinity(abs(bound)) else np.sign(bound) * np.inf
    return Outcome(status, values, objective, bound, f"SCIP status {said}")


# --- Gurobi (gurobipy) -------------------------------------------------------------------------

# Gurobi's optimization status codes: 2 optimal; 3 infeasible; 4 infeasible or unbounded; 5
# unbounded; 6 nothing below the cutoff (our "infeasible"); 7-11, 13, 15-17 stopped by a limit
# or interrupted (13: a suboptimal solution).
_GUROBI = {2: Status.OPTIMAL, 3: Status.INFEASIBLE, 4: Status.UNBOUNDED, 5: Status.UNBOUNDED,
           6: Status.INFEASIBLE,
           **dict.fromkeys((7, 8, 9, 10, 11, 13, 15, 16, 17), Status.TIME_LIMIT)}


def gurobi(f: StandardForm, options: SolveOptions, start: MipStart | None) -> Outcome:
    import gurobipy as gp

    eq, le, ge = _rows(f)
    rows = int(eq.sum() + le.sum() + ge.sum())
    try:
        env = gp.Env(empty=True)
        env.setParam("OutputFlag", 0)  # before start(): no licence banner either
        env.start()
    except gp.GurobiError as err:
        raise SolverUnavailable(f"solver 'gurobi': no usable licence ({err})") from None
    with env, gp.Model(env=env) as m:
        x = m.addMVar(len(f.c), lb=f.col_lb, ub=f.col_ub, obj=f.c,
                      vtype=np.where(f.integer, gp.GRB.INTEGER, gp.GRB.CONTINUOUS))
        m.ObjCon = f.c0
        if rows:
            m.addMConstr(sp.vstack([f.A[eq], f.A[le], f.A[ge]], format="csr"), x,
                         np.repeat(["=", "<", ">"], [eq.sum(), le.sum(), ge.sum()]),
                         np.concatenate([f.row_lb[eq], f.row_ub[le], f.row_lb[ge]]))
        m.Params.TimeLimit = float(options.time_limit_s)
        m.Params.MIPGap = float(options.mip_rel_gap)
        m.Params.Threads = int(options.threads)
        if np.isfinite(options.cutoff):
            m.Params.Cutoff = float(options.cutoff)  # nothing below it: status 6, "cutoff"
        if start is not None:
            x[start.index].Start = start.value  # Gurobi completes a partial start itself
        stop = options.interrupt

        def poll(model, where) -> None:
            if stop.is_set():
                model.terminate()

        try:
            m.optimize(poll if stop is not None else None)
        except gp.GurobiError as err:
            if err.errno == gp.GRB.Error.SIZE_LIMIT_EXCEEDED:
                raise SizeLimit(_over_limit("gurobi", f, GUROBI_LIMIT, rows)) from None
            raise
        status = _GUROBI.get(m.Status, Status.ERROR)
        solved = m.SolCount > 0 and status in (Status.OPTIMAL, Status.TIME_LIMIT)
        values = np.array(x.X) if solved else None
        objective = float(m.ObjVal) if solved else np.inf
        if m.IsMIP:
            try:
                bound = float(m.ObjBound)
            except gp.GurobiError:  # no bound yet (stopped before the root finished)
                bound = -np.inf
        else:
            bound = objective if status is Status.OPTIMAL else -np.inf
        return Outcome(status, values, objective, bound, f"Gurobi status {m.Status}")


# --- CPLEX (cplex) -----------------------------------------------------------------------------

# CPLEX's solution status codes, LP (1-13) and MIP (101-132).
_CPLEX_OPTIMAL = {1, 101, 102}  # 102: optimal within the relative gap
_CPLEX_INFEASIBLE = {3, 103}
_CPLEX_UNBOUNDED = {2, 4, 118, 119}  # 4, 119: infeasible or unbounded
_CPLEX_STOPPED = {10, 11, 12, 13, 104, 105, 106, 107, 108, 111, 112, 113, 114, 131, 132}
_CPLEX_SIZE_LIMIT = 1016  # CPXERR_RESTRICTED_VERSION: over the Community Edition's limits


def cplex(f: StandardForm, options: SolveOptions, start: MipStart | None) -> Outcome:
    import cplex as cpx

    c = cpx.Cplex()
    try:
        for stream in (c.set_results_stream, c.set_log_stream, c.set_warning_stream,
                       c.set_error_stream):
            stream(None)
        inf = cpx.infinity
        mip = bool(f.integer.any())
        c.variables.add(obj=f.c.tolist(), lb=np.maximum(f.col_lb, -inf).tolist(),
                        ub=np.minimum(f.col_ub, inf).tolist(),
                        **({"types": "".join("I" if i else "C" for i in f.integer)} if mip
                           else {}))
        c.objective.set_offset(float(f.c0))
        eq, le, ge = _rows(f)
        keep = np.flatnonzero(eq | le | ge)
        sense = np.where(eq, "E", np.where(le & ge, "R", np.where(le, "L", "G")))[keep]
        rhs = np.where(le & ~ge, f.row_ub, f.row_lb)[keep]
        A = f.A
        c.linear_constraints.add(
            lin_expr=[cpx.SparsePair(A.indices[A.indptr[r]:A.indptr[r + 1]].tolist(),
                                     A.data[A.indptr[r]:A.indptr[r + 1]].tolist())
                      for r in keep],
            senses="".join(sense), rhs=rhs.tolist(),
            range_values=np.where(sense == "R", (f.row_ub - f.row_lb)[keep], 0.0).tolist())
        c.parameters.timelimit.set(float(options.time_limit_s))
        c.parameters.mip.tolerances.mipgap.set(float(options.mip_rel_gap))
        c.parameters.threads.set(int(options.threads))
        if np.isfinite(options.cutoff) and mip:  # nothing below it: status 103, "infeasible"
            c.parameters.mip.tolerances.uppercutoff.set(float(options.cutoff))
        if start is not None and mip:
            c.MIP_starts.add(cpx.SparsePair(start.index.tolist(), start.value.tolist()),
                             c.MIP_starts.effort_level.auto)
        aborter = c.use_aborter(cpx.Aborter())
        try:
            if options.interrupt is None:
                c.solve()
            else:
                with options.interrupt.watch(aborter.abort):  # an abort before the solve holds
                    c.solve()
        except cpx.exceptions.CplexSolverError as err:
            if err.args[2] == _CPLEX_SIZE_LIMIT:
                raise SizeLimit(_over_limit("cplex", f, CPLEX_LIMIT, len(keep))) from None
            raise
        sol = c.solution
        code = sol.get_status()
        status = (Status.OPTIMAL if code in _CPLEX_OPTIMAL else
                  Status.INFEASIBLE if code in _CPLEX_INFEASIBLE else
                  Status.UNBOUNDED if code in _CPLEX_UNBOUNDED else
                  Status.TIME_LIMIT if code in _CPLEX_STOPPED else Status.ERROR)
        solved = sol.is_primal_feasible() and status in (Status.OPTIMAL, Status.TIME_LIMIT)
        values = np.array(sol.get_values()) if solved else None
        objective = float(sol.get_objective_value()) if solved else np.inf
        if mip and status is not Status.INFEASIBLE:
            bound = float(sol.MIP.get_best_objective())
            bound = bound if abs(bound) < inf else np.sign(bound) * np.inf
        else:
            bound = objective if status is Status.OPTIMAL else -np.inf
        return Outcome(status, values, objective, bound,
                       f"CPLEX status {code} ({sol.get_status_string()})")
    finally:
        c.end()


# --- the solve, one way for every backend ------------------------------------------------------

# by the names of solver.BACKENDS
ADAPTERS = {"highs": highs, "scip": scip, "gurobi": gurobi, "cplex": cplex}


def solve(prog: MathematicalProgram, options: SolveOptions | None = None,
          start: Start | None = None) -> SolveResult:
    """Solve the MILP ``prog`` from an optional MIP ``start`` (default options: HiGHS)."""
    return solve_standard_form(standard_form(prog), options or SolveOptions(), start)


def solve_standard_form(f: StandardForm, options: SolveOptions,
                        start: Start | None = None) -> SolveResult:
    """Solve ``f`` with ``options.backend``; raises
    :class:`~dualarm_mpc.milp.solver.SolverUnavailable` when that backend cannot (unknown, not
    installed, unlicensed, the model over its licence's size limit)."""
    require_backend(options.backend)
    t0 = time.perf_counter()
    out = ADAPTERS[options.backend](f, options, _start(f, start))
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
