"""Tests for dualarm_mpc.model.scenario: built-in files, overrides, one test per error path."""

from __future__ import annotations

import dataclasses
import re
import typing
from pathlib import Path

import numpy as np
import pytest

from dualarm_mpc.model.scenario import (
    BUILTIN,
    YAML_FIELDS,
    Scenario,
    ScenarioError,
    apply_overrides,
    load_scenario,
    merge_overrides,
    parse_override,
    random_objects,
    scenario_path,
)

# --- built-in scenarios ---------------------------------------------------------------------------


def test_builtin_names() -> None:
    assert set(BUILTIN) == {"table1_vc", "table1_vd", "panda_vc", "panda_vd"}


def test_table1_vc_is_the_papers_section_vc() -> None:
    s = load_scenario("table1_vc")
    assert s.n_objects == 10
    assert [o.name for o in s.task.objects] == [f"object{j}" for j in range(1, 11)]
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
        assert s.task.objects[j - 1].position == pytest.approx(list(p))
    positions = {tuple(o.position) for o in s.task.objects}
    assert len(positions) == 10  # objects 3 and 10 at free spots
    assert s.task.goals == {
        "red": [0.225, 0.575, 1.15, 1.45],
        "green": [-0.175, 0.175, 1.35, 1.65],
        "blue": [-0.575, -0.225, 1.15, 1.45],
    }
    assert s.robot.workspace == [-0.9, 0.9, 0.0, 0.9]
    assert s.robot.hand_start == [[0.1, 0.0], [-0.1, 0.0]]  # arm 1 = right
    assert all(o.goal in s.task.goals for o in s.task.objects)
    # every goal lies beyond the hands' reach: objects must be thrown
    assert min(b[2] for b in s.task.goals.values()) > s.robot.workspace[3]


def test_table1_vd_random_objects_and_extended_hand_range() -> None:
    s = load_scenario("table1_vd")
    assert s.task.random_objects is not None and s.n_objects == s.task.random_objects.count == 10
    xy = np.array([o.position for o in s.task.objects])
    assert (np.abs(xy) <= 0.25).all()
    assert s.robot.workspace[2] <= -0.3  # docs/scenarios.md: the hands reach objects below y = 0
    assert [o.goal for o in s.task.objects[:4]] == ["red", "green", "blue", "red"]  # round-robin
    assert s.task.goals["green"] == [-0.175, 0.175, 0.85, 1.15]


# --- overrides ------------------------------------------------------------------------------------


def test_override_by_dict_and_by_yaml_text_agree() -> None:
    as_dict = load_scenario(
        "table1_vc", {"max_speed": 0.3, "solver": {"time_limit_s": 5}, "rules": ["G true"]}
    )
    as_text = load_scenario(
        "table1_vc", "max_speed: 0.3\nsolver: {time_limit_s: 5}\nrules: ['G true']"
    )
    assert as_dict == as_text
    assert as_dict.robot.max_speed == 0.3 and as_dict.solver.time_limit_s == 5.0
    assert as_dict.solver.max_horizon == Scenario().solver.max_horizon  # nested: merged, not reset
    assert as_dict.robot.max_force == 0.5  # untouched fields keep the file's values
    assert isinstance(as_dict.solver.time_limit_s, float)


def test_no_overrides_is_the_file() -> None:
    # an override text that sets nothing is refused (test_an_override_that_sets_nothing_...)
    assert load_scenario("table1_vc") == load_scenario("table1_vc", {})


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
    assert [(o.name, o.position, o.grasp_half_size) for o in s.task.objects] == [
        ("b", [0.0, 0.2], 0.03)]
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
    assert s.task.goals["red"] == [0.2, 0.5, 1.2, 1.4]
    assert set(s.task.goals) == {"red", "green", "blue"}


# --- random objects -------------------------------------------------------------------------------


def test_random_objects_are_reproducible_from_the_seed() -> None:
    a = load_scenario("table1_vd", {"seed": 7})
    b = load_scenario("table1_vd", {"seed": 7})
    c = load_scenario("table1_vd", {"seed": 8})
    assert a.task.objects == b.task.objects
    assert [o.position for o in a.task.objects] != [o.position for o in c.task.objects]
    assert [o.goal for o in a.task.objects] == [o.goal for o in c.task.objects]


def test_random_objects_in_region_and_count() -> None:
    from dualarm_mpc.model.scenario import RandomObjects

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
        ({"m_o": 0}, "m_o: must be >= 1 and <= 10, got 0"),
        ({"m_o": 7, "n_o": 6}, "m_o: need 1 <= m_o <= n_o"),
        ({"task_form": "both"}, "task_form: must be"),
        ({"solver": {"backend": "glpk"}}, "solver.backend: unknown solver 'glpk' (one of highs"),
        ({"solver": {"time_limit_s": 0}}, "solver.time_limit_s: must be > 0 and <= 86400"),
        ({"max_force": 0}, "max_force: must be >= 0.001 and <= 10, got 0.0"),
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
    message = _error(overrides, "table1_vd")
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
    with pytest.raises(ScenarioError, match=rf"^{re.escape(str(path))}:2: not valid YAML"):
        load_scenario(str(path))
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ScenarioError, match="expected a mapping of scenario fields"):
        load_scenario(str(path))
    with pytest.raises(ScenarioError, match="^override:2: not valid YAML"):
        load_scenario("table1_vc", "max_speed: [1")
    with pytest.raises(ScenarioError, match="^override: expected a mapping"):
        load_scenario("table1_vc", "just text")


def test_the_file_is_flat_and_names_every_grouped_field_once() -> None:
    """The groups are Python's view only: each YAML key sets one field of one group, every field
    has its key, and a group's name is no key of the file."""
    s = Scenario()
    groups = ("robot", "table", "task")
    fields = [f"{g}.{f.name}" for g in groups for f in dataclasses.fields(getattr(s, g))]
    fields += [f.name for f in dataclasses.fields(s) if f.name not in groups]
    assert sorted(YAML_FIELDS.values()) == sorted(fields)
    assert _error("robot.max_speed: 0.3").startswith("robot: unknown field (known: arm_bases, ")


def test_unknown_field_in_a_file(tmp_path) -> None:
    path = tmp_path / "typo.yaml"
    path.write_text("goalz: {}\n")
    with pytest.raises(ScenarioError, match="^goalz: unknown field"):
        load_scenario(str(path))


# --- numbers, field paths, files: issue 7 --------------------------------------------------------


@pytest.mark.parametrize(("text", "value"), [("1e-3", 1e-3), ("5E-1", 0.5), ("2.5e+1", 25.0),
                                             ("+1.5e-3", 1.5e-3), (".5e1", 5.0)])
def test_numbers_yaml_1_1_reads_as_text_are_numbers(tmp_path, text: str, value: float) -> None:
    """YAML 1.1 (PyYAML) reads ``1e-3`` as the string '1e-3'; YAML 1.2 and every user read it
    as a number."""
    assert parse_override(f"solver: {{mip_rel_gap: {text}}}") == {
        "solver": {"mip_rel_gap": value}}
    path = tmp_path / "s.yaml"
    path.write_text(f"state_weight: {text}\n")
    assert load_scenario("table1_vc", path.read_text()).task.state_weight == value
    assert load_scenario("table1_vc", {"state_weight": value}).task.state_weight == value


def test_a_quoted_number_stays_text() -> None:
    assert _error("max_speed: '5e-1'").startswith("max_speed: expected a number, got '5e-1'")


@pytest.mark.parametrize(
    ("path_form", "nested"),
    [
        ("solver.time_limit_s: 5", {"solver": {"time_limit_s": 5}}),
        ("random_objects.count: 3", {"random_objects": {"count": 3}}),
        ("goals.red: [0.2, 0.5, 1.2, 1.4]", {"goals": {"red": [0.2, 0.5, 1.2, 1.4]}}),
    ],
)
def test_a_field_path_is_the_nested_mapping(path_form: str, nested: dict) -> None:
    """The form the error messages print works as an override."""
    assert load_scenario("table1_vd", path_form) == load_scenario("table1_vd", nested)


def test_paths_with_indices_change_one_element() -> None:
    base = load_scenario("table1_vc")
    s = load_scenario("table1_vc", "objects[2].position: [0.25, 0.15]\n"
                                   "objects[3].position[1]: 0.25\n"
                                   "goals.red[3]: 1.5\nhand_start[1][0]: -0.2")
    assert s.task.objects[2].position == [0.25, 0.15]
    assert s.task.objects[3].position == [base.task.objects[3].position[0], 0.25]
    assert s.task.objects[2].name == base.task.objects[2].name
    assert s.task.objects[4] == base.task.objects[4]
    assert s.task.goals["red"] == [*base.task.goals["red"][:3], 1.5]
    assert s.robot.hand_start == [base.robot.hand_start[0], [-0.2, 0.0]]
    assert load_scenario("table1_vc", {"objects[2].goal": "blue"}).task.objects[2].goal == "blue"


def test_later_keys_win_between_paths_and_mappings() -> None:
    assert load_scenario("table1_vc", "solver: {time_limit_s: 7}\nsolver.time_limit_s: 5"
                         ).solver.time_limit_s == 5
    assert load_scenario("table1_vc", "solver.time_limit_s: 5\nsolver: {time_limit_s: 7}"
                         ).solver.time_limit_s == 7
    # a path into a list given in the same override changes that list
    s = load_scenario("table1_vc", {"objects": [{"name": "a", "position": [0.1, 0.1],
                                                 "goal": "red"}], "objects[0].goal": "blue"})
    assert [(o.name, o.goal) for o in s.task.objects] == [("a", "blue")]


def test_merging_overrides_patches_lists_by_index() -> None:
    into = {"objects": [{"name": "a", "goal": "red"}], "solver": {"time_limit_s": 3}}
    merge_overrides(into, parse_override("objects[0].goal: blue\nsolver.workers: 1"))
    assert into == {"objects": [{"name": "a", "goal": "blue"}],
                    "solver": {"time_limit_s": 3, "workers": 1}}
    with pytest.raises(ScenarioError, match=r"^objects\[1\]: no such element"):
        merge_overrides(into, parse_override("objects[1].goal: blue"))


def test_a_path_in_a_file(tmp_path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(Path(scenario_path("table1_vc")).read_text() + "\nsolver.max_horizon: 20\n")
    assert load_scenario(str(path)).solver.max_horizon == 20


@pytest.mark.parametrize(
    ("override", "prefix"),
    [
        ("solver.timelimit: 3", "solver.timelimit: unknown field"),
        ("solver..x: 3", "solver..x: not a field path"),
        ("objects[x].goal: red", "objects[x].goal: not a field path"),
        ("objects[10].goal: red", "objects[10]: no such element (objects has 10)"),
        ("objects[0].position[2]: 0.1", "objects[0].position[2]: no such element"),
        ("events[0].time: 1", "events[0]: no such element (events has 0)"),
        ("max_speed.x: 1", "max_speed: expected a number"),
    ],
)
def test_bad_field_paths_name_the_path(override: str, prefix: str) -> None:
    assert _error(override).startswith(prefix)


def test_a_file_that_is_not_utf8(tmp_path) -> None:
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: caf\u00e9\n".encode("latin-1"))
    with pytest.raises(ScenarioError, match=rf"^{re.escape(str(path))}: not UTF-8 .*0xe9"):
        load_scenario(str(path))


def test_deeply_nested_yaml_is_a_scenario_error() -> None:
    message = _error("rules: " + "[" * 5000 + "]" * 5000)
    assert message.startswith("override:1: nested too deeply")


def test_a_long_value_is_shortened_in_the_message() -> None:
    message = _error({"name": "x", "max_speed": "y" * 10_000})
    assert message.startswith("max_speed: expected a number") and len(message) < 200


# --- silently changed data is an error: issue 7 --------------------------------------------------


@pytest.mark.parametrize(
    ("overrides", "prefix"),
    [
        ({"seed": -1}, "seed: must be >= 0 and <= 4294967295, got -1"),
        ({"objects": [{"name": "a", "goal": "red"}]}, "objects[0].position: missing"),
        ({"events": [{"time": -1.0, "kind": "move_object", "target": "object1",
                      "position": [0.0, 0.1]}]}, "events[0].time: must be >= 0"),
        ({"solver": {"max_horizon": 100_000}}, "solver.max_horizon: must be >= 1 and <= 1000"),
    ],
)
def test_values_that_were_silently_changed_are_errors(overrides, prefix: str) -> None:
    assert _error(overrides).startswith(prefix)


def test_objects_and_random_objects_together_are_an_error(tmp_path) -> None:
    """The random draw replaced the listed objects without a word."""
    path = tmp_path / "both.yaml"
    path.write_text("goals: {red: [0.2, 0.4, 0.5, 0.7]}\n"
                    "objects: [{name: a, position: [0.1, 0.1], goal: red}]\n"
                    "random_objects: {count: 3}\nm_o: 1\nn_o: 1\n")
    with pytest.raises(ScenarioError, match="^objects: given while random_objects"):
        load_scenario(str(path))
    assert _error({"objects": [{"name": "a", "position": [0.1, 0.1], "goal": "red"}]},
                  "table1_vd").startswith("objects: given while random_objects")
    assert _error("objects[0].position: [0.1, 0.1]", "table1_vd").startswith("objects: given")
    listed = load_scenario("table1_vd", {"random_objects": None, "objects": [
        {"name": "a", "position": [0.1, 0.1], "goal": "red"}]})
    assert [o.name for o in listed.task.objects] == ["a"]


def test_an_object_off_the_table_is_named() -> None:
    """Named as itself, not as the speed limits after a failed plan."""
    message = _error({"objects[0].position": [0.3, -0.5]})
    assert message.startswith("objects[0].position: object1 at [0.3, -0.5] lies beyond the "
                              "hands' reach"), message
    # a grasp box's reach beyond the hand range is still reachable, and so is a goal
    load_scenario("table1_vc", {"objects[0].position": [0.3, -0.04]})
    load_scenario("table1_vc", {"objects[0].position": [0.4, 1.3]})
    drawn = _error({"random_objects": {"region": [0.0, 0.2, -0.5, -0.4]}}, "table1_vd")
    assert drawn.startswith("objects[0].position") and "random_objects.region" in drawn


def test_a_dt_too_short_for_the_task_is_named() -> None:
    message = _error({"dt": 0.01})
    assert message.startswith("dt: with dt = 0.01 s"), message
    assert "solver.max_horizon" in message and "object1" in message


@pytest.mark.parametrize(
    ("random", "prefix"),
    [
        ({"count": 10**9}, "random_objects.count: must be >= 1 and <= 200, got 1000000000"),
        ({"count": 100, "min_separation": 0.2}, "random_objects: 100 objects 0.2 m apart do not "
                                                 "fit"),
    ],
)
def test_random_objects_that_would_fill_memory_or_never_fit(random, prefix: str) -> None:
    assert _error({"random_objects": random}, "table1_vd").startswith(prefix)


# --- read as written: YAML 1.2 core schema, names as text, ranges, caps (issue 37) --------------


@pytest.mark.parametrize(
    ("text", "value"),
    [("010", 10), ("0x1F", 31), ("0o17", 15), ("+7", 7), ("1e1", 10.0)],
)
def test_numbers_by_the_yaml_1_2_core_schema(text: str, value) -> None:
    """YAML 1.1 (PyYAML) read 010 as 8 and 1:30 as 90; 1.2 has no octal without 0o."""
    assert parse_override(f"solver.max_horizon: {text}") == {"solver": {"max_horizon": value}}
    if isinstance(value, int):
        assert load_scenario("table1_vc", f"solver.max_horizon: {text}").solver.max_horizon \
            == value


@pytest.mark.parametrize("text", ["1:30", "yes", "no", "on", "off", "NO", "Yes", "y", "0b11",
                                  "1_000", "2001-01-01", "=", "<<"])
def test_yaml_1_1_forms_are_text(text: str) -> None:
    assert parse_override(f"name: {text}") == {"name": text}
    assert load_scenario("table1_vc", f"name: {text}").name == text
    assert _error(f"max_speed: {text}").startswith(f"max_speed: expected a number, got {text!r}")


def test_only_true_and_false_are_booleans() -> None:
    assert load_scenario("table1_vc", "pruning: False").task.pruning is False
    assert _error("pruning: yes").startswith("pruning: expected true or false, got 'yes'")


@pytest.mark.parametrize("text", [".inf", "-.inf", ".nan", ".NaN", "1e999"])
def test_infinities_are_refused_where_a_finite_number_is_needed(text: str) -> None:
    assert _error(f"max_speed: {text}").startswith("max_speed: expected a finite number")
    assert _error(f"objects[0].position[1]: {text}").startswith(
        "objects[0].position[1]: expected a finite number")


@pytest.mark.parametrize("name", ["NO", "1", "null", "1e3", "010", "0x1F", "true", "~", "1:30"])
def test_names_are_the_text_as_written(tmp_path, name: str) -> None:
    """A goal named NO was the boolean False; 1e3 was 1000.0: a key is always its text, and a
    number naming a goal is read as written."""
    path = tmp_path / "names.yaml"
    quoted = name if name in ("null", "true", "~") else None
    goal = f"'{name}'" if quoted else name
    path.write_text(f"goals: {{{name}: [0.2, 0.4, 0.5, 0.7]}}\n"
                    f"objects: [{{name: {goal}, position: [0.1, 0.1], goal: {goal}}}]\n"
                    "m_o: 1\nn_o: 1\n")
    s = load_scenario(str(path))
    assert list(s.task.goals) == [name]
    assert (s.task.objects[0].name, s.task.objects[0].goal) == (name, name)


@pytest.mark.parametrize("value", ["null", "true", "~", ""])
def test_null_or_true_as_a_name_asks_for_quotes(value: str) -> None:
    message = _error(f"objects[0].goal: {value}")
    assert message.startswith("objects[0].goal: expected text, got ") and "quote it" in message


def test_a_key_that_is_a_number_picks_a_list_element() -> None:
    """Keys are text, so ``objects: {2: ...}`` names element 2 by the text '2'."""
    s = load_scenario("table1_vc", "objects: {2: {goal: blue}}")
    assert s.task.objects[2].goal == "blue"


def test_duplicate_keys_name_both_lines(tmp_path) -> None:
    path = tmp_path / "dup.yaml"
    path.write_text("goals:\n  red: [0.2, 0.4, 0.5, 0.7]\n  red: [0.2, 0.4, 0.6, 0.7]\n")
    with pytest.raises(ScenarioError, match=rf"^{re.escape(str(path))}:3: duplicate key 'red' "
                                            rf"\(first at {re.escape(str(path))}:2\)$"):
        load_scenario(str(path))
    assert _error("solver: {workers: 1, workers: 2}") == (
        "override:1: duplicate key 'workers' (first at override:1)")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("a: &x [*x]", "override:1: an alias inside the node it names"),
        ("a: 1\n---\nb: 2", "override:2: not valid YAML: expected a single document in the "
                            "stream, but found another document"),
        ("? [1]\n: 2", "override:1: a key must be text, not a sequence"),
        ("name: !!python/name:os.system x", "override:1: not valid YAML: could not determine a "
                                            "constructor"),
        ("<<: {dt: 2}", "<<: unknown field"),
        ("a:\n\t- 1", "override:2: not valid YAML"),
        ("rules: &r [G true]\nname: *r", "name: expected text, got ['G true']"),
    ],
)
def test_yaml_an_adversary_writes(text: str, message: str) -> None:
    assert _error(text).startswith(message), _error(text)


def test_a_byte_order_mark_is_no_part_of_the_first_key(tmp_path) -> None:
    path = tmp_path / "bom.yaml"
    path.write_text("\ufeff" + Path(scenario_path("table1_vc")).read_text(), encoding="utf-8")
    assert load_scenario(str(path)) == load_scenario("table1_vc")


def test_alias_expansion_is_capped_before_anything_is_built() -> None:
    laughs = "a0: &a0 lol\n" + "".join(
        f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]\n" for i in range(1, 10))
    assert _error(laughs).startswith("override:7: more than 1,000,000 characters with its "
                                     "aliases (*name) expanded")
    # a few aliases are fine
    s = load_scenario("table1_vc", "goals: {red: &box [0.2, 0.5, 1.2, 1.4], blue: *box}")
    assert s.task.goals["blue"] == s.task.goals["red"]


def test_every_number_field_has_a_range() -> None:
    from dualarm_mpc.model.scenario import Event, ObjectSpec, RandomObjects, SolverSettings

    s = Scenario()
    numeric = (int, float, int | None, float | None, list[float], list[list[float]],
               dict[str, list[float]])
    for cls in (type(s.robot), type(s.table), type(s.task), SolverSettings, ObjectSpec,
                RandomObjects, Event):
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if hints[f.name] in numeric and f.name != "rule":  # rule: a choice, 1 or 2
                assert "range" in f.metadata, f"{cls.__name__}.{f.name}"


def test_the_docs_table_states_the_ranges_of_the_code() -> None:
    """docs/scenarios.md's Fields tables against each field's Range."""
    from dualarm_mpc.model.scenario import COORDINATE, _fields, _owner

    docs = (Path(__file__).parents[1] / "docs" / "scenarios.md").read_text()
    rows = dict(re.findall(r"^\| `([\w.\[\]]+)`[^|]*\|[^\n]*\| ([^|]*) \| [^|]* \|$", docs, re.M))
    s = Scenario()
    checked = 0
    for key, path in YAML_FIELDS.items():
        owner, name = _owner(s, path)
        value = getattr(owner, name)
        if dataclasses.is_dataclass(value) or name in ("random_objects", "events"):
            cls = {"solver": type(s.solver)}.get(key) or typing.get_args(
                typing.get_type_hints(type(owner))[name])[0]
            items = [(f"{key}{'[]' if name in ('objects', 'events') else ''}.{f}", fld)
                     for f, fld in _fields(cls).items()]
        else:
            items = [(key, _fields(type(owner))[name])]
        for doc_key, fld in items:
            rng = fld.metadata.get("range")
            if rng is None or doc_key not in rows:
                continue
            stated = rows[doc_key].strip()
            assert stated == ("coordinates" if rng == COORDINATE["range"] else str(rng)), doc_key
            checked += 1
    assert checked >= 25, checked


def test_the_largest_horizon_builds_a_program() -> None:
    """solver.max_horizon's maximum: the encoder once recursed T deep (RecursionError at 1000)."""
    from dualarm_mpc.milp.horizon import build_program
    from dualarm_mpc.model.mld import State
    from dualarm_mpc.model.scenario import MAX_HORIZON
    from dualarm_mpc.model.spec import StepProblem, specification

    s = load_scenario("table1_vd", {"random_objects": {"count": 1}, "m_o": 1, "n_o": 1,
                                    "rules": ["F theta[1]", "eta[1,1] U theta[1]",
                                              "G(eta[1,1] R theta[1])"],
                                    "solver": {"max_horizon": MAX_HORIZON}})
    prog, *_ = build_program(StepProblem(s, State.initial(s), specification(s, [0])), MAX_HORIZON)
    assert prog.num_vars() > MAX_HORIZON


def test_caps_are_checked_on_loading() -> None:
    many = [{"name": f"o{j}", "position": [0.0, 0.1], "goal": "red"} for j in range(201)]
    assert _error({"objects": many}).startswith("objects: 201 objects, at most 200")
    assert _error({"rules": ["G true & " * 2000 + "true"]}).startswith(
        "rules[0]: 18,004 characters, at most 10,000")
    assert _error({"objects[0].name": "y" * 20_000}).startswith(
        "objects[0].name: 20,000 characters, at most 10,000")
    assert _error({"random_objects": {"count": 14}, "task_form": "subsets", "m_o": 7,
                   "n_o": 14}, "table1_vd").startswith(
        "task_form: subsets makes φ_task a disjunction of 3,432 subsets")  # C(14, 7)
    load_scenario("table1_vc", {"task_form": "subsets", "m_o": 5, "n_o": 10})  # 252
    # the route bound's work: m_o·2^m_o stages, C(n_o, m_o)·2^m_o choices
    assert _error({"m_o": 11, "n_o": 11}).startswith("m_o: must be >= 1 and <= 10, got 11")
    assert _error({"random_objects": {"count": 20}, "m_o": 8, "n_o": 20}, "table1_vd") \
        .startswith("n_o: the route bound weighs 32,248,320 choices")  # C(20, 8)·2^8
    load_scenario("table1_vd", {"m_o": 10, "n_o": 10})  # 1,024: the largest step


def test_a_rule_given_twice_is_in_force_once() -> None:
    from dualarm_mpc.model.spec import rule_formulas

    s = load_scenario("table1_vc", {"rules": ["G !eta[1,2]", "G !eta[1,2]", "F theta[1]"]})
    assert [name for name, _ in rule_formulas(s)][-2:] == ["rules[0] G !eta[1,2]",
                                                           "rules[2] F theta[1]"]


@pytest.mark.parametrize(
    ("override", "prefix"),
    [
        ("arm_bases: [[3, -0.8], [-3, -0.8]]", "arm_bases: [[3.0, -0.8], [-3.0, -0.8]] are not the "
                                               "robot model's"),
        ("workspace: [-3, 3, 0, 3]", "workspace: [-3.0, 3.0, 0.0, 3.0] is not all within reach of "
                                     "arm 1, 0.4 to 2.2 m from its base"),
        ("workspace[2]: -0.5", "workspace: [-0.9, 0.9, -0.5, 0.9] is not all within reach"),
    ],
)
def test_the_arms_reach_the_whole_hand_range(override: str, prefix: str) -> None:
    """The simulation's inverse kinematics had no answer (a traceback) beyond the arms' reach."""
    assert _error(override).startswith(prefix), _error(override)


def test_the_rules_expansion_is_capped_with_the_horizon() -> None:
    from dualarm_mpc.model.spec import rule_formulas

    rule = "G(" + " | ".join(f"eta[{1 + k % 2},j]" for k in range(800)) + ")"  # 802 nodes
    s = load_scenario("table1_vc", {"rules": [rule], "n_o": 6})  # 6 instances: 4,812 nodes
    assert rule_formulas(s)
    s = load_scenario("table1_vc", {"rules": [rule], "n_o": 6, "solver.max_horizon": 1000})
    with pytest.raises(ScenarioError, match=r"^rules\[0\]: the rules up to this one expand "
                                            r"to 4,812 formula nodes .* 4,816,812 over the 1001"):
        rule_formulas(s)


@pytest.mark.parametrize(("text", "message"), [
    ("", "sets nothing"), ("null", "sets nothing"), ("{}", "sets nothing"),
    ("# a comment", "sets nothing"),
])
def test_an_override_that_sets_nothing_is_refused(text, message, capsys) -> None:
    """``--set ''`` and ``--set null`` exited 0 having done nothing (issue 52)."""
    from dualarm_mpc.cli.app import main

    with pytest.raises(ScenarioError, match=f"^override: {message}"):
        load_scenario("table1_vc", text)
    assert main(["check", "table1_vc", "--set", text]) == 2
    assert f"error: --set {text!r}: {message} (give 'field: value'" in capsys.readouterr().err


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n", "---\n"])
def test_an_empty_scenario_file_says_it_is_empty(tmp_path, text) -> None:
    """It was reported as "goals: at least one goal region is needed"."""
    path = tmp_path / "empty.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=r"empty.yaml: the file is empty \(blank or comments "
                       r"only\): a scenario needs at least goals and objects"):
        load_scenario(str(path))


@pytest.mark.parametrize(("event", "message"), [
    ({"kind": "move_object", "target": "object1", "position": [0.0, 0.1],
      "box": [0.0, 0.1, 0.0, 0.1]},
     r"^events\[0\].box: a move_object event has no box \(move_object takes position, "
     r"move_goal takes box\)$"),
    ({"kind": "move_goal", "target": "red", "box": [0.3, 0.6, 0.6, 0.9],
      "position": [0.0, 0.1]}, r"^events\[0\].position: a move_goal event has no position"),
    ({"time": 3.0, "kind": "move_object", "target": "object1", "position": [5.0, 0.1]},
     r"^events\[0\].position: object1 moved to \[5.0, 0.1\] at t = 3 s lies beyond the hands' "
     r"reach \(workspace \[-0.9, 0.9, -0.3, 0.9\] widened by its grasp_half_size 0.05\) and "
     r"outside its goal"),
])
def test_an_event_that_would_do_nothing_or_lose_its_object_is_refused(event, message) -> None:
    """A ``box`` on a move_object event was ignored; an object moved 5 m off the table ran the
    whole simulation and failed at its end without naming the event (issue 52)."""
    with pytest.raises(ScenarioError, match=message):
        load_scenario("table1_vd", {"events": [event]})
