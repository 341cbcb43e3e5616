"""MPC planner: the MPC core (``mpc.py``) inside the Diagram, replanning every Δt.

A thin LeafSystem: a periodic unrestricted update (every Δt from t = 0) reads the measured state
and the goals from its input ports, calls :meth:`dualarm_mpc.planning.mpc.Replanner.step`, and keeps
the new :class:`~dualarm_mpc.planning.mpc.MpcState` and the replan's record in its abstract state.
The new state takes over ``Scenario.replan_latency`` of simulated time after the replan (at most
Δt; unset, 0 in lockstep and Δt in real time), held until then as the pending state, and its plan
starts there, planned from where the robot will be then; the plan in force meanwhile is the
previous one. In real time the first plan is made at initialization, before the clock starts,
so that the robot moves from the first second (a search longer than one solve's time limit goes
on while the robot waits, as any other). The output ports only read that state: the plan
in force, also as Drake trajectories (:mod:`~dualarm_mpc.systems.trajectories`), and the last
replan (the closed loop records every one of them; the log is not kept in the state). The state
holds values only: a search that runs on (real time) is the Replanner's, stopped by
:meth:`MpcPlanner.close`, at the end of a ``with`` block, when the planner is collected, or at
the interpreter's exit.
"""

from __future__ import annotations

import threading
import weakref

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.model.mld import State
from dualarm_mpc.model.plan import TimedTrajectory
from dualarm_mpc.model.scenario import Scenario, check_goals
from dualarm_mpc.planning.mpc import MpcState, Replan, Replanner, Solve
from dualarm_mpc.systems.trajectories import grasp_schedule, hand_trajectory, object_trajectory

__all__ = ["MpcPlanner", "MpcState", "Replan"]


class MpcPlanner(LeafSystem):
    """Receding-horizon LTL planner (the paper's planner in closed loop).

    .. pydrake_system::

        name: MpcPlanner
        input_ports:
        - measured_state
        - goals
        output_ports:
        - plan
        - replan
        - hand_trajectory
        - object_trajectory
        - grasp_schedule

    ``measured_state`` (8 + 6N): the measured :class:`~dualarm_mpc.model.mld.State` as
    :meth:`~dualarm_mpc.model.mld.State.vector` lays it out (the StateEstimator's output). ``goals``
    (abstract): dict goal name → box [xmin, xmax, ymin, ymax], read at every replan (a moved goal
    counts from the next one). ``plan``: the :class:`~dualarm_mpc.model.plan.TimedTrajectory` in
    force (abstract). ``replan``: the last replan's :class:`~dualarm_mpc.planning.mpc.Replan`
    (abstract; None before the first). ``hand_trajectory``, ``object_trajectory``,
    ``grasp_schedule``: the plan in force as ``PiecewisePolynomial`` objects over simulated time
    (4, 2N and 2N rows; :mod:`~dualarm_mpc.systems.trajectories` says what each holds),
    abstract (pydrake binds no ``Value[PiecewisePolynomial]``: the value is a Python object),
    made once per plan. A stock ``TrajectorySource`` takes one (its constructor or
    ``UpdateTrajectory``). A context manager: the ``with`` block's end calls
    :meth:`MpcPlanner.close`. ``solve`` replaces one horizon's solve
    (``sequential.solve_horizon``), e.g. to inject failures.
    """

    _DUE = 1e-9  # s: a pending state due at t takes over at the update at t (float sums)

    def __init__(self, scenario: Scenario, time_limit_s: float | None = None,
                 solve: Solve | None = None):
        super().__init__()
        self._n, self._task = scenario.n_objects, scenario.task
        self._replanner = Replanner(scenario, time_limit_s, solve)
        initial = self._replanner.initial_state()
        self._state = self.DeclareAbstractState(AbstractValue.Make(initial))
        self._last = self.DeclareAbstractState(AbstractValue.Make(None))
        # (time it takes over, MpcState) of the last replan, until it does; else None
        self._pending = self.DeclareAbstractState(AbstractValue.Make(None))
        dt, self.latency_s = scenario.robot.dt, scenario.replan_latency
        self.realtime = self._replanner.realtime
        self._measured = self.DeclareVectorInputPort("measured_state", State.size(self._n))
        goals = {k: list(v) for k, v in scenario.task.goals.items()}
        self._goals = self.DeclareAbstractInputPort("goals", AbstractValue.Make(goals))
        self._plan = self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(initial.plan), self._calc_plan,
            prerequisites_of_calc={self.abstract_state_ticket(self._state)})
        self._replan = self.DeclareAbstractOutputPort(
            "replan", lambda: AbstractValue.Make(None), self._calc_replan,
            prerequisites_of_calc={self.abstract_state_ticket(self._last)})
        self._hand_trajectory, self._object_trajectory, self._grasp_schedule = (
            self._declare_trajectory(name, convert, initial.plan) for name, convert in (
                ("hand_trajectory", hand_trajectory), ("object_trajectory", object_trajectory),
                ("grasp_schedule", grasp_schedule)))
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)
        if self.realtime:
            self.DeclareInitializationUnrestrictedUpdateEvent(self._first_plan)
        if 0 < self.latency_s < dt:  # a latency of Δt takes over at the next replan's update
            self.DeclarePeriodicUnrestrictedUpdateEvent(dt, self.latency_s, self._take_over)

        # Holds the Replanner, not the planner: a planner nobody closed stops its search when
        # collected, or at exit at the latest. concurrent.futures joins its worker threads at
        # exit before atexit (weakref.finalize's hook) runs, and a running search would hold the
        # exit until it ended; threading's exit hooks run before that join, the last registered
        # first, so this one stops the search first.
        self._closer = weakref.finalize(self, self._replanner.close)
        if self.realtime:
            threading._register_atexit(self._closer)

    def close(self) -> None:
        """Stop a search still running in the background (real time; the simulation is over)."""
        self._closer()

    def pace(self, rate: float) -> None:
        """Real time: the simulation runs at ``rate`` × real time (a live run this machine cannot
        keep at full speed); a replan's wall-time budget stretches with it."""
        self._replanner.pace(rate)

    def __enter__(self) -> MpcPlanner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def get_measured_state_input_port(self):
        return self._measured

    def get_goals_input_port(self):
        return self._goals

    def get_plan_output_port(self):
        return self._plan

    def get_replan_output_port(self):
        return self._replan

    def get_hand_trajectory_output_port(self):
        return self._hand_trajectory

    def get_object_trajectory_output_port(self):
        return self._object_trajectory

    def get_grasp_schedule_output_port(self):
        return self._grasp_schedule

    def mpc_state(self, context) -> MpcState:
        """The state in force (its plan is the one the robot follows)."""
        return context.get_abstract_state(self._state).get_value()

    def latest_state(self, context) -> MpcState:
        """The last replan's state, pending or in force (what the planner last counted)."""
        pending = context.get_abstract_state(self._pending).get_value()
        return self.mpc_state(context) if pending is None else pending[1]

    def _declare_trajectory(self, name: str, convert, initial: TimedTrajectory):
        """An output port of the plan in force as ``convert`` makes it a Drake trajectory."""
        return self.DeclareAbstractOutputPort(
            name, lambda: AbstractValue.Make(convert(initial)),
            lambda context, output: output.set_value(convert(self.mpc_state(context).plan)),
            prerequisites_of_calc={self.abstract_state_ticket(self._state)})

    def _calc_plan(self, context, output) -> None:
        output.set_value(self.mpc_state(context).plan)

    def _calc_replan(self, context, output) -> None:
        output.set_value(context.get_abstract_state(self._last).get_value())

    def _in_force(self, context) -> tuple[MpcState, tuple | None]:
        """The state in force at the context's time and what is still pending."""
        pending = context.get_abstract_state(self._pending).get_value()
        if pending is not None and pending[0] <= context.get_time() + self._DUE:
            return pending[1], None
        return self.mpc_state(context), pending

    def _inputs(self, context) -> tuple[State, dict]:
        """The measured state and the goals at the input ports, checked: a value that is not
        finite, a goal missing or an empty box raises here, naming the port and the field (a
        replan would report it as an infeasible task)."""
        goals = self._goals.Eval(context)
        check_goals(goals, self._task, "goals")
        return State.from_vector(self._measured.Eval(context), self._n, "measured_state"), goals

    def _take_over(self, context, state) -> None:
        current, pending = self._in_force(context)
        state.get_mutable_abstract_state(self._state).set_value(current)
        state.get_mutable_abstract_state(self._pending).set_value(pending)

    def _first_plan(self, context, state) -> None:
        """Real time: the first replan, waited for up to one solve's time limit, before the
        simulator's clock starts (Drake measures the real-time rate from the end of
        ``Initialize``)."""
        measured, goals = self._inputs(context)
        new, replan = self._replanner.step(context.get_time(), self.mpc_state(context), measured,
                                           goals, wait=True)
        state.get_mutable_abstract_state(self._state).set_value(new)
        state.get_mutable_abstract_state(self._last).set_value(replan)

    def _update(self, context, state) -> None:
        """The replan at t, from the state in force at t; its state takes over at t + latency."""
        t = context.get_time()
        last = context.get_abstract_state(self._last).get_value()
        if last is not None and last.t == t:  # made at initialization, at this very time
            return
        current, _ = self._in_force(context)
        measured, goals = self._inputs(context)
        new, replan = self._replanner.step(t, current, measured, goals, self.latency_s)
        pending = None if self.latency_s == 0 else (t + self.latency_s, new)
        state.get_mutable_abstract_state(self._state).set_value(new if pending is None
                                                                else current)
        state.get_mutable_abstract_state(self._pending).set_value(pending)
        state.get_mutable_abstract_state(self._last).set_value(replan)
