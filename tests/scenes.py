"""The scenes the tests share: two objects with reachable goals that need a real carry (0.3–0.4 m),
and variations of it by override."""

from __future__ import annotations

import yaml

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

# One object on the robot with §V-D's bounds and goals: the short closed-loop runs (CLI, viewer).
ONE_ON_THE_ROBOT = {
    "name": "one_on_the_robot",
    "workspace": [-0.9, 0.9, -0.3, 0.9],
    "max_speed": 0.2,
    "max_force": 0.1,
    "goals": {"red": [0.225, 0.575, 0.65, 0.95], "green": [-0.175, 0.175, 0.85, 1.15]},
    "objects": [OBJECT1],
    "rule": 1,
    "m_o": 1,
    "n_o": 1,
    "delivery": "rest",
    "goal_margin": 0.03,
    "solver": {"time_limit_s": 10},
}


def yaml_text(data: dict, **overrides) -> str:
    """``data`` with top-level ``overrides`` as a scenario file's text."""
    return yaml.safe_dump({**data, **overrides}, sort_keys=False)
