"""The public API: ``import dualarm_mpc as dm`` gives every name a user needs, the library
functions the CLI calls return typed results, and the examples and the README use nothing else."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml

import dualarm_mpc as dm
from dualarm_mpc.model.mld import State

ROOT = Path(__file__).resolve().parents[1]
SCENE = {  # two objects a short carry from their goals, as tests/scenes.py's
    "name": "two",
    "goals": {"red": [0.2, 0.4, 0.5, 0.7], "blue": [-0.4, -0.2, 0.5, 0.7]},
    "objects": [{"name": "object1", "position": [0.1, 0.1], "goal": "red"},
                {"name": "object2", "position": [-0.1, 0.2], "goal": "blue"}],
    "m_o": 2, "n_o": 2, "solver": {"time_limit_s": 10.0},
}


def scene_file(tmp_path: Path, **overrides) -> str:
    path = tmp_path / "two.yaml"
    path.write_text(yaml.safe_dump({**SCENE, **overrides}))
    return str(path)


def test_every_public_name_loads_and_nothing_else_is_public() -> None:
    assert set(dm.__all__) == {"__version__", *dm._EXPORTS}
    for name in dm._EXPORTS:
        assert getattr(dm, name).__name__ == name, name
    assert set(dm.__all__) <= set(dir(dm))
    with pytest.raises(AttributeError, match="no attribute 'transport'"):
        dm.transport  # noqa: B018


def test_importing_the_package_loads_no_drake() -> None:
    done = subprocess.run([sys.executable, "-c", "import sys, dualarm_mpc as dm; dm.load_scenario"
                           "('table1_vc'); print('pydrake' in sys.modules)"],
                          capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"


def test_the_version_is_the_installed_one_and_the_cli_says_it() -> None:
    from importlib.metadata import version

    assert dm.__version__ == version("dualarm_mpc")
    done = subprocess.run([sys.executable, "-m", "dualarm_mpc.cli.app", "--version"],
                          capture_output=True, text=True, check=True)
    assert done.stdout.strip() == f"dualarm-mpc {dm.__version__}"


def test_the_package_is_typed() -> None:
    assert (resources.files("dualarm_mpc") / "py.typed").is_file()


def test_load_scenario_takes_the_robot_set_up_and_overrides_in_order(tmp_path) -> None:
    path = scene_file(tmp_path)
    robot = dm.load_scenario(path, on_robot=True)
    assert robot.task.delivery == "rest" and robot.task.goal_slots
    assert robot.task.object_clearance == dm.load_scenario(path, on_robot=True).task \
        .object_clearance > 0
    # --set-style texts and mappings, applied in order after the robot's set-up: later wins
    s = dm.load_scenario(path, ["delivery: reach", {"solver.time_limit_s": 3},
                                "solver.time_limit_s: 4"], on_robot=True)
    assert (s.task.delivery, s.solver.time_limit_s, s.task.goal_slots) == ("reach", 4.0, True)
    with pytest.raises(dm.ScenarioError, match="max_speed"):
        dm.load_scenario(path, ["max_speed: -1"])
    with pytest.raises(dm.ScenarioError, match="override 2: expected a mapping or YAML text"):
        dm.load_scenario(path, ["rule: 2", 5])


def test_plan_returns_a_verified_plan_whose_objects_end_in_their_goals(tmp_path) -> None:
    scenario = dm.load_scenario(scene_file(tmp_path))
    plan = dm.plan(scenario)
    assert isinstance(plan, dm.Plan) and plan.verified and not plan.partial
    end = State.last(plan.trajectory)
    assert dm.delivered_objects(scenario, end.object_pos, end.object_vel).all()
    assert all(step is not None for step in plan.delivered_step)


def test_plan_refuses_a_task_its_rules_forbid_naming_the_objects(tmp_path) -> None:
    scenario = dm.load_scenario(scene_file(tmp_path, rules=["G !eta[1,1] & G !eta[2,1]"]))
    assert not dm.check(scenario).consistent
    with pytest.raises(dm.ConflictError) as caught:
        dm.plan(scenario)
    assert caught.value.proven
    assert [c.objects for c in caught.value.report.conflicts] == [("object1",)]


def test_a_stopped_plan_comes_back_partial_and_unverified(tmp_path) -> None:
    stop = dm.Interrupt()
    stop.set()
    plan = dm.plan(dm.load_scenario(scene_file(tmp_path)), stop=stop)
    assert plan.partial and not plan.verified


def _private_imports(source: str) -> list[str]:
    """The package's modules a script imports past its top level."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("dualarm_mpc."):
            found.append(node.module)
        elif isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.startswith("dualarm_mpc.")]
    return found


def readme_snippets() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)


@pytest.mark.parametrize("script", sorted((ROOT / "examples").glob("*.py")), ids=lambda p: p.name)
def test_the_examples_use_only_the_public_api(script: Path) -> None:
    assert _private_imports(script.read_text()) == []


def test_the_readme_snippets_use_only_the_public_api() -> None:
    snippets = readme_snippets()
    assert snippets, "the README shows the Python API"
    for code in snippets:
        assert _private_imports(code) == []


@pytest.mark.slow
def test_the_readme_snippets_run(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    for code in readme_snippets():
        exec(compile(code, "README.md", "exec"), {"__name__": "readme"})
    assert np.all([p.stat().st_size > 0 for p in tmp_path.rglob("*.png")])


@pytest.mark.parametrize(("field", "value", "key"), [
    ("solver.time_limit_s", -1.0, "solver.time_limit_s"),
    ("solver.time_limit_s", float("nan"), "solver.time_limit_s"),
    ("task.m_o", 0, "m_o"),
    ("task.goals", {"red": [0.4, 0.2, 0.5, 0.7], "blue": [-0.4, -0.2, 0.5, 0.7]}, "goals"),
])
def test_the_library_refuses_what_the_command_line_refuses_in_its_words(tmp_path, capsys, field,
                                                                         value, key) -> None:
    """A scenario changed after loading is checked again by ``dm.check``, ``dm.plan`` and
    ``dm.simulate`` (``Scenario.validate``, what ``load_scenario`` and so the CLI run)."""
    import dataclasses
    import json

    from dualarm_mpc.cli.app import main

    scenario = dm.load_scenario(scene_file(tmp_path))
    group, name = field.split(".")
    bad = dataclasses.replace(scenario, **{group: dataclasses.replace(getattr(scenario, group),
                                                                       **{name: value})})
    messages = set()
    for entry in (dm.check, dm.plan, dm.simulate):
        with pytest.raises(dm.ScenarioError) as caught:
            entry(bad)
        messages.add(str(caught.value))
    assert len(messages) == 1
    capsys.readouterr()
    code = main(["check", scene_file(tmp_path), "--set",
                 f"{key}: {json.dumps(value) if value == value else '.nan'}"])
    said = messages.pop()  # the value as the caller wrote it: nan, or YAML's .nan
    assert code == 2 and said.rsplit(" got ", 1)[0] in capsys.readouterr().err


def test_the_library_refuses_a_duration_the_command_line_refuses(tmp_path, capsys) -> None:
    from dualarm_mpc.cli.app import main

    scenario = dm.load_scenario(scene_file(tmp_path))
    with pytest.raises(dm.ScenarioError, match="^duration: must be a positive number of seconds, "
                                               "got -1$"):
        dm.simulate(scenario, duration=-1)
    with pytest.raises(SystemExit):
        main(["simulate", scene_file(tmp_path), "--duration", "-1"])
    assert "argument --duration: must be a positive number of seconds, got -1" in \
        capsys.readouterr().err
