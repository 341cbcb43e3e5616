"""Planning: the program of one horizon, solved; predictT; sequential transportation (Algorithm 1).

``solve_step`` builds the MILP of one sequential step — model (``program.py``), specification
(``spec.py`` through ``encoding.py``), cost (17) and pruning — solves it and returns the step's
trajectory. ``plan_step`` raises the horizon from the reachability bound until a plan is found, and
``plan`` repeats steps until every object rests in its goal.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydrake.solvers import MathematicalProgram

from dualarm_mpc import program
from dualarm_mpc.encoding import Encoder, EncodingError, Literal
from dualarm_mpc.ltl import Atom
from dualarm_mpc.mld import POSITION_TOL, Box, Model, State, reachability, simulate
from dualarm_mpc.plan import Plan, Segment, Trajectory
from dualarm_mpc.scenario import Scenario
from dualarm_mpc.solver import (
    SolveOptions,
    StandardForm,
    Start,
    Status,
    solve,
    solve_standard_form,
    standard_form,
)
from dualarm_mpc.spec import Specification, rule_formulas, specification

log = logging.getLogger(__name__)

REST_TOL = 1e-6  # m/s: "at rest" in the model's own units


class PlanningError(RuntimeError):
    """No plan was found; the message says why (e.g. which rules conflict)."""


@dataclass(frozen=True)
class StepResult:
    """The outcome of one solve of one horizon."""

    status: Status
    horizon: int
    trajectory: Trajectory | None  # the step's objects only, as in ``spec.objects``
    cost: float
    solve_time_s: float  # wall time of the solver
    build_time_s: float
    gap: float
    binaries: int
    solution: np.ndarray | None  # raw solver values, for a MIP start
    variables: program.HorizonVariables | None = None
    message: str = ""
    bound: float = 0.0  # the solver's proven lower bound on the cost


def solver_options(scenario: Scenario, time_limit_s: float | None = None) -> SolveOptions:
    s = scenario.solver
    return SolveOptions(time_limit_s=s.time_limit_s if time_limit_s is None else time_limit_s,
                        mip_rel_gap=s.mip_rel_gap, threads=s.threads, backend=s.backend)


def _resolver(spec: Specification, x: program.HorizonVariables, state: State, scenario: Scenario):
    """Atoms of the formulas → program variables (objects outside the step are constants)."""
    local = {j + 1: n for n, j in enumerate(spec.objects)}
    goals = [Box.of(scenario.goals[o.goal]) for o in scenario.objects]

    def resolve(atom: Atom, k: int) -> Literal:
        idx = atom.index
        if atom.name == "eta" and len(idx) == 2 and idx[0] in (1, 2):
            i, j = idx
            if j in local:
                return Literal(int(x.eta[k, i - 1, local[j]]))
            if 1 <= j <= len(goals):
                return Literal(-1, constant=False)  # an object outside the step is not grabbed
        if atom.name == "theta" and len(idx) == 1:
            (j,) = idx
            if j in local:
                return Literal(int(x.theta[k, local[j]]), geometric=True)
            if 1 <= j <= len(goals):
                return Literal(-1, geometric=True,
                               constant=bool(goals[j - 1].contains(state.object_pos[j - 1])))
        raise EncodingError(
            f"unknown atom {atom}: the atoms are eta[i,j] (hand i = 1 right, 2 left, grabs "
            f"object j) and theta[j] (object j in its goal), j = 1..{len(goals)}"
        )

    return resolve


class HorizonProgram:
    """The MILP of one horizon over one step's objects, before its specification.

    The model (eqs. 1, 7–11, 14–16), pruning and cost (17) are built once as a
    MathematicalProgram and read into a standard form; :meth:`solve` adds a specification (only
    its LTL rows are encoded anew, over the same variables) and the skeleton search's
    restrictions as bounds and rows. The monolithic solve and every program of the skeleton
    search (``search.py``) go through it."""

    def __init__(self, scenario: Scenario, state: State, objects: list[int], horizon: int,
                 pruning: bool | None = None) -> None:
        self.scenario, self.state, self.horizon = scenario, state, horizon
        self.objects = list(objects)
        self.model = Model.from_scenario(scenario, self.objects)
        self.local_state = state.select(self.objects)
        reach = reachability(self.model, self.local_state, horizon)
        self.prog = MathematicalProgram()
        x = self.x = program.new_horizon_variables(self.prog, horizon, len(self.objects))
        pruning = scenario.pruning if pruning is None else pruning
        program.add_bounds(self.prog, x, self.model, self.local_state, reach, pruning)
        program.add_dynamics(self.prog, x, self.model)
        program.add_picking(self.prog, x, self.model, self.local_state, reach)
        program.add_system_constraints(self.prog, x, self.model)
        program.add_goal_atoms(self.prog, x, self.model, reach)
        self._hand_cost = program.add_cost(self.prog, x, scenario.state_weight)
        self.form = standard_form(self.prog)

    def encode(self, prog: MathematicalProgram, spec: Specification) -> None:
        """Add ``spec`` (φ_task and the rules) to ``prog``, whose first variables are ours."""
        enc = Encoder(prog, self.horizon, _resolver(spec, self.x, self.state, self.scenario))
        if spec.task_form == "counting":
            enc.require_at_least(spec.m_o, spec.events)
        else:
            enc.require(spec.task())
        for _, rule in spec.rules:
            enc.require(rule)
        enc.emit("LTL specification")

    def program(self, spec: Specification) -> MathematicalProgram:
        """The whole MILP of ``spec`` as one MathematicalProgram (for Drake's own solvers)."""
        prog = self.prog.Clone()
        self.encode(prog, spec)
        return prog

    def standard_form(self, spec: Specification, allowed: np.ndarray | None = None,
                      hands: tuple[int, ...] = (0, 1), grasp: np.ndarray | None = None,
                      floor: np.ndarray | None = None) -> StandardForm:
        """The MILP of ``spec`` in standard form, narrowed for the skeleton search:

        * ``allowed`` (2, n_step): η_ij(k ≥ 1) = 0 where false (which hand may hold what);
        * ``hands``: only these hands' force is costed (alone, the other hand moves for free,
          out of the way of eq. 16: a relaxation);
        * ``grasp`` (T+1, 2, n_step): every η fixed;
        * ``floor`` (2,): proven lower bounds on each costed hand's Σ_k ‖u_i(k)‖₁ as rows,
          which lift the LP bound (otherwise near zero)."""
        ltl = MathematicalProgram()
        ltl.NewContinuousVariables(self.prog.num_vars(), "model")
        self.encode(ltl, spec)
        f = self.form.extended(standard_form(ltl))
        c = sum(self._hand_cost[i] for i in hands)
        f.c[: len(c)] = c
        eta = self.x.eta
        if allowed is not None:
            keep = np.broadcast_to(np.asarray(allowed, bool)[None], eta[1:].shape)
            f.col_ub[eta[1:][~keep]] = 0.0
        if grasp is not None:
            f.col_lb[eta] = f.col_ub[eta] = np.asarray(grasp, float)
        if floor is not None:
            for i in hands:
                if floor[i] > 0:
                    f = f.with_row(self.x.force_abs[:, i].ravel(), lb=float(floor[i]))
        return f

    def solve(self, spec: Specification, options: SolveOptions,
              start: Callable[[program.HorizonVariables], Start] | None = None,
              **narrow) -> StepResult:
        """Solve ``spec`` (narrowed as in :meth:`standard_form`); the trajectory is
        re-simulated from the solver's forces and grasps through the model (so it is exactly
        the model's, not the solver's rounding). The cost is that of the costed hands."""
        x = self.x
        t0 = time.perf_counter()
        if options.backend == "highs":
            f = self.standard_form(spec, **narrow)
            build = time.perf_counter() - t0
            result = solve_standard_form(f, options, start(x) if start else None)
        elif narrow:
            raise ValueError("the skeleton search needs the HiGHS backend")
        else:
            prog = self.program(spec)
            build = time.perf_counter() - t0
            result = solve(prog, options, start(x) if start else None)
        binaries = int(x.binaries.size)
        if not result.status.has_solution:
            return StepResult(result.status, self.horizon, None, np.inf, result.wall_time_s,
                              build, result.gap, binaries, None, x, result.message,
                              bound=result.bound)
        values = result.x
        force = values[x.force]
        traj = simulate(self.model, self.local_state, force, np.round(values[x.eta]).astype(int))
        cost = float(np.abs(force[:, list(narrow.get("hands", (0, 1)))]).sum())
        return StepResult(result.status, self.horizon, traj, cost, result.wall_time_s, build,
                          result.gap, binaries, values, x, result.message, bound=result.bound)


def build_program(scenario: Scenario, state: State, spec: Specification, horizon: int,
                  pruning: bool | None = None):
    """The MILP of one horizon as one MathematicalProgram: model, specification, cost.
    ``state`` covers all objects. Returns the program, its variables, model and local state."""
    h = HorizonProgram(scenario, state, list(spec.objects), horizon, pruning)
    return h.program(spec), h.x, h.model, h.local_state


def solve_step(scenario: Scenario, state: State, spec: Specification, horizon: int,
               options: SolveOptions | None = None,
               start: Callable[[program.HorizonVariables], Start] | None = None,
               pruning: bool | None = None) -> StepResult:
    """Build and solve the monolithic MILP of one horizon (:meth:`HorizonProgram.solve`).
    ``start(x)`` may give a MIP start for the horizon's variables ``x``."""
    options = options or solver_options(scenario)
    t0 = time.perf_counter()
    h = HorizonProgram(scenario, state, list(spec.objects), horizon, pruning)
    build = time.perf_counter() - t0
    res = h.solve(spec, options, start)
    return dataclasses.replace(res, build_time_s=res.build_time_s + build)


def solve_horizon(scenario: Scenario, state: State, spec: Specification, horizon: int,
                  options: SolveOptions | None = None) -> StepResult:
    """The optimum of one horizon by the scenario's ``solver.search``: the skeleton search or
    the monolithic MILP (the same optimum; the search is much faster on hard steps)."""
    if scenario.solver.search == "monolithic":
        return solve_step(scenario, state, spec, horizon, options)
    from dualarm_mpc.search import search_step  # search.py builds on solve_step above

    return search_step(scenario, state, spec, horizon, options)


def predict_horizon(scenario: Scenario, state: State, spec: Specification) -> int:
    """predictT: the smallest horizon the reachability bound does not rule out (§IV-C.2) — the
    m_o-th smallest step at which an object of the step can first be in its goal."""
    objects = list(spec.objects)
    model = Model.from_scenario(scenario, objects)
    cap = scenario.solver.max_horizon
    reach = reachability(model, state.select(objects), cap)
    first = np.sort(reach.first_goal)
    return int(min(max(first[spec.m_o - 1], 1), cap))


def select_objects(scenario: Scenario, state: State, remaining: list[int]) -> list[int]:
    """Algorithm 1, line 2: the n_o remaining objects cheapest to deliver, by the distance from
    the nearer hand to the object plus the object's distance to its goal box."""
    def estimate(j: int) -> float:
        p = state.object_pos[j]
        goal = Box.of(scenario.goals[scenario.objects[j].goal])
        to_goal = np.linalg.norm(np.maximum(goal.lo - p, 0) + np.maximum(p - goal.hi, 0))
        to_hand = np.linalg.norm(state.hand_pos - p, axis=1).min()
        return float(to_hand + to_goal)

    return sorted(sorted(remaining, key=lambda j: (estimate(j), j))[: scenario.n_o])


def at_rest_in_goal(scenario: Scenario, state: State) -> np.ndarray:
    """(N,) whether each object rests inside its goal."""
    inside = np.array([
        Box.of(scenario.goals[o.goal]).contains(state.object_pos[j], 1e-9)
        for j, o in enumerate(scenario.objects)
    ])
    still = np.abs(state.object_vel).max(axis=1) <= REST_TOL
    return inside & still


def plan_step(scenario: Scenario, state: State, spec: Specification,
              options: SolveOptions | None = None,
              on_try: Callable[[StepResult], None] | None = None) -> tuple[StepResult, float]:
    """Lines 4–6 of Algorithm 1: from predictT, raise T until a plan is found (an infeasible or
    timed-out horizon counts as "not yet"). Returns the result and the step's total solve time."""
    total = 0.0
    last = None
    for T in range(predict_horizon(scenario, state, spec), scenario.solver.max_horizon + 1):
        res = solve_horizon(scenario, state, spec, T, options)
        total += res.solve_time_s + res.build_time_s
        if on_try:
            on_try(res)
        last = res
        if res.status.has_solution:
            return res, total
        if res.status is Status.ERROR:
            break
    raise PlanningError(diagnose(scenario, state, spec, last, options))


def diagnose(scenario: Scenario, state: State, spec: Specification, last: StepResult | None,
             options: SolveOptions | None) -> str:
    """Why no plan exists within the horizon cap: which rules, dropped, make the task feasible."""
    T = scenario.solver.max_horizon
    objects = [scenario.objects[j].name for j in spec.objects]
    head = (f"no plan delivering {spec.m_o} of {objects} within horizon {T} "
            f"(last status: {last.status.value if last else 'none'})")
    options = options or solver_options(scenario)
    quick = SolveOptions(time_limit_s=min(options.time_limit_s, 20.0),
                         mip_rel_gap=1.0, threads=options.threads, backend=options.backend)

    def feasible(rules) -> Status:
        s = Specification(spec.objects, spec.m_o, spec.delivery, spec.task_form, tuple(rules))
        return solve_step(scenario, state, s, T, quick).status

    alone = feasible([])
    if alone is Status.INFEASIBLE:
        return (f"{head}: the task alone is infeasible — the goals cannot be reached with "
                f"|v| <= {scenario.max_speed} and |u| <= {scenario.max_force} from this state")
    if not alone.has_solution:
        return f"{head}: the solver could not decide the task alone within its time limit"
    culprits = [name for name, f in spec.rules if not feasible([(name, f)]).has_solution]
    if culprits:
        return f"{head}: the task conflicts with rule(s) {', '.join(culprits)}"
    names = ", ".join(n for n, _ in spec.rules)
    return f"{head}: the rules {names} together conflict with the task"


def embed_step(scenario: Scenario, state: State, objects: list[int],
               local: Trajectory) -> Trajectory:
    """The step's trajectory over all objects: those outside the step stay where they are."""
    K1 = len(local.hand_pos)
    n = scenario.n_objects
    op = np.repeat(state.object_pos[None], K1, axis=0)
    ov = np.zeros((K1, n, 2))
    g = np.zeros((K1, 2, n), int)
    op[:, objects] = local.object_pos
    ov[:, objects] = local.object_vel
    g[:, :, objects] = local.grasp
    return Trajectory(local.hand_pos, local.hand_vel, local.force, op, ov, g)


def plan(scenario: Scenario, options: SolveOptions | None = None,
         progress: Callable[[Segment], None] | None = None) -> Plan:
    """Algorithm 1 (sequential transportation): plan m_o objects at a time until every object
    rests in its goal. Raises :class:`PlanningError` with the reason when a step has no plan."""
    # The oracle's tolerance: an optimal plan leaves objects on a goal's edge, give or take a
    # rounding error.

    state = State.initial(scenario)
    rules = rule_formulas(scenario)
    trajectory: Trajectory | None = None
    segments: list[Segment] = []
    delivered_step: list[int | None] = [None] * scenario.n_objects
    done = at_rest_in_goal(scenario, state)
    for j in np.flatnonzero(done):
        delivered_step[j] = 0
    for _ in range(3 * scenario.n_objects):  # each step delivers >= 1 object unless stuck
        remaining = [j for j in range(scenario.n_objects) if not done[j]]
        if not remaining:
            break
        objects = select_objects(scenario, state, remaining)
        spec = specification(scenario, objects, rules=rules)
        res, total = plan_step(scenario, state, spec, options)
        step = embed_step(scenario, state, objects, res.trajectory)
        offset = 0 if trajectory is None else trajectory.steps
        trajectory = step if trajectory is None else trajectory.then(step)
        state = State.last(step)
        now = at_rest_in_goal(scenario, state)
        newly = [j for j in objects if now[j] and not done[j]]
        for j in newly:  # the first step in the true goal box (the planner aims goal_margin in)
            goal = Box.of(scenario.goals[scenario.objects[j].goal])
            inside = np.flatnonzero(goal.contains(step.object_pos[:, j], POSITION_TOL))
            delivered_step[j] = offset + int(inside[0] if inside.size else step.steps)
        done = done | now
        seg = Segment(objects=objects, delivered=newly, horizon=res.horizon,
                      status=res.status.value, solve_time_s=total, cost=res.cost,
                      binaries=res.binaries, gap=float(res.gap))
        segments.append(seg)
        if progress:
            progress(seg)
    if not done.all():
        missing = [scenario.objects[j].name for j in np.flatnonzero(~done)]
        raise PlanningError(f"sequential transportation stalled: {missing} not delivered")
    return Plan(
        dt=scenario.dt, rule=scenario.rule, delivery=scenario.delivery,
        goals={k: list(v) for k, v in scenario.goals.items()},
        objects=[{"name": o.name, "goal": o.goal, "grasp_half_size": o.grasp_half_size}
                 for o in scenario.objects],
        workspace=list(scenario.workspace), trajectory=trajectory,
        delivered_step=delivered_step, segments=segments,
    )
