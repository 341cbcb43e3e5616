"""Goals: where the goal boxes are now, as a source system (a ``move_goal`` event moves one)."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem


class GoalSource(LeafSystem):
    """The goal boxes, held in abstract state and read by the MPC planner.

    .. pydrake_system::

        name: GoalSource
        output_ports:
        - goals

    ``goals`` (abstract): dict goal name → box [xmin, xmax, ymin, ymax], the scenario's until
    :meth:`set_goal` moves one (an environment change, like ``MultibodyPlant.SetFreeBodyPose``).
    """

    def __init__(self, goals: dict[str, list[float]]):
        super().__init__()
        initial = {k: list(v) for k, v in goals.items()}
        self._state = self.DeclareAbstractState(AbstractValue.Make(initial))
        self._goals = self.DeclareAbstractOutputPort(
            "goals", lambda: AbstractValue.Make(dict(initial)), self._calc_goals,
            prerequisites_of_calc={self.abstract_state_ticket(self._state)})

    def get_goals_output_port(self):
        return self._goals

    def goals(self, context) -> dict[str, list[float]]:
        return context.get_abstract_state(self._state).get_value()

    def set_goal(self, context, name: str, box: list[float]) -> None:
        """Move goal ``name`` to ``box`` (``context``: this system's, mutable)."""
        goals = {**self.goals(context), name: list(box)}
        context.get_mutable_abstract_state(self._state).set_value(goals)

    def _calc_goals(self, context, output) -> None:
        output.set_value(self.goals(context))
