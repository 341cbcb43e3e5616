"""The MPC core: one replan, from the measured state, the goals and the previous plan to a new
plan and its record — plain Python, no Drake system (``systems/mpc_planner.py`` wraps it).

Each Δt the closed loop calls :meth:`Replanner.step` and re-solves the current sequential step
from the measured state (Algorithm 1, one step at a time):

* the grasp in force for the next Δt is the one the previous plan committed to, so the new plan's
  η(0) is that (a decision takes effect one step after it is made, as in the model's k = 0);
* an object is *delivered* when it is at rest on the robot (``mld.REST_SPEED``) in its goal,
  unheld (``delivery.py`` decides which are); the step ends when m_o of its objects are
  delivered, and the next step selects new objects;
* within a step every replan takes the shortest feasible horizon from the measured state (so the
  plan cannot idle and the step arrives), MIP-started from the previous plan's grasps shifted by
  one step;
* lockstep (the default): a replan runs to its end in the caller, and no solve stops by wall
  time (a program stops at ``solver.replan_node_limit`` branch-and-bound nodes, the replan's
  search, over all its horizons, at ``solver.replan_program_limit`` programs instead), so the
  replan is a function of its inputs alone, on any machine and under any load;
* real time (``solver.realtime``): a replan holds the caller for ``solver.replan_budget_s`` of
  wall time at most (0.4 Δt by default). The search runs on a worker thread
  (``replan_worker.py``); past the budget the robot follows the plan in force. While the robot
  waits at rest with no plan left (the first replan of a step), the search goes on over the next
  periods and its plan starts when it ends ("searching"); while the robot moves, the late search
  is stopped ("over_budget") and the next period plans afresh. What the robot does then depends
  on the machine;
* the next sequential step is planned ahead while the current one runs, from the state the plan
  in force predicts at its end (delivered set, the hands' end states); the replan at that end
  adopts it where the state it starts from matches the prediction within the tolerances a replan
  snaps to the plan in force by, and searches afresh otherwise. In real time it runs on a
  thread of its own, in lockstep in the replan that made the plan;
* anytime (real time): where the robot would wait at rest for a search past its budget, the same
  step with m_o = 1 is searched beside it, and its plan, the first to end, moves the robot at
  once (the search for the whole step is then dropped: its start is gone); the step's other
  objects are planned from where that plan ends;
* a replan may plan from later than now: with a latency L (the time the computer needs), the
  replan at t plans from the measured state carried L on by the plan in force's inputs through
  the model, and its plan starts at t + L (:meth:`Replanner.step`);
* a replan from exactly the state the plan in force reaches now, when that plan was proven
  optimal for the same step and goals, keeps it without a search ("kept"): by the principle of
  optimality its rest is the replan's optimum (:meth:`!Replanner._on_proven_plan`);
* a solver time-out, an infeasible horizon or any error keeps the previous plan; every replan
  returns its record (:class:`Replan`: wall time, status, cost). Nothing raises.

The state (:class:`MpcState`) is a frozen value the caller keeps (the LeafSystem keeps it in its
Context); the replan log is the caller's to keep. In real time, a search carried over to the next
periods and the worker thread that runs it are the :class:`Replanner`'s, never in that state.

Why one module of this length: the replan, the next step planned ahead and the state a replan
starts from are one Replanner's, over one :class:`MpcState`, one worker and one ``_prepare``;
apart, each would reach into the others' private parts.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np

from dualarm_mpc.logic.evaluate import evaluate
from dualarm_mpc.milp.horizon import StepResult, solve_options
from dualarm_mpc.milp.solver import Interrupt, SolveOptions, Status, WorkLimit
from dualarm_mpc.model.mld import (
    POSITION_TOL,
    Model,
    Rect,
    State,
    replay,
    standing,
)
from dualarm_mpc.model.plan import TimedTrajectory, empty_plan, sample_grasp, step_at
from dualarm_mpc.model.scenario import Scenario, seconds_problem
from dualarm_mpc.model.spec import RULE_TEXT, StepProblem, rule_formulas, specification
from dualarm_mpc.model.verify import atom_trace
from dualarm_mpc.planning import delivery
from dualarm_mpc.planning.replan_worker import ReplanWorker, Search
from dualarm_mpc.planning.sequential import (
    embed_step,
    predict_horizon,
    select_objects,
    solve_horizon,
)

log = logging.getLogger(__name__)

# How far the measured state may be from the plan's and still count as on it (:class:`Tolerances`),
# in boxes (table.object_size) and boxes per Δt: within SNAP_POSITION and SNAP_VELOCITY of the
# plan, a replan starts from the plan's own state; an unheld object slower than STILL_SPEED is at
# rest (its speed is measurement noise).
SNAP_POSITION = 0.4
SNAP_VELOCITY = 1.0
STILL_SPEED = 0.1
# m: a committed grasp stands while the hand is this close to the grasp box. The robot's own
# tracking (a held box strays up to 9 mm from a Panda's tool, docs/robots.md), not the scene's
# size, decides it.
GRASP_SLACK = 0.02


@dataclass(frozen=True)
class Tolerances:
    """The tolerances above in the scene's own units (m, m/s): with the paper's 5 cm boxes and
    Δt = 1 s, 2 cm, 0.05 m/s and 5 mm/s. A scene scaled to a smaller robot keeps them in
    proportion: fixed, 2 cm was a quarter of a quarter-scale goal's width, and snapped a box
    shoved 6 mm out of its goal back into it, where every replan then had nothing to do
    (measured: the SCARA on ``panda_vd``, rule 2, seed 1). Below the on-robot goal margin
    (0.6 of a box, docs/scenarios.md), a box snapped to where its plan left it is in its goal
    only where it truly is."""

    snap_position: float
    snap_velocity: float
    still_speed: float

    @staticmethod
    def of(scenario: Scenario) -> Tolerances:
        size, speed = scenario.table.object_size, scenario.table.object_size / scenario.robot.dt
        return Tolerances(SNAP_POSITION * size, SNAP_VELOCITY * speed, STILL_SPEED * speed)


# Lockstep: the time limit of every solve, long enough never to be reached (a wall-clock limit
# would make the plan depend on the machine), finite for the backends that refuse infinity; what
# bounds a solve instead is ``solver.replan_node_limit``, a count of branch-and-bound nodes.
NO_TIME_LIMIT_S = 1e7
SEARCHING = "over budget: the robot waits at rest while the search goes on"
ON_PROVEN_PLAN = "on the proven plan: its rest is the replan's optimum"
PLANNED_AHEAD = "planned ahead while the last step ran"
ONE_FIRST = "one object first: the search for the whole step outlasted its budget"
_ON_GRID = 1e-6  # of a step: a replan at the plan's step k exactly

# solve(problem, T, options, start=...) -> StepResult: one horizon's solve (problem: StepProblem).
Solve = Callable[..., StepResult]
Goals = dict[str, list[float]]  # goal name → box [xmin, xmax, ymin, ymax]


@dataclass(frozen=True)
class Replan:
    """One replan, as recorded."""

    t: float
    wall_s: float
    status: str
    cost: float | None
    horizon: int | None
    objects: tuple[int, ...]
    n_delivered: int  # objects resting in their goals when it ran
    note: str = ""
    start: float | None = None  # when its plan starts: t + the replan's latency
    adopted: bool = False  # it put a new plan in force


@dataclass(frozen=True)
class MpcState:
    """The planner's state: the plan in force and the sequential step it serves."""

    plan: TimedTrajectory
    step_objects: tuple[int, ...] = ()
    step_target: int = 0  # delivered count at which the current step is done
    horizon_end: float = 0.0  # sim time at the end of the current plan's horizon
    # The last plan's step objects and their η, (T+1, 2, n): the next replan's MIP start.
    grasp_start: tuple[tuple[int, ...], np.ndarray] | None = None
    delivered_time: tuple[float | None, ...] = ()
    # What the plan in force was proven optimal for (:func:`_step_key`), or None.
    proven: tuple | None = None
    # Where the objects outside the plan's step stood when it was made (``mld.standing``): the
    # boxes its objects keep clear of, (C1)–(C2).
    standing: tuple[np.ndarray, np.ndarray] | None = None


class Replanner:
    """The receding-horizon planner of the closed loop, one :meth:`step` per Δt.

    ``solve`` is one horizon's solve (``sequential.solve_horizon`` by default; a test may pass
    one that fails). ``time_limit_s`` overrides the scenario's per-solve limit in real time;
    lockstep has none."""

    def __init__(self, scenario: Scenario, time_limit_s: float | None = None,
                 solve: Solve | None = None) -> None:
        problem = None if time_limit_s is None else seconds_problem(time_limit_s)
        if problem:
            raise ValueError(f"time_limit_s: {problem}")
        scenario.validate()
        self._scenario = scenario
        self.tolerances = Tolerances.of(scenario)
        self.realtime = scenario.solver.realtime
        self._options = solve_options(scenario, time_limit_s if self.realtime
                                       else NO_TIME_LIMIT_S)
        if not self.realtime:
            self._options = dataclasses.replace(self._options,
                                                node_limit=scenario.solver.replan_node_limit)
        self._solve_horizon = solve_horizon if solve is None else solve
        # Real time: the worker that searches within the budget, and on while the robot waits.
        self._worker = ReplanWorker(scenario) if self.realtime else None
        self._rules = rule_formulas(scenario)
        # The paper's rules look at most two steps ahead, which the model's state fixes (see
        # _on_proven_plan); a user rule may look anywhere, so with one every replan searches.
        self._keep_proven = all(name in RULE_TEXT for name, _ in self._rules)
        self._ahead: _Ahead | None = None  # the next sequential step, planned ahead
        # Real time: beside a search the robot waits for, the same step with m_o = 1
        self._quick: tuple[_Job, Future] | None = None

    def initial_state(self) -> MpcState:
        sc = self._scenario
        return MpcState(plan=empty_plan(sc.n_objects, np.array(sc.robot.hand_start)),
                        delivered_time=(None,) * sc.n_objects)

    @property
    def search(self) -> Search | None:
        """Real time: the search carried over to the next periods, if any."""
        return None if self._worker is None else self._worker.search

    def pace(self, rate: float) -> None:
        """Real time at ``rate`` × real time: the wall-time budget of a replan stretches with
        it (the same share of a control period)."""
        if self._worker is not None:
            self._worker.pace(rate)

    def close(self) -> None:
        """Stop the searches running, if any, and the worker (the run is over)."""
        self._drop_ahead()
        self._drop_quick()
        if self._worker is not None:
            self._worker.close()

    def step(self, t: float, state: MpcState, measured: State, goals: Goals,
             latency: float = 0.0, wait: bool = False) -> tuple[MpcState, Replan]:
        """The replan at time ``t``: the new state (its plan starts at ``t + latency``, from the
        measured state carried ``latency`` on by the plan in force, :meth:`propagated`) and the
        record. ``wait``: in real time, wait for the search up to the time limit of one solve if
        that is longer than the budget (the first plan, before the clock starts)."""
        wall0 = time.perf_counter()
        goals = {k: list(v) for k, v in goals.items()}
        start = t + latency
        try:
            if latency > 0:
                measured = self.propagated(t, state, measured, latency)
            new, r = self._replan(start, state, measured, goals, wall0, wait)
        except Exception as err:  # a replan must never stop the simulation
            log.exception("replan at t=%.2f failed", t)
            if self._worker is not None:
                self._worker.abandon()
            self._drop_ahead()
            new, r = _record(state, t, wall0, "error", note=f"{type(err).__name__}: {err}")
        return new, dataclasses.replace(r, t=t, start=start)

    def propagated(self, t: float, s: MpcState, m: State, latency: float) -> State:
        """Where the robot will be when the replan's plan takes over, ``latency`` after ``t``:
        the state a replan at ``t`` would start from (:meth:`!_committed_state`: the plan in
        force's own where the measurement matches it, the measurement where it has left it)
        carried on through the model (eqs. 1, 8 and the one-step slide,
        :func:`~dualarm_mpc.model.mld.replay`) by the plan in force's force and grasps over that
        time; nothing held and no force once the plan is over, and a grasp voided at ``t`` (the
        object gone from the hand) stays void."""
        sc = self._scenario
        n = sc.n_objects
        now = self._committed_state(t, s, m)
        k, _ = step_at(s.plan, t)
        forces = s.plan.trajectory.force
        planned = t < s.horizon_end - 1e-9 and 0 <= k < len(forces)
        force = forces[k] if planned else np.zeros((2, 2))
        later = now.grasp
        if t + latency < s.horizon_end - 1e-9:
            later = sample_grasp(s.plan, t + latency).reshape(2, n).round().astype(int)
            if planned:
                was = sample_grasp(s.plan, t).reshape(2, n).round().astype(int)
                later = later * ~((was == 1) & (now.grasp == 0))
        model = dataclasses.replace(Model.from_scenario(sc), dt=latency)
        return State.last(replay(model, now, force[None], np.stack([now.grasp, later])))

    # -- the replan ---------------------------------------------------------------------------

    def _replan(self, t: float, s: MpcState, measured: State, goals: Goals,
                wall0: float, wait: bool = False) -> tuple[MpcState, Replan]:
        """Lockstep: solve to the end. Real time: wait at most the budget for a plan; past it,
        follow the plan in force and let the search go on in the background while the robot
        waits at rest (carried over to the next periods), or stop it while the robot moves (its
        start state is gone by then)."""
        worker = self._worker
        if self.search is not None:
            job, future = self.search.job, self.search.future
            if job.problem.scenario.task.goals != goals or not self._still(job, measured):
                worker.abandon()  # the world moved on: plan afresh below
                self._drop_quick()
            elif not worker.within_budget(future):
                quick = self._quick_plan()
                if quick is not None:  # anytime: move now, the step's rest planned on the way
                    worker.abandon()
                    return self._adopt(s, dataclasses.replace(quick[0], changes=job.changes),
                                       quick[1], t, wall0, ONE_FIRST)
                return _record(s, t, wall0, "searching", note=SEARCHING, **job.changes)
            else:
                worker.take()
                self._drop_quick()
                return self._adopt(s, job, future.result(), t, wall0)
        prepared = self._prepare(t, s, measured, goals, wall0)
        if not isinstance(prepared, _Job):
            return prepared
        job = prepared
        ahead = self._take_ahead(t, job)
        if ahead is not None:
            planned = dataclasses.replace(ahead.job, changes=job.changes)
            if not self.realtime or worker.within_budget(ahead.future):
                return self._adopt(s, planned, ahead.future.result(), t, wall0, PLANNED_AHEAD)
            worker.carry(planned, ahead.future, planned.options.interrupt)
            return _record(s, t, wall0, "searching", note=SEARCHING, **job.changes)
        if self._on_proven_plan(t, s, job):
            previous, grasp = s.grasp_start
            return _record(s, t, wall0, "kept", note=ON_PROVEN_PLAN,
                           grasp_start=(previous, grasp[1:]), **job.changes)
        if not self.realtime:
            return self._adopt(s, job, self._solve(job), t, wall0)
        future = worker.start(self._solve, job)
        first = max(worker.budget_s, job.options.time_limit_s) if wait else None
        if worker.within_budget(future, first):
            return self._adopt(s, job, future.result(), t, wall0)
        if job.idle:
            worker.carry(job, future, job.options.interrupt)
            self._start_quick(job)
            return _record(s, t, wall0, "searching", note=SEARCHING, **job.changes)
        job.options.interrupt.set()
        return _record(s, t, wall0, "over_budget", note="kept the previous plan", **job.changes)

    def _prepare(self, t: float, s: MpcState, measured: State, goals: Goals, wall0: float):
        """What the replan at ``t`` must solve (a :class:`_Job`), or the new state and record at
        once when nothing is left to solve (every object delivered, or the rest out of reach)."""
        base = self._scenario
        sc = dataclasses.replace(base, task=dataclasses.replace(base.task, goals=goals))
        state = self._committed_state(t, s, measured)
        # A held object counts once its plan is over, or when that plan keeps it where it is.
        released = (t >= s.horizon_end - 1e-9) | delivery.kept(s.plan, t)
        resting = delivery.resting(sc, state, released, measured)
        delivered_time = tuple((t if d is None else d) if r else None
                               for d, r in zip(s.delivered_time, resting, strict=True))
        # A thrown object still sliding into its goal needs nothing more from the robot.
        done = resting | delivery.arriving(sc, state, measured)
        n_done = int(np.sum(done))
        lost = delivery.lost(sc, state) & ~done
        remaining = [j for j in range(sc.n_objects) if not done[j] and not lost[j]]
        if not remaining and lost.any():
            names = ", ".join(sc.task.objects[j].name for j in np.flatnonzero(lost))
            return _record(s, t, wall0, "stuck", plan=_hold(t, sc.robot.dt, state), step_objects=(),
                           delivered_time=delivered_time, proven=None,
                           note=f"{names} can no longer reach the goal")
        if not remaining:
            return _record(s, t, wall0, "done", plan=_hold(t, sc.robot.dt, state), step_objects=(),
                           delivered_time=delivered_time, proven=None)
        new_step = (not s.step_objects or n_done >= s.step_target
                    or not set(s.step_objects) & set(remaining))
        if new_step:
            objects = select_objects(sc, state, remaining)
            target = n_done + min(sc.task.m_o, len(objects))
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
                    and np.abs(state.hand_vel).max(initial=0) < self.tolerances.snap_velocity
                    and np.abs(state.object_vel).max(initial=0) < self.tolerances.snap_velocity)
        if idle:
            state = dataclasses.replace(state, hand_vel=np.zeros_like(state.hand_vel),
                                        object_vel=np.zeros_like(state.object_vel))
        changes = dict(delivered_time=delivered_time, step_objects=tuple(objects),
                       step_target=target)
        work = None if self.realtime else WorkLimit(sc.solver.replan_program_limit)
        options = dataclasses.replace(self._options, interrupt=Interrupt(), work=work)
        return _Job(StepProblem(sc, state, spec), start, options, idle, changes)

    def _solve(self, job: _Job) -> StepResult | None:
        """The shortest feasible horizon (with cost (17) alone, a longer horizon lets the plan
        idle first, and a receding horizon would then never arrive); in real time, on the
        worker."""
        wall0 = time.perf_counter()
        res = None
        problem = job.problem
        for T in range(predict_horizon(problem, job.options),
                       problem.scenario.solver.max_horizon + 1):
            res = self._solve_horizon(problem, T, job.options, start=job.start)
            if res.status is not Status.INFEASIBLE or job.options.interrupt.is_set():
                break
            if job.options.work is not None and job.options.work.spent():
                # lockstep: out of work before a horizon had a plan, undecided (as a time limit)
                return dataclasses.replace(res, status=Status.TIME_LIMIT)
            if time.perf_counter() - wall0 > job.options.time_limit_s:
                break
        return res

    def _adopt(self, s: MpcState, job: _Job, res: StepResult | None, t: float,
               wall0: float, note: str = "") -> tuple[MpcState, Replan]:
        """The plan of a finished search, starting now (a search carried over started from a
        state the robot still holds at rest); the next step is then planned ahead from its
        end."""
        sc, start = job.problem.scenario, job.problem.state
        if res is None or not res.status.has_solution:
            status = res.status.value if res else "no_horizon"
            return _record(s, t, wall0, status, res, note="kept the previous plan", **job.changes)
        objects = list(job.problem.spec.objects)
        traj = embed_step(sc, start, objects, res.trajectory)
        plan = TimedTrajectory(t, sc.robot.dt, traj)
        new, record = _record(s, t, wall0, res.status.value, res, note=note, plan=plan,
                              horizon_end=t + res.horizon * sc.robot.dt,
                              grasp_start=(tuple(objects), res.trajectory.grasp),
                              proven=_step_key(job) if res.status is Status.OPTIMAL else None,
                              standing=standing(start, objects, sc.robot.dt),
                              **job.changes)
        self._plan_ahead(new, start, sc.task.goals)
        return new, record

    # -- anytime: one object first while the robot would wait -------------------------------

    def _start_quick(self, job: _Job) -> None:
        """Beside a search the robot waits for at rest, the same step with m_o = 1 (the one
        delivery found first, a far smaller search), on the plan-ahead thread: a plan that moves
        the robot now, the rest of the step planned on the way."""
        self._drop_quick()
        spec = job.problem.spec
        if spec.m_o <= 1:
            return
        self._drop_ahead()
        one = dataclasses.replace(
            job, problem=job.problem.with_spec(dataclasses.replace(spec, m_o=1)),
            options=dataclasses.replace(job.options, interrupt=Interrupt()))
        self._quick = (one, self._worker.start_ahead(self._solve, one))

    def _drop_quick(self) -> None:
        if self._quick is not None:
            self._quick[0].options.interrupt.set()
            self._quick = None

    def _quick_plan(self) -> tuple[_Job, StepResult] | None:
        """The one-delivery plan of :meth:`!_start_quick`, if it has ended with a plan (and
        the robot still rests where it started: the carried search checked that)."""
        if self._quick is None or not self._quick[1].done():
            return None
        one, future = self._quick
        self._quick = None
        res = future.result() if future.exception() is None else None
        return (one, res) if res is not None and res.status.has_solution else None

    # -- the next step, planned ahead ---------------------------------------------------------

    def _plan_ahead(self, s: MpcState, start: State, goals: Goals) -> None:
        """Start planning the next sequential step: what the first replan that ``s``'s plan
        (made from ``start``) predicts to start a new step (its objects delivered, a thrown one
        arriving) will solve, from the state the plan predicts there. Objects outside the plan's
        step that were sliding at its start are predicted where their slide ends (the plan
        keeps them where they were). Nothing if no replan within the plan starts a new step,
        or that replan has nothing to search (every object delivered), or it is being planned
        already."""
        traj, dt = s.plan.trajectory, self._scenario.robot.dt
        outside = ~np.isin(np.arange(self._scenario.n_objects), s.step_objects)
        settled = start.object_pos + dt * start.object_vel
        for k in range(1, traj.steps + 1):
            due = s.plan.t0 + k * dt
            predicted = dataclasses.replace(State.at(traj, k), object_pos=np.where(
                outside[:, None], settled, traj.object_pos[k]))
            job = self._prepare(due, s, predicted, goals, time.perf_counter())
            if not isinstance(job, _Job) or job.start is None:  # the step ends here
                break
        else:
            job = None
        if not isinstance(job, _Job):
            self._drop_ahead()
            return
        if self._ahead is not None and self._ahead.due == due and \
                _same_problem(self._ahead.job, job, self.tolerances):
            return
        self._drop_ahead()
        if self.realtime:
            future = self._worker.start_ahead(self._solve, job)
        else:  # lockstep: now, in the caller, as every lockstep solve
            future = Future()
            future.set_result(self._solve(job))
        self._ahead = _Ahead(due, job, future)

    def _take_ahead(self, t: float, job: _Job) -> _Ahead | None:
        """The step planned ahead, where the replan at ``t`` is the one it was planned for and
        starts where it was predicted to, within the tolerances a replan snaps to the plan in
        force by the snap tolerances (:class:`Tolerances`); a plan ahead for other goals, or whose
        time has come without a match, is dropped."""
        ahead = self._ahead
        if ahead is None:
            return None
        if ahead.job.problem.scenario.task.goals != job.problem.scenario.task.goals:
            self._drop_ahead()
            return None
        if t < ahead.due - 1e-9:
            return None
        self._ahead = None
        if _same_problem(ahead.job, job, self.tolerances):
            return ahead
        ahead.job.options.interrupt.set()
        return None

    def _drop_ahead(self) -> None:
        if self._ahead is not None:
            self._ahead.job.options.interrupt.set()
            self._ahead = None

    def _on_proven_plan(self, t: float, s: MpcState, job: _Job) -> bool:
        """Whether the plan in force, from its step k reached at ``t`` on, is the optimum of
        ``job`` (Bellman's principle of optimality), so that no search is needed.

        It holds when that plan was proven optimal, at the shortest horizon, for the same
        objects, m_o and goals, and the replan starts from exactly the plan's state at k (the
        committed state snaps to it while the robot tracks the plan). The model is Markov in
        (x, η): a plan from x(k) with η(k) fixed, prefixed with the plan's steps 0..k−1, is a
        plan from the start, so a cheaper or shorter one from x(k) would have made the plan in
        force neither optimal nor shortest. Its rules hold on the prefix too: the paper's rules
        look at most two steps ahead (no-throw's ``WX WX θ``), and θ one step after k is fixed
        by x(k) (p(k+1) = p(k) + Δt·v(k)). The task must still hold on the rest (◇θ may have
        held only before k): checked by the evaluator on the rest of the plan. With the objects'
        spacing, (C1)–(C2), the objects outside the step must still stand within the boxes the
        plan kept clear of (none knocked into its way)."""
        if not self._keep_proven or s.proven is None or s.proven != _step_key(job):
            return False
        traj = s.plan.trajectory
        k, within = step_at(s.plan, t)
        if within > _ON_GRID or not 1 <= k < traj.steps:
            return False
        sc, x, spec = job.problem.scenario, job.problem.state, job.problem.spec
        objects = list(spec.objects)
        pairs = [(x.hand_pos, traj.hand_pos[k]), (x.hand_vel, traj.hand_vel[k]),
                 (x.object_pos[objects], traj.object_pos[k][objects]),
                 (x.object_vel[objects], traj.object_vel[k][objects]),
                 (x.grasp[:, objects], traj.grasp[k][:, objects])]
        if any(np.abs(a - b).max(initial=0) > POSITION_TOL for a, b in pairs):
            return False
        if sc.task.object_clearance is not None and not _within(
                standing(x, objects, sc.robot.dt), s.standing):
            return False  # an object outside the step moved into its way (C1)
        holds = atom_trace(sc, traj, k, traj.steps)
        return evaluate(spec.task(), holds, traj.steps - k)

    def _still(self, job: _Job, m: State) -> bool:
        """Whether the robot and the objects still rest where the search carried over started."""
        pos = np.concatenate([m.hand_pos, m.object_pos])
        start = job.problem.state
        was = np.concatenate([start.hand_pos, start.object_pos])
        speed = np.abs(np.concatenate([m.hand_vel, m.object_vel])).max(initial=0)
        tol = self.tolerances
        return bool(np.abs(pos - was).max(initial=0) < tol.snap_position
                    and speed < tol.snap_velocity)

    def _committed_state(self, t: float, s: MpcState, m: State) -> State:
        """The state a replan starts from: the measured one, with the grasp the previous plan
        committed to for [t, t + Δt).

        Where a hand or an object is within the snap tolerances (:class:`Tolerances`) of where the
        previous plan put it, the plan's own (nominal) value is used: the controller absorbs
        millimetre tracking errors, and the shifted plan stays feasible (otherwise tight plans —
        throws at full speed from the edge of the hand range — turn infeasible by a hair at every
        replan and the robot dithers). Larger deviations (a knock, a short throw, a failed grasp)
        are taken as measured. Unheld objects slower than ``still_speed`` are at rest. Hands
        measured inside eq. (16)'s gap are moved apart (:func:`_apart`)."""
        sc, tol = self._scenario, self.tolerances
        ws = Rect.of(sc.robot.workspace)
        hand_pos = np.clip(m.hand_pos, ws.lo, ws.hi)
        hand_vel = np.clip(m.hand_vel, -sc.robot.max_speed, sc.robot.max_speed)
        obj_pos, obj_vel = np.array(m.object_pos, float), np.array(m.object_vel, float)
        obj_vel[np.linalg.norm(obj_vel, axis=1) < tol.still_speed] = 0.0
        k, _ = step_at(s.plan, t)
        traj = s.plan.trajectory
        if 0 <= k < len(traj.hand_pos) and s.step_objects:
            # Hands on position alone: at a release the interpolator deliberately keeps the
            # hand at the previous step's speed (the throw), so its velocity differs by design.
            close = np.abs(hand_pos - traj.hand_pos[k]).max(axis=1) < tol.snap_position
            hand_pos[close], hand_vel[close] = traj.hand_pos[k][close], traj.hand_vel[k][close]
            # The step's objects only: the plan keeps the others where they were when it was
            # made (embed_step), which is no prediction for one still sliding (measured: a
            # thrown object snapped back 1–2 cm short of its goal, out of reach: "stuck").
            # A held object's velocity is its hand's (eq. 8): its own measured one is contact
            # jitter, which at a quarter of §V-D's size left a box held at the grasp box's edge
            # 0.07 mm outside it, and every horizon infeasible.
            held = np.asarray(traj.grasp[k]).any(axis=0)
            close = ((np.abs(obj_pos - traj.object_pos[k]).max(axis=1) < tol.snap_position)
                     & (held | (np.abs(obj_vel - traj.object_vel[k]).max(axis=1)
                                < tol.snap_velocity)))
            close &= np.isin(np.arange(sc.n_objects), s.step_objects)
            obj_pos[close], obj_vel[close] = traj.object_pos[k][close], traj.object_vel[k][close]
        if t < s.horizon_end - 1e-9:
            grasp = sample_grasp(s.plan, t).reshape(2, sc.n_objects).round().astype(int)
        else:  # the plan is over: what the gripper holds
            grasp = np.asarray(m.grasp).round().astype(int)
        # A grasp of an object no longer at the hand (knocked away, or never caught) is void.
        half = np.array([o.grasp_half_size for o in sc.task.objects])
        reach = np.abs(m.hand_pos[:, None] - obj_pos[None]).max(axis=2)  # (2, N)
        grasp[reach > half[None] + GRASP_SLACK] = 0
        shift = _apart(hand_pos, hand_vel, sc.robot.hand_gap, sc.robot.dt, ws)
        hand_pos[:, 0] += shift
        for i, j in zip(*np.nonzero(grasp), strict=True):
            obj_vel[j] = hand_vel[i]  # held: moves with its hand (eq. 8)
            obj_pos[j, 0] += shift[i]  # and keeps its offset
        return State(hand_pos, hand_vel, obj_pos, obj_vel, grasp)


def _apart(hand_pos: np.ndarray, hand_vel: np.ndarray, gap: float, dt: float,
           ws: Rect) -> np.ndarray:
    """The shift along x of each hand that restores eq. (16), x_arm2 + gap ≤ x_arm1, now and
    one step on (where the start velocity alone takes the hands): half each, less where the
    hand range stops one. A plan may end with the hands exactly ``gap`` apart; the controller
    then holds them a few micrometres closer, and from that measured state every horizon
    would be infeasible, whatever the task (the hands' positions at step 1 are fixed)."""
    closest = min(hand_pos[0, 0] - hand_pos[1, 0],
                  hand_pos[0, 0] - hand_pos[1, 0] + dt * (hand_vel[0, 0] - hand_vel[1, 0]))
    deficit = max(gap - closest, 0.0)
    room_right, room_left = ws.hi[0] - hand_pos[0, 0], hand_pos[1, 0] - ws.lo[0]
    right = min(deficit / 2, room_right)
    left = min(deficit - right, room_left)
    right = min(deficit - left, room_right)  # what the left hand could not take
    return np.array([right, -left])


def _record(s: MpcState, t: float, wall0: float, status: str, res: StepResult | None = None,
            note: str = "", **changes) -> tuple[MpcState, Replan]:
    new = dataclasses.replace(s, **changes)
    r = Replan(t=t, wall_s=time.perf_counter() - wall0, status=status,
               cost=None if res is None or res.trajectory is None else res.cost,
               horizon=None if res is None else res.horizon, objects=new.step_objects,
               n_delivered=sum(d is not None for d in new.delivered_time), note=note,
               adopted="plan" in changes)
    return new, r


def _same_problem(a: _Job, b: _Job, tol: Tolerances) -> bool:
    """Whether two replans solve the same problem: the same objects, m_o and goals, the same
    grasps, and start states within the snap tolerances of each other."""
    if (a.problem.spec.objects, a.problem.spec.m_o, a.problem.scenario.task.goals,
         a.start is None) != \
            (b.problem.spec.objects, b.problem.spec.m_o, b.problem.scenario.task.goals,
             b.start is None):
        return False
    x, y = a.problem.state, b.problem.state
    if not np.array_equal(x.grasp, y.grasp):
        return False
    return all(np.abs(p - q).max(initial=0) <= tol for p, q, tol in (
        (x.hand_pos, y.hand_pos, tol.snap_position), (x.hand_vel, y.hand_vel, tol.snap_velocity),
        (x.object_pos, y.object_pos, tol.snap_position),
        (x.object_vel, y.object_vel, tol.snap_velocity)))


def _within(now: tuple[np.ndarray, np.ndarray], then: tuple[np.ndarray, np.ndarray] | None,
            tol: float = delivery.KEPT) -> bool:
    """Whether the standing boxes ``now`` lie within those ``then`` (``mld.standing``, of the
    same objects), to ``tol``: a plan kept clear of these is still clear of those."""
    return then is not None and bool(np.all(now[0] >= then[0] - tol)
                                     and np.all(now[1] <= then[1] + tol))


def _step_key(job: _Job) -> tuple:
    """What a plan is optimal for: the step's objects, m_o and the goals."""
    scenario, spec = job.problem.scenario, job.problem.spec
    goals = tuple(sorted((name, tuple(box)) for name, box in scenario.task.goals.items()))
    return spec.objects, spec.m_o, goals


@dataclass(frozen=True)
class _Job:
    """One replan's search: what to solve, from which state, and how to stop it."""

    problem: StepProblem  # its scenario with the goals the replan saw
    start: Callable | None  # MIP start for the monolithic MILP
    options: SolveOptions  # with the Interrupt that stops it
    idle: bool  # the robot rests with no plan left: a late result still applies
    changes: dict  # the bookkeeping to record with the replan


@dataclass(frozen=True)
class _Ahead:
    """The next sequential step planned ahead: due at the plan in force's end."""

    due: float
    job: _Job  # from the state the plan in force predicts at ``due``
    future: Future  # its result (lockstep: already there)


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
