"""MPC planner: the MILP planner inside the Diagram, replanning receding-horizon every Δt.

Each Δt a periodic unrestricted update reads the measured state and re-solves the current
sequential step from it (Algorithm 1, one step at a time):

* the grasp in force for the next Δt is the one the previous plan committed to, so the new plan's
  η(0) is that (a decision takes effect one step after it is made, as in the model's k = 0);
* an object is *delivered* when it rests (speed below ``REST_SPEED``) inside its goal, unheld;
  the step ends when m_o of its objects are delivered, and the next step selects new objects;
* within a step every replan takes the shortest feasible horizon from the measured state (so the
  plan cannot idle and the step arrives), MIP-started from the previous plan's grasps shifted by
  one step;
* real time: a replan holds the simulation for ``solver.replan_budget_s`` of wall time at most
  (0.4 Δt by default). The search runs on a worker thread; past the budget the robot follows the
  plan in force. While the robot waits at rest with no plan left (the first replan of a step),
  the search goes on over the next periods and its plan starts when it ends ("searching"); while
  the robot moves, the late search is stopped ("over_budget") and the next period plans afresh;
* a solver time-out, an infeasible horizon or any error keeps the previous plan; every replan's
  wall time, status and cost are recorded in the state. Nothing raises inside the simulation.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.horizon import StepResult, solver_options
from dualarm_mpc.mld import Model, Rect, State, reachability
from dualarm_mpc.plan import TimedTrajectory
from dualarm_mpc.scenario import Scenario
from dualarm_mpc.sequential import embed_step, predict_horizon, select_objects, solve_horizon
from dualarm_mpc.solver import Interrupt, SolveOptions, Status
from dualarm_mpc.spec import Specification, rule_formulas, specification
from dualarm_mpc.systems.interpolator import empty_plan, sample_grasp
from dualarm_mpc.systems.state_estimator import split_measured_state

log = logging.getLogger(__name__)

REST_SPEED = 0.01  # m/s: an object slower than this counts as resting
STILL_SPEED = 0.005  # m/s: slower than this, an unheld object's velocity is measurement noise
SNAP_POSITION = 0.02  # m: within this of the plan, a replan starts from the plan's own state
SNAP_VELOCITY = 0.05  # m/s
GRASP_SLACK = 0.02  # m: a committed grasp stands while the hand is this close to the grasp box
# The share of a control period a replan may hold the simulation for: the plant's own simulation
# of §V-D takes about half of real time, so 0.4 Δt keeps the loop at least real time.
BUDGET_SHARE = 0.4


@dataclass(frozen=True)
class Replan:
    """One replan, as recorded."""

    t: float
    wall_s: float
    status: str
    cost: float | None
    horizon: int | None
    objects: tuple[int, ...]
    delivered: int  # objects resting in their goals when it ran
    note: str = ""


@dataclass(frozen=True)
class MpcState:
    """The planner's abstract state: the plan in force and the sequential step it serves."""

    plan: TimedTrajectory
    goals: dict[str, list[float]]
    step_objects: tuple[int, ...] = ()
    step_target: int = 0  # delivered count at which the current step is done
    horizon_end: float = 0.0  # sim time at the end of the current plan's horizon
    # The last plan's step objects and their η, (T+1, 2, n): the next replan's MIP start.
    grasp_start: tuple[tuple[int, ...], np.ndarray] | None = None
    delivered_time: tuple[float | None, ...] = ()
    replans: tuple[Replan, ...] = field(default_factory=tuple)


class MpcPlanner(LeafSystem):
    """Receding-horizon LTL planner (the paper's planner in closed loop).

    .. pydrake_system::

        name: MpcPlanner
        input_ports:
        - measured_state
        output_ports:
        - plan

    ``measured_state`` (8 + 6N): the StateEstimator's layout. ``plan``: the
    :class:`~dualarm_mpc.plan.TimedTrajectory` in force (abstract), read from the state.
    """

    def __init__(self, scenario: Scenario, time_limit_s: float | None = None):
        super().__init__()
        self._scenario = scenario
        self._options = solver_options(scenario, time_limit_s)
        # Wall time a replan may hold the simulation: one control period at most.
        budget = scenario.solver.replan_budget_s
        self._budget_s = BUDGET_SHARE * scenario.dt if budget is None else budget
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="mpc-search")
        self._pending: tuple[_Job, Future] | None = None  # a search carried over
        self._rules = rule_formulas(scenario)
        n = scenario.n_objects
        initial = MpcState(
            plan=empty_plan(n, np.array(scenario.hand_start)),
            goals={k: list(v) for k, v in scenario.goals.items()},
            delivered_time=(None,) * n,
        )
        self._state = self.DeclareAbstractState(AbstractValue.Make(initial))
        self._measured = self.DeclareVectorInputPort("measured_state", 8 + 6 * n)
        self._plan = self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(initial.plan), self._calc_plan,
            prerequisites_of_calc={self.abstract_state_ticket(self._state)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(scenario.dt, 0.0, self._update)

    def close(self) -> None:
        """Stop a search still running in the background (the simulation is over)."""
        self._abandon()
        self._worker.shutdown(wait=False, cancel_futures=True)

    def get_measured_state_input_port(self):
        return self._measured

    def get_plan_output_port(self):
        return self._plan

    def mpc_state(self, context) -> MpcState:
        return context.get_abstract_state(self._state).get_value()

    def set_goal(self, context, name: str, box: list[float]) -> None:
        """Move a goal (an environment change); the planner sees it at its next replan."""
        s = self.mpc_state(context)
        goals = {**s.goals, name: list(box)}
        context.get_mutable_abstract_state(self._state).set_value(
            dataclasses.replace(s, goals=goals))

    def _calc_plan(self, context, output) -> None:
        output.set_value(self.mpc_state(context).plan)

    # -- the replan ---------------------------------------------------------------------------

    def _update(self, context, state) -> None:
        t = context.get_time()
        s = self.mpc_state(context)
        wall0 = time.perf_counter()
        try:
            new = self._replan(t, s, self._measured.Eval(context), wall0)
        except Exception as err:  # a replan must never stop the simulation
            log.exception("replan at t=%.2f failed", t)
            self._abandon()
            new = self._record(s, t, wall0, "error", note=f"{type(err).__name__}: {err}")
        state.get_mutable_abstract_state(self._state).set_value(new)

    def _record(self, s: MpcState, t: float, wall0: float, status: str,
                res: StepResult | None = None, note: str = "", **changes) -> MpcState:
        delivered = sum(d is not None for d in changes.get("delivered_time", s.delivered_time))
        r = Replan(t=t, wall_s=time.perf_counter() - wall0, status=status,
                   cost=None if res is None or res.trajectory is None else res.cost,
                   horizon=None if res is None else res.horizon,
                   objects=changes.get("step_objects", s.step_objects), delivered=delivered,
                   note=note)
        return dataclasses.replace(s, replans=s.replans + (r,), **changes)

    def _replan(self, t: float, s: MpcState, measured: np.ndarray, wall0: float) -> MpcState:
        """Wait at most the budget for a plan; past it, follow the plan in force and let the
        search go on in the background while the robot waits at rest (carried over to the next
        periods), or stop it while the robot moves (its start state is gone by then)."""
        if self._pending is not None:
            job, future = self._pending
            if job.scenario.goals != s.goals or not self._still(job, measured):
                self._abandon()  # the world moved on: plan afresh below
            elif not _wait(future, self._budget_s):
                return self._record(s, t, wall0, "searching", note=SEARCHING, **job.changes)
            else:
                self._pending = None
                return self._adopt(s, job, future.result(), t, wall0)
        prepared = self._prepare(t, s, measured, wall0)
        if isinstance(prepared, MpcState):
            return prepared
        job = prepared
        future = self._worker.submit(self._solve, job)
        if _wait(future, self._budget_s):
            return self._adopt(s, job, future.result(), t, wall0)
        if job.idle:
            self._pending = (job, future)
            return self._record(s, t, wall0, "searching", note=SEARCHING, **job.changes)
        job.options.interrupt.set()
        return self._record(s, t, wall0, "over_budget", note="kept the previous plan",
                            **job.changes)

    def _abandon(self) -> None:
        if self._pending is not None:
            self._pending[0].options.interrupt.set()
            self._pending = None

    def _prepare(self, t: float, s: MpcState, measured: np.ndarray, wall0: float):
        """What the replan at ``t`` must solve (a :class:`_Job`), or the new state at once when
        nothing is left to solve (every object delivered, or the rest out of reach)."""
        sc = dataclasses.replace(self._scenario, goals=s.goals)
        state = self._committed_state(t, s, measured)
        resting = self._resting(sc, state, exhausted=t >= s.horizon_end - 1e-9)
        delivered_time = tuple((t if d is None else d) if r else None
                               for d, r in zip(s.delivered_time, resting, strict=True))
        # A thrown object still sliding into its goal needs nothing more from the robot.
        done = resting | self._arriving(sc, state)
        n_done = int(np.sum(done))
        lost = self._lost(sc, state) & ~done
        remaining = [j for j in range(sc.n_objects) if not done[j] and not lost[j]]
        if not remaining and lost.any():
            names = ", ".join(sc.objects[j].name for j in np.flatnonzero(lost))
            return self._record(s, t, wall0, "stuck", plan=_hold(t, sc.dt, state),
                                step_objects=(), delivered_time=delivered_time,
                                note=f"{names} can no longer reach the goal")
        if not remaining:
            return self._record(s, t, wall0, "done", plan=_hold(t, sc.dt, state),
                                step_objects=(), delivered_time=delivered_time)
        new_step = (not s.step_objects or n_done >= s.step_target
                    or not set(s.step_objects) & set(remaining))
        if new_step:
            objects = select_objects(sc, state, remaining)
            target = n_done + min(sc.m_o, len(objects))
            grasp_start = None
        else:
            # Delivered ones leave the step (a hand still holding one lets go): else they would
            # satisfy φ_task again and the step would never move on.
            objects = [j for j in s.step_objects if j in remaining]
            target = s.step_target
            grasp_start = s.grasp_start
        spec = specification(sc, objects, rules=self._rules)
        spec = dataclasses.replace(spec, m_o=max(1, min(spec.m_o, target - n_done)))
        start = _shifted_start(*grasp_start, objects) if grasp_start is not None else None
        # At rest with no plan left: a search that outlasts the budget still applies when it
        # ends, so it may go on (from exactly at rest: the controller absorbs the noise).
        idle = bool(t >= s.horizon_end - 1e-9
                    and np.abs(state.hand_vel).max(initial=0) < SNAP_VELOCITY
                    and np.abs(state.object_vel).max(initial=0) < SNAP_VELOCITY)
        if idle:
            state = dataclasses.replace(state, hand_vel=np.zeros_like(state.hand_vel),
                                        object_vel=np.zeros_like(state.object_vel))
        changes = dict(delivered_time=delivered_time, step_objects=tuple(objects),
                       step_target=target)
        options = dataclasses.replace(self._options, interrupt=Interrupt())
        return _Job(sc, state, spec, start, options, idle, changes)

    @staticmethod
    def _solve(job: _Job) -> StepResult | None:
        """The shortest feasible horizon (with cost (17) alone, a longer horizon lets the plan
        idle first, and a receding horizon would then never arrive); runs on the worker."""
        wall0 = time.perf_counter()
        res = None
        sc, state, spec = job.scenario, job.state, job.spec
        for T in range(predict_horizon(sc, state, spec), sc.solver.max_horizon + 1):
            res = solve_horizon(sc, state, spec, T, job.options, start=job.start)
            if res.status is not Status.INFEASIBLE or job.options.interrupt.is_set():
                break
            if time.perf_counter() - wall0 > job.options.time_limit_s:
                break
        return res

    def _adopt(self, s: MpcState, job: _Job, res: StepResult | None, t: float,
               wall0: float) -> MpcState:
        """The plan of a finished search, starting now (a search carried over started from a
        state the robot still holds at rest)."""
        sc = job.scenario
        if res is None or not res.status.has_solution:
            status = res.status.value if res else "no_horizon"
            return self._record(s, t, wall0, status, res, note="kept the previous plan",
                                **job.changes)
        objects = list(job.spec.objects)
        traj = embed_step(sc, job.state, objects, res.trajectory)
        plan = TimedTrajectory(t, sc.dt, traj)
        return self._record(s, t, wall0, res.status.value, res, plan=plan,
                            horizon_end=t + res.horizon * sc.dt,
                            grasp_start=(tuple(objects), res.trajectory.grasp),
                            **job.changes)

    def _still(self, job: _Job, measured: np.ndarray) -> bool:
        """Whether the robot and the objects still rest where the search carried over started."""
        m = split_measured_state(measured, self._scenario.n_objects)
        pos = np.concatenate([m["hand_pos"], m["object_pos"]])
        was = np.concatenate([job.state.hand_pos, job.state.object_pos])
        speed = np.abs(np.concatenate([m["hand_vel"], m["object_vel"]])).max(initial=0)
        return bool(np.abs(pos - was).max(initial=0) < SNAP_POSITION and speed < SNAP_VELOCITY)

    def _committed_state(self, t: float, s: MpcState, measured: np.ndarray) -> State:
        """The state a replan starts from: the measured one, with the grasp the previous plan
        committed to for [t, t + Δt).

        Where a hand or an object is within ``SNAP_POSITION`` / ``SNAP_VELOCITY`` of where the
        previous plan put it, the plan's own (nominal) value is used: the controller absorbs
        millimetre tracking errors, and the shifted plan stays feasible (otherwise tight plans —
        throws at full speed from the edge of the hand range — turn infeasible by a hair at every
        replan and the robot dithers). Larger deviations (a knock, a short throw, a failed grasp)
        are taken as measured. Unheld objects slower than ``STILL_SPEED`` are at rest."""
        sc = self._scenario
        m = split_measured_state(measured, sc.n_objects)
        ws = Rect.of(sc.workspace)
        hand_pos = np.clip(m["hand_pos"], ws.lo, ws.hi)
        hand_vel = np.clip(m["hand_vel"], -sc.max_speed, sc.max_speed)
        obj_pos, obj_vel = m["object_pos"].copy(), m["object_vel"].copy()
        obj_vel[np.linalg.norm(obj_vel, axis=1) < STILL_SPEED] = 0.0
        k = int(np.floor((t - s.plan.t0) / s.plan.dt + 1e-9))
        traj = s.plan.trajectory
        if 0 <= k < len(traj.hand_pos) and s.step_objects:
            # Hands on position alone: at a release the interpolator deliberately keeps the
            # hand at the previous step's speed (the throw), so its velocity differs by design.
            close = np.abs(hand_pos - traj.hand_pos[k]).max(axis=1) < SNAP_POSITION
            hand_pos[close], hand_vel[close] = traj.hand_pos[k][close], traj.hand_vel[k][close]
            close = ((np.abs(obj_pos - traj.object_pos[k]).max(axis=1) < SNAP_POSITION)
                     & (np.abs(obj_vel - traj.object_vel[k]).max(axis=1) < SNAP_VELOCITY))
            obj_pos[close], obj_vel[close] = traj.object_pos[k][close], traj.object_vel[k][close]
        if t < s.horizon_end - 1e-9:
            grasp = sample_grasp(s.plan, t).reshape(2, sc.n_objects).round().astype(int)
        else:  # the plan is over: what the gripper holds
            grasp = m["grasp"].round().astype(int)
        # A grasp of an object no longer at the hand (knocked away, or never caught) is void.
        half = np.array([o.grasp_half_size for o in sc.objects])
        reach = np.abs(m["hand_pos"][:, None] - obj_pos[None]).max(axis=2)  # (2, N)
        grasp[reach > half[None] + GRASP_SLACK] = 0
        for i, j in zip(*np.nonzero(grasp), strict=True):
            obj_vel[j] = hand_vel[i]  # held: moves with its hand (eq. 8)
        return State(hand_pos, hand_vel, obj_pos, obj_vel, grasp)

    @staticmethod
    def _lost(sc: Scenario, state: State) -> np.ndarray:
        """Objects that reachability proves can never reach their goals (e.g. knocked or thrown
        short beyond the hands' reach): left out so that the others still get delivered."""
        model = Model.from_scenario(sc)
        reach = reachability(model, state, sc.solver.max_horizon)
        return reach.first_goal > sc.solver.max_horizon

    @staticmethod
    def _arriving(sc: Scenario, state: State) -> np.ndarray:
        """Unheld objects whose one-step slide (the model's, and the table's v·τ) ends inside
        their goals."""
        landing = state.object_pos + sc.dt * state.object_vel
        inside = np.array([Rect.of(sc.goals[o.goal]).contains(landing[j])
                           for j, o in enumerate(sc.objects)])
        moving = np.linalg.norm(state.object_vel, axis=1) > 0
        return inside & moving & ~state.grasp.any(axis=0)

    @staticmethod
    def _resting(sc: Scenario, state: State, exhausted: bool) -> np.ndarray:
        """Objects at rest inside their goals; one still held counts once its plan is over (the
        hand stopped there and lets go when it moves on)."""
        inside = np.array([Rect.of(sc.goals[o.goal]).contains(state.object_pos[j])
                           for j, o in enumerate(sc.objects)])
        slow = np.linalg.norm(state.object_vel, axis=1) < REST_SPEED
        return inside & slow & (exhausted | ~state.grasp.any(axis=0))


SEARCHING = "over budget: the robot waits at rest while the search goes on"


@dataclass(frozen=True)
class _Job:
    """One replan's search: what to solve, from which state, and how to stop it."""

    scenario: Scenario  # with the goals the replan saw
    state: State
    spec: Specification
    start: Callable | None  # MIP start for the monolithic MILP
    options: SolveOptions  # with the Interrupt that stops it
    idle: bool  # the robot rests with no plan left: a late result still applies
    changes: dict  # the bookkeeping to record with the replan


def _wait(future: Future, timeout_s: float) -> bool:
    try:
        future.result(timeout=timeout_s)
    except FutureTimeout:
        return False
    return True


def _hold(t: float, dt: float, state: State) -> TimedTrajectory:
    """A plan of one step: both hands at rest where they are, nothing held."""
    plan = empty_plan(len(state.object_pos), state.hand_pos)
    traj = dataclasses.replace(plan.trajectory, object_pos=state.object_pos[None].copy())
    return TimedTrajectory(t, dt, traj)


def _shifted_start(previous: tuple[int, ...], grasp: np.ndarray, objects: list[int]):
    """A MIP start from the previous plan's grasps, one step on (binaries only; HiGHS completes
    the rest), for the step's objects that were in the previous plan."""
    where = {j: n for n, j in enumerate(previous)}

    def start(x):
        index, value = [], []
        K = len(grasp) - 1
        for n_new, j in enumerate(objects):
            if j not in where:
                continue
            for k in range(1, x.horizon + 1):
                index.append(x.eta[k, :, n_new])
                value.append(grasp[min(k + 1, K), :, where[j]])
        if not index:
            return np.zeros(0, int), np.zeros(0)
        return np.concatenate(index), np.concatenate(value).astype(float)

    return start
