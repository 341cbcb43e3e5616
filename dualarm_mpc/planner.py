"""Planning: the program of one horizon, solved; predictT; sequential transportation (Algorithm 1).

``solve_step`` builds the MILP of one sequential step — model (``program.py``), specification
(``spec.py`` through ``encoding.py``), cost (17) and pruning — solves it and returns the step's
trajectory. ``plan_step`` raises the horizon from the reachability bound until a plan is found, and
``plan`` repeats steps until every object rests in its goal.
"""

from __future__ import annotations

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
from dualarm_mpc.solver import SolveOptions, SolveResult, Start, Status, solve
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


def build_program(scenario: Scenario, state: State, spec: Specification, horizon: int,
                  pruning: bool | None = None, allowed: np.ndarray | None = None,
                  hands: tuple[int, ...] = (0, 1), grasp: np.ndarray | None = None,
                  floor: np.ndarray | None = None):
    """The MILP of one horizon: model, specification, cost. ``state`` covers all objects.

    The skeleton search (``search.py``) narrows it: ``allowed`` (2, n_step) says which hand may
    hold which of the step's objects; with one hand in ``hands`` only that hand's force is costed
    (the other hand moves for free, out of the way of eq. 16: a relaxation); ``grasp``
    (T+1, 2, n_step) fixes every η, and ``floor`` bounds each hand's cost from below
    (:func:`program.add_cost`)."""
    pruning = scenario.pruning if pruning is None else pruning
    objects = list(spec.objects)
    model = Model.from_scenario(scenario, objects)
    local_state = state.select(objects)
    prog = MathematicalProgram()
    reach = reachability(model, local_state, horizon)
    x = program.new_horizon_variables(prog, horizon, len(objects))
    program.add_bounds(prog, x, model, local_state, reach, pruning, allowed, grasp)
    program.add_dynamics(prog, x, model)
    program.add_picking(prog, x, model, local_state, reach)
    program.add_system_constraints(prog, x, model)
    program.add_goal_atoms(prog, x, model, reach)
    program.add_cost(prog, x, scenario.state_weight, hands, floor)
    enc = Encoder(prog, horizon, _resolver(spec, x, state, scenario))
    if spec.task_form == "counting":
        enc.require_at_least(spec.m_o, spec.events)
    else:
        enc.require(spec.task())
    for _, rule in spec.rules:
        enc.require(rule)
    enc.emit("LTL specification")
    return prog, x, model, local_state


def solve_step(scenario: Scenario, state: State, spec: Specification, horizon: int,
               options: SolveOptions | None = None,
               start: Callable[[program.HorizonVariables], Start] | None = None,
               pruning: bool | None = None, allowed: np.ndarray | None = None,
               hands: tuple[int, ...] = (0, 1), grasp: np.ndarray | None = None,
               floor: np.ndarray | None = None) -> StepResult:
    """Build and solve one horizon; the trajectory is re-simulated from the solver's forces and
    grasps through the model (so it is exactly the model's, not the solver's rounding).
    ``start(x)`` may give a MIP start for the horizon's variables ``x``; ``allowed``, ``hands``,
    ``grasp`` and ``floor`` narrow the program as in :func:`build_program`. The cost is that of
    ``hands``."""
    options = options or solver_options(scenario)
    t0 = time.perf_counter()
    prog, x, model, local_state = build_program(scenario, state, spec, horizon, pruning, allowed,
                                                hands, grasp, floor)
    build = time.perf_counter() - t0
    result: SolveResult = solve(prog, options, start(x) if start else None)
    binaries = int(x.binaries.size)
    if not result.status.has_solution:
        return StepResult(result.status, horizon, None, np.inf, result.wall_time_s, build,
                          result.gap, binaries, None, x, result.message, bound=result.bound)
    values = result.x
    grasp = np.round(values[x.eta]).astype(int)
    force = values[x.force]
    traj = simulate(model, local_state, force, grasp)
    cost = float(np.abs(force[:, list(hands)]).sum())
    return StepResult(result.status, horizon, traj, cost, result.wall_time_s, build, result.gap,
                      binaries, values, x, result.message, bound=result.bound)


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
