"""The scenes the tests share: two objects with reachable goals that need a real carry (0.3–0.4 m),
and variations of it by override; with a third object, placed or at random (the search's and the
CP-SAT relaxation's small steps)."""

from __future__ import annotations

import numpy as np
import yaml

from dualarm_mpc.model.scenario import Scenario, apply_overrides

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

def scene(rule: int = 2, rules: tuple[str, ...] = (), **overrides) -> Scenario:
    """The shared scene with a third object (to red, at the origin), one object per step."""
    object3 = {"name": "object3", "position": [0.0, 0.0], "goal": "red"}
    return two_objects(**{"name": "search", "objects": [OBJECT1, OBJECT2, object3],
                          "rule": rule, "rules": list(rules), "m_o": 1, "n_o": 3,
                          "solver": {"time_limit_s": 30.0, "mip_rel_gap": 1e-7}, **overrides})


def random_scene(seed: int) -> Scenario:
    """Three objects at random in the cluster, one of four rule sets, both deliveries."""
    rng = np.random.default_rng(seed)
    def draw():  # within the hands' reach (y >= 0), apart
        return rng.uniform([-0.2, 0.0], [0.2, 0.25], size=(3, 2))

    positions = draw()
    while min(np.linalg.norm(positions[a] - positions[b]) for a, b in ((0, 1), (0, 2), (1, 2))) \
            < 0.08:
        positions = draw()
    rule, rules = [(1, ()), (2, ()), (2, ("G !(eta[1,1] & F eta[2,1])",)),
                   (1, ("G(eta[2,3] -> WX !eta[2,1])",))][seed % 4]
    delivery = ("reach", "rest")[(seed // 4) % 2]
    objects = [{"name": f"object{j + 1}", "position": p.round(3).tolist(),
                "goal": ("red", "blue")[int(rng.integers(2))]} for j, p in enumerate(positions)]
    return scene(rule, rules, objects=objects, delivery=delivery, m_o=1 + seed % 2)


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


# §V-D's bounds; object a goes straight up to red, and b, delivered to the small blue goal,
# stands in its way: the paper's plan carries a through b (a point), which keeps a box's
# clearance from it with ``object_clearance`` (docs/formulation.md, (C1)-(C2)).
IN_THE_WAY = {
    **{k: ONE_ON_THE_ROBOT[k] for k in ("workspace", "max_speed", "max_force", "rule", "m_o",
                                         "n_o", "delivery", "goal_margin")},
    "name": "in_the_way",
    "goals": {"red": [0.225, 0.575, 0.65, 0.95], "blue": [0.2, 0.4, 0.3, 0.5]},
    "objects": [{"name": "a", "position": [0.3, 0.1], "goal": "red"},
                {"name": "b", "position": [0.3, 0.4], "goal": "blue"}],
}


def in_the_way(**overrides) -> Scenario:
    """:data:`IN_THE_WAY` with ``overrides``."""
    return apply_overrides(Scenario(), {**IN_THE_WAY, **overrides})


def yaml_text(data: dict, **overrides) -> str:
    """``data`` with top-level ``overrides`` as a scenario file's text."""
    return yaml.safe_dump({**data, **overrides}, sort_keys=False)
