"""The scenes the tests share: two objects with reachable goals that need a real carry (0.3–0.4 m),
and variations of it by override."""

from __future__ import annotations

from dualarm_mpc.scenario import Scenario, apply_overrides

OBJECT1 = {"name": "object1", "position": [0.1, 0.1], "goal": "red"}
OBJECT2 = {"name": "object2", "position": [-0.1, 0.2], "goal": "blue"}
TWO_OBJECTS = {
    "name": "two",
    "goals": {"red": [0.2, 0.4, 0.5, 0.7], "blue": [-0.4, -0.2, 0.5, 0.7]},
    "objects": [OBJECT1, OBJECT2],
    "m_o": 2,
    "n_o": 2,
    "solver": {"time_limit_s": 10.0},
}


def two_objects(**overrides) -> Scenario:
    """:data:`TWO_OBJECTS` with ``overrides`` (top-level fields replaced whole)."""
    return apply_overrides(Scenario(), {**TWO_OBJECTS, **overrides})
