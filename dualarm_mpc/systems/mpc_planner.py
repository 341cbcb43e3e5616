"""MPC planner: the MPC core (``mpc.py``) inside the Diagram, replanning every Δt.

A thin LeafSystem: a periodic unrestricted update (every Δt from t = 0) reads the measured state
and the goals from its input ports, calls :meth:`dualarm_mpc.mpc.Replanner.step`, and keeps the
new :class:`~dualarm_mpc.mpc.MpcState` and the replan's record in its abstract state. The output
ports only read that state: the plan in force, and the last replan (the closed loop records every
one of them; the log is not kept in the state).
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.mpc import Measured, MpcState, Replan, Replanner, Solve
from dualarm_mpc.scenario import Scenario
from dualarm_mpc.systems.state_estimator import split_measured_state

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

    ``measured_state`` (8 + 6N): the StateEstimator's layout. ``goals`` (abstract): dict goal
    name → box [xmin, xmax, ymin, ymax], read at every replan (a moved goal counts from the next
    one). ``plan``: the :class:`~dualarm_mpc.plan.TimedTrajectory` in force (abstract). ``replan``:
    the last replan's :class:`~dualarm_mpc.mpc.Replan` (abstract; None before the first).
    ``solve`` replaces one horizon's solve (``sequential.solve_horizon``), e.g. to inject failures.
    """

    def __init__(self, scenario: Scenario, time_limit_s: float | None = None,
                 solve: Solve | None = None):
        super().__init__()
        self._n = scenario.n_objects
        self._replanner = Replanner(scenario, time_limit_s, solve)
        initial = self._replanner.initial_state()
        self._state = self.DeclareAbstractState(AbstractValue.Make(initial))
        self._last = self.DeclareAbstractState(AbstractValue.Make(None))
        self._measured = self.DeclareVectorInputPort("measured_state", 8 + 6 * self._n)
        goals = {k: list(v) for k, v in scenario.task.goals.items()}
        self._goals = self.DeclareAbstractInputPort("goals", AbstractValue.Make(goals))
        self._plan = self.DeclareAbstractOutputPort(
            "plan", lambda: AbstractValue.Make(initial.plan), self._calc_plan,
            prerequisites_of_calc={self.abstract_state_ticket(self._state)})
        self._replan = self.DeclareAbstractOutputPort(
            "replan", lambda: AbstractValue.Make(None), self._calc_replan,
            prerequisites_of_calc={self.abstract_state_ticket(self._last)})
        self.DeclarePeriodicUnrestrictedUpdateEvent(scenario.robot.dt, 0.0, self._update)

    def close(self, context=None) -> None:
        """Stop a search still running in the background (the simulation is over)."""
        self._replanner.close(None if context is None else self.mpc_state(context))

    def get_measured_state_input_port(self):
        return self._measured

    def get_goals_input_port(self):
        return self._goals

    def get_plan_output_port(self):
        return self._plan

    def get_replan_output_port(self):
        return self._replan

    def mpc_state(self, context) -> MpcState:
        return context.get_abstract_state(self._state).get_value()

    def _calc_plan(self, context, output) -> None:
        output.set_value(self.mpc_state(context).plan)

    def _calc_replan(self, context, output) -> None:
        output.set_value(context.get_abstract_state(self._last).get_value())

    def _update(self, context, state) -> None:
        m = split_measured_state(self._measured.Eval(context), self._n)
        measured = Measured(**{k: v.copy() for k, v in m.items()})
        new, replan = self._replanner.step(context.get_time(), self.mpc_state(context), measured,
                                           self._goals.Eval(context))
        state.get_mutable_abstract_state(self._state).set_value(new)
        state.get_mutable_abstract_state(self._last).set_value(replan)
