"""The colours the plan's figure and the simulated station draw with: a goal's by its name, the
arms' and the table's (one palette, so the plot and the replay agree)."""

from __future__ import annotations

GOAL_COLOURS = {  # RGB by goal name
    "red": (0.85, 0.15, 0.15),
    "green": (0.15, 0.65, 0.2),
    "blue": (0.15, 0.3, 0.85),
}
OTHER_COLOUR = (0.55, 0.55, 0.55)  # a goal of any other name
ARM_COLOURS = ("#e68c26", "#338c99")  # arm 1 (right), arm 2 (left), as models/dual_scara.sdf
TABLE_COLOUR = (0.82, 0.78, 0.7, 1.0)  # RGBA


def goal_colour(goal: str) -> tuple[float, float, float]:
    """RGB of a goal name: red, green, blue by name, grey for any other name."""
    return GOAL_COLOURS.get(goal.lower(), OTHER_COLOUR)
