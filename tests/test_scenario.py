"""Tests for dualarm_mpc.scenario: built-in files, overrides, one test per error path."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from dualarm_mpc.scenario import (
    BUILTIN,
    Scenario,
    ScenarioError,
    apply_overrides,
    load_scenario,
    random_objects,
)

# --- built-in scenarios ---------------------------------------------------------------------------


def test_builtin_names() -> None:
    assert set(BUILTIN) == {"table1_vc", "table1_vd"}


def test_table1_vc_is_the_papers_section_vc() -> None:
    s = load_scenario("table1_vc")
    assert s.n_objects == 10
    assert [o.name for o in s.objects] == [f"object{j}" for j in range(1, 11)]
    given = {
        1: (0.1, 0.1),
        2: (-0.1, 0.1),
        4: (-0.2, 0.2),
        5: (0.0, 0.2),
        6: (0.2, 0.2),
        7: (0.2, 0.0),
        8: (-0.2, 0.0),
        9: (-0.3, 0.1),
    }  # Table I
    for j, p in given.items():
        assert s.objects[j - 1].position == pytest.approx(list(p))
    positions = {tuple(o.position) for o in s.objects}
    assert len(positions) == 10  # objects 3 and 10 at free spots
    assert s.goals == {
        "red": [0.225, 0.575, 1.15, 1.45],
        "green": [-0.175, 0.175, 1.35, 1.65],
        "blue": [-0.575, -0.225, 1.15, 1.45],
    }
    assert s.workspace == [-0.9, 0.9, 0.0, 0.9]
    assert s.hand_start == [[0.1, 0.0], [-0.1, 0.0]]  # arm 1 = right
    assert all(o.goal in s.goals for o in s.objects)
    # every goal lies beyond the hands' reach: objects must be thrown
    assert min(b[2] for b in s.goals.values()) > s.workspace[3]


def test_table1_vd_random_objects_and_extended_hand_range() -> None:
    s = load_scenario("table1_vd")
    assert s.random_objects is not None and s.n_objects == s.random_objects.count == 10
    xy = np.array([o.position for o in s.objects])
    assert (np.abs(xy) <= 0.25).all()
    assert s.workspace[2] <= -0.3  # design §1: the hands reach objects below y = 0
    assert [o.goal for o in s.objects[:4]] == ["red", "green", "blue", "red"]  # round-robin
    assert s.goals["green"] == [-0.175, 0.175, 0.85, 1.15]


# --- overrides ------------------------------------------------------------------------------------


def test_override_by_dict_and_by_yaml_text_agree() -> None:
    as_dict = load_scenario(
        "table1_vc", {"max_speed": 0.3, "solver": {"time_limit_s": 5}, "rules": ["G true"]}
    )
    as_text = load_scenario(
        "table1_vc", "max_speed: 0.3\nsolver: {time_limit_s: 5}\nrules: ['G true']"
    )
    assert as_dict == as_text
    assert as_dict.max_speed == 0.3 and as_dict.solver.time_limit_s == 5.0
    assert as_dict.solver.max_horizon == Scenario().solver.max_horizon  # nested: merged, not reset
    assert as_dict.max_force == 0.5  # untouched fields keep the file's values
    assert isinstance(as_dict.solver.time_limit_s, float)


def test_empty_override_is_the_file() -> None:
    assert (
        load_scenario("table1_vc", "")
        == load_scenario("table1_vc")
        == load_scenario("table1_vc", {})
    )


def test_override_replaces_objects_and_scenario_file_path(tmp_path) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text(
        "name: mine\ngoals: {red: [0.2, 0.4, 0.3, 0.5]}\n"
        "objects:\n  - {name: a, position: [0.1, 0.1], goal: red}\nm_o: 1\nn_o: 1\n"
    )
    s = load_scenario(
        str(path),
        {
            "objects": [
                {"name": "b", "position": [0.0, 0.2], "goal": "red", "grasp_half_size": 0.03}
            ]
        },
    )
    assert [(o.name, o.position, o.grasp_half_size) for o in s.objects] == [("b", [0.0, 0.2], 0.03)]
    assert s.name == "mine"


def test_apply_overrides_leaves_its_input_alone() -> None:
    base = load_scenario("table1_vd")
    before = dataclasses.asdict(base)
    apply_overrides(
        base,
        {
            "random_objects": {"count": 3},
            "solver": {"threads": 2},
            "goals": {"red": [0.2, 0.5, 0.6, 0.9]},
        },
    )
    assert dataclasses.asdict(base) == before


def test_overriding_one_goal_keeps_the_others() -> None:
    """Mappings merge, as Drake's ``yaml_load_typed`` does (retain_map_defaults): moving one goal
    with ``--set 'goals: {red: [...]}'`` must not delete the green and blue goals."""
    s = load_scenario("table1_vc", {"goals": {"red": [0.2, 0.5, 1.2, 1.4]}})
    assert s.goals["red"] == [0.2, 0.5, 1.2, 1.4]
    assert set(s.goals) == {"red", "green", "blue"}


# --- random objects -------------------------------------------------------------------------------


def test_random_objects_are_reproducible_from_the_seed() -> None:
    a = load_scenario("table1_vd", {"seed": 7})
    b = load_scenario("table1_vd", {"seed": 7})
    c = load_scenario("table1_vd", {"seed": 8})
    assert a.objects == b.objects
    assert [o.position for o in a.objects] != [o.position for o in c.objects]
    assert [o.goal for o in a.objects] == [o.goal for o in c.objects]


def test_random_objects_in_region_and_count() -> None:
    from dualarm_mpc.scenario import RandomObjects

    spec = RandomObjects(count=25, region=[0.1, 0.3, -0.2, 0.0], grasp_half_size=0.04)
    objs = random_objects(spec, ["g1", "g2"], seed=3)
    assert len(objs) == 25
    xy = np.array([o.position for o in objs])
    assert (xy[:, 0] >= 0.1).all() and (xy[:, 0] <= 0.3).all()
    assert (xy[:, 1] >= -0.2).all() and (xy[:, 1] <= 0.0).all()
    assert [o.goal for o in objs[:3]] == ["g1", "g2", "g1"]
    assert all(o.grasp_half_size == 0.04 for o in objs)
    assert len({o.name for o in objs}) == 25
    assert random_objects(spec, ["g1", "g2"], seed=3) == objs


# --- error paths: each names its field ------------------------------------------------------------


def _error(overrides, name: str = "table1_vc") -> str:
    with pytest.raises(ScenarioError) as info:
        load_scenario(name, overrides)
    return str(info.value)


@pytest.mark.parametrize(
    ("overrides", "prefix"),
    [
        ({"max_speed": "fast"}, "max_speed: expected a number"),
        ({"max_speed": True}, "max_speed: expected a number"),
        ({"solver": {"time_limit_s": "1 min"}}, "solver.time_limit_s: expected a number"),
        (
            {"objects": [{"name": "a", "position": [0.1, "y"], "goal": "red"}]},
            "objects[0].position[1]: expected a number",
        ),
        ({"m_o": 2.5}, "m_o: expected an integer"),
        ({"pruning": "yes"}, "pruning: expected true or false"),
    ],
)
def test_bad_number(overrides, prefix: str) -> None:
    assert _error(overrides).startswith(prefix)


@pytest.mark.parametrize(
    ("overrides", "prefix"),
    [
        ({"max_sped": 0.3}, "max_sped: unknown field"),
        ({"solver": {"timelimit": 3}}, "solver.timelimit: unknown field"),
        (
            {"objects": [{"name": "a", "position": [0, 0], "goal": "red", "colour": "red"}]},
            "objects[0].colour: unknown field",
        ),
    ],
)
def test_unknown_field(overrides, prefix: str) -> None:
    message = _error(overrides)
    assert message.startswith(prefix)
    assert "known:" in message


def test_bad_goal_name() -> None:
    message = _error({"objects": [{"name": "a", "position": [0, 0.1], "goal": "purple"}]})
    assert message.startswith("objects[0].goal: 'purple' is not a goal")
    assert "red" in message


@pytest.mark.parametrize(
    ("overrides", "prefix"),
    [
        ({"goals": {"red": [0.5, 0.2, 1.15, 1.45]}}, "goals.red: empty box"),
        ({"workspace": [-0.9, 0.9, 0.9, 0.9]}, "workspace: empty box"),
        ({"goals": {"red": [0.5, 0.2, 1.15]}}, "goals.red: expected [xmin, xmax, ymin, ymax]"),
    ],
)
def test_empty_or_malformed_box(overrides, prefix: str) -> None:
    assert _error(overrides).startswith(prefix)


@pytest.mark.parametrize(
    ("overrides", "prefix"),
    [
        ({"rule": 3}, "rule: must be 1"),
        ({"delivery": "throw"}, "delivery: must be 'reach' or 'rest'"),
        ({"m_o": 0}, "m_o: need 1 <= m_o <= n_o"),
        ({"m_o": 7, "n_o": 6}, "m_o: need 1 <= m_o <= n_o"),
        ({"task_form": "both"}, "task_form: must be"),
        ({"solver": {"backend": "cplex"}}, "solver.backend: unknown backend"),
        ({"solver": {"time_limit_s": 0}}, "solver.time_limit_s: must be positive"),
        ({"max_force": 0}, "max_force: must be positive"),
        ({"hand_gap": -0.1}, "hand_gap: must be >= 0"),
        ({"hand_start": [[0.1, 0.0]]}, "hand_start: expected two points"),
        (
            {"objects": [{"name": "a", "position": [0.1, 0.1, 0.0], "goal": "red"}]},
            "objects[0].position: expected [x, y]",
        ),
        (
            {
                "objects": [
                    {"name": "a", "position": [0, 0.1], "goal": "red"},
                    {"name": "a", "position": [0, 0.2], "goal": "red"},
                ]
            },
            "objects[1].name: missing or repeated",
        ),
        ({"objects": []}, "objects: no objects"),
        ({"goals": {}}, "goals: at least one"),
        (
            {"events": [{"kind": "move_object", "target": "nobody", "position": [0, 0]}]},
            "events[0].target: no object named 'nobody'",
        ),
        ({"events": [{"kind": "teleport", "target": "object1"}]}, "events[0].kind: must be"),
        ({"solver": 5}, "solver: expected a mapping"),
    ],
)
def test_bad_value(overrides, prefix: str) -> None:
    assert _error(overrides).startswith(prefix)


@pytest.mark.parametrize(
    ("rules", "field"),
    [(["G (("], "rules[0]"), (["G true", "F eta[1,"], "rules[1]")],
)
def test_bad_rule_text_is_a_scenario_error(rules, field: str) -> None:
    """A rule that does not parse is a bad scenario value: it must fail at load time, naming
    the field (not later, deep inside the planner, as an LTLSyntaxError)."""
    message = _error({"rules": rules})
    assert message.startswith(field), message


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"random_objects": {"count": 3, "region": [0.3, 0.1, 0.0, 0.2]}}, "random_objects.region"),
        ({"random_objects": {"count": 3, "region": [0.1, 0.3]}}, "random_objects.region"),
        ({"random_objects": {"count": -1}}, "random_objects.count"),
    ],
)
def test_bad_random_objects(overrides, field: str) -> None:
    message = _error(overrides)
    assert message.startswith(field), message


@pytest.mark.parametrize(
    ("key", "value"),
    [("dt", float("nan")), ("max_speed", float("inf")), ("max_force", float("nan"))],
)
def test_non_finite_numbers_are_rejected(key: str, value: float) -> None:
    assert _error({key: value}).startswith(key)


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"hand_start": [[0.1, 0.0], [0.05, 0.0]]}, "hand_start"),  # breaks eq. (16) at k = 0
        ({"hand_start": [[0.1, 1.5], [-0.1, 0.0]]}, "hand_start[0]"),  # outside the hand range
        ({"solver": {"max_horizon": 0}}, "solver.max_horizon"),
        ({"solver": {"threads": 0}}, "solver.threads"),
    ],
)
def test_values_the_planner_cannot_use_are_rejected(overrides, field: str) -> None:
    message = _error(overrides)
    assert message.startswith(field), message


def test_missing_file() -> None:
    with pytest.raises(ScenarioError, match=r"^scenario: .*no_such\.yaml.*neither a file"):
        load_scenario("/nonexistent/no_such.yaml")


def test_bad_yaml_file_and_text(tmp_path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("max_speed: [0.1\n")
    with pytest.raises(ScenarioError, match=rf"^{re.escape(str(path))}: not valid YAML"):
        load_scenario(str(path))
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ScenarioError, match="expected a mapping of scenario fields"):
        load_scenario(str(path))
    with pytest.raises(ScenarioError, match="^override: not valid YAML"):
        load_scenario("table1_vc", "max_speed: [1")
    with pytest.raises(ScenarioError, match="^override: expected a mapping"):
        load_scenario("table1_vc", "just text")


def test_unknown_field_in_a_file(tmp_path) -> None:
    path = tmp_path / "typo.yaml"
    path.write_text("goalz: {}\n")
    with pytest.raises(ScenarioError, match="^goalz: unknown field"):
        load_scenario(str(path))
