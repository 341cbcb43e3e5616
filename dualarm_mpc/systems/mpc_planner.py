"""MPC planner: the MPC core (``mpc.py``) inside the Diagram, replanning every Δt.

A thin LeafSystem: a periodic unrestricted update (every Δt from t = 0) reads the measured state
and the goals from its input ports, calls :meth:`dualarm_mpc.planning.mpc.Replanner.step`, and keeps
the new :class:`~dualarm_mpc.planning.mpc.MpcState` and the replan's record in its abstract state.
The new state takes over ``solver.replan_latency_s`` of simulated time after the replan (0 by
default: at once; at most Δt), held until then as the pending state; the plan in force meanwhile is
the previous one. The output ports only read that state: the plan in
force, and the last replan (the closed loop records every one of them; the log is not kept in the
state). The state holds values only: a search that runs on (real time) is the Replanner's.
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.model.mld import State
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.planning.mpc import MpcState, Replan, Replanner, Solve

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

    ``measured_state`` (8 + 6N): the measured :class:`~dualarm_mpc.model.mld.State` as
    :meth:`~dualarm_mpc.model.mld.State.vector` lays it out (the StateEstimator's output). ``goals``
    (abstract): dict goal name → box [xmin, xmax, ymin, ymax], read at every replan (a moved goal
    counts from the next one). ``plan``: the :class:`~dualarm_mpc.model.plan.TimedTrajectory` in
    force (abstract). ``replan``: the last replan's :class:`~dualarm_mpc.planning.mpc.Replan`
    (abstract; None before the first).
    ``solve`` replaces one horizon's solve (``sequential.solve_horizon``), e.g. to inject failures.
    """

    _DUE = 1e-9  # s: a pending state due at t takes over at the update at t (float sums)

    def __init__(self, scenario: Scenario, time_limit_s: float | None = None,
                 solve: Solve | None = None):
        super().__init__()
        self._n = scenario.n_objects
        self._replanner = Replanner(scenario, time_limit_s, solve)
        initial = self._replanner.initial_state()
        self._state = self.DeclareAbstractState(AbstractValue.Make(initial))
        self._last = self.DeclareAbstractState(AbstractValue.Make(None))
        # (time it takes over, MpcState) of the last replan, until it does; else None
        self._pending = self.DeclareAbstractState(AbstractValue.Make(None))
        dt, self.latency_s = scenario.robot.dt, scenario.solver.replan_latency_s
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
        self.DeclarePeriodicUnrestrictedUpdateEvent(dt, 0.0, self._update)
        if 0 < self.latency_s < dt:  # a latency of Δt takes over at the next replan's update
            self.DeclarePeriodicUnrestrictedUpdateEvent(dt, self.latency_s, self._take_over)

    def close(self) -> None:
        """Stop a search still running in the background (real time; the simulation is over)."""
        self._replanner.close()

    def get_measured_state_input_port(self):
        return self._measured

    def get_goals_input_port(self):
        return self._goals

    def get_plan_output_port(self):
        return self._plan

    def get_replan_output_port(self):
        return self._replan

    def mpc_state(self, context) -> MpcState:
        """The state in force (its plan is the one the robot follows)."""
        return context.get_abstract_state(self._state).get_value()

    def latest_state(self, context) -> MpcState:
        """The last replan's state, pending or in force (what the planner last counted)."""
        pending = context.get_abstract_state(self._pending).get_value()
        return self.mpc_state(context) if pending is None else pending[1]

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

    def _take_over(self, context, state) -> None:
        current, pending = self._in_force(context)
        state.get_mutable_abstract_state(self._state).set_value(current)
        state.get_mutable_abstract_state(self._pending).set_value(pending)

    def _update(self, context, state) -> None:
        """The replan at t, from the state in force at t; its state takes over at t + latency."""
        t = context.get_time()
        current, _ = self._in_force(context)
        measured = State.from_vector(self._measured.Eval(context), self._n)
        new, replan = self._replanner.step(t, current, measured, self._goals.Eval(context))
        pending = None if self.latency_s == 0 else (t + self.latency_s, new)
        state.get_mutable_abstract_state(self._state).set_value(new if pending is None
                                                                else current)
        state.get_mutable_abstract_state(self._pending).set_value(pending)
        state.get_mutable_abstract_state(self._last).set_value(replan)
