"""Tests for cli.app: ``dualarm-mpc plan`` writes the plan JSON of the issue and a PNG, and
fails with the reason (never a traceback) on a bad scenario or an infeasible task."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dualarm_mpc.cli.app import main
from dualarm_mpc.model.plan import Plan
from dualarm_mpc.model.scenario import load_scenario
from dualarm_mpc.model.verify import verify

SCENARIO = """\
name: cli_small
goals:
  red: [0.2, 0.4, 0.5, 0.7]
  blue: [-0.4, -0.2, 0.5, 0.7]
objects:
  - {name: object1, position: [0.1, 0.1], goal: red}
  - {name: object2, position: [-0.1, 0.2], goal: blue}
  - {name: object3, position: [0.0, 0.1], goal: red, grasp_half_size: 0.04}
rule: 1
m_o: 2
n_o: 3
solver: {time_limit_s: 10, max_horizon: 15}
"""

# The plan JSON of the issue, field by field.
TOP = {
    "dt",
    "rule",
    "delivery",
    "goals",
    "objects",
    "workspace",
    "trajectory",
    "delivered_step",
    "segments",
    "total_cost",
    "total_solve_time_s",
}
OBJECT = {"name", "goal", "grasp_half_size"}
TRAJECTORY = {"hand_pos", "hand_vel", "force", "object_pos", "object_vel", "grasp"}
SEGMENT = {"objects", "delivered", "horizon", "status", "solve_time_s", "cost"}


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    scenario = d / "small.yaml"
    scenario.write_text(SCENARIO)
    out, png = d / "plan.json", d / "plan.png"
    code = main(["plan", str(scenario), "--out", str(out), "--plot", str(png)])
    return code, scenario, out, png


def test_plan_exits_zero_and_writes_both_files(planned, capsys) -> None:
    code, _, out, png = planned
    assert code == 0
    assert out.is_file() and png.is_file()
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 10_000


def test_plan_json_has_the_issues_fields(planned) -> None:
    """The issue's fields, each with its shape, are all there; "more are welcome"."""
    data = json.loads(planned[2].read_text())
    assert TOP <= set(data), sorted(TOP - set(data))
    assert TRAJECTORY <= set(data["trajectory"]), sorted(TRAJECTORY - set(data["trajectory"]))
    assert isinstance(data["goals"], dict) and len(data["workspace"]) == 4
    assert isinstance(data["objects"], list) and isinstance(data["segments"], list)
    assert len(data["delivered_step"]) == len(data["objects"]) == 3
    for o in data["objects"]:
        assert OBJECT <= set(o), sorted(OBJECT - set(o))
    for s in data["segments"]:
        assert SEGMENT <= set(s), sorted(SEGMENT - set(s))
        assert isinstance(s["objects"], list) and isinstance(s["delivered"], list)


def test_plan_json_values(planned) -> None:
    _, scenario_path, out, _ = planned
    data = json.loads(out.read_text())
    assert data["dt"] == 1.0 and data["rule"] == 1 and data["delivery"] == "reach"
    assert data["goals"] == {"red": [0.2, 0.4, 0.5, 0.7], "blue": [-0.4, -0.2, 0.5, 0.7]}
    assert data["objects"] == [
        {"name": "object1", "goal": "red", "grasp_half_size": 0.05},
        {"name": "object2", "goal": "blue", "grasp_half_size": 0.05},
        {"name": "object3", "goal": "red", "grasp_half_size": 0.04},
    ]
    assert data["workspace"] == [-0.9, 0.9, 0.0, 0.9]
    t = {k: np.asarray(v) for k, v in data["trajectory"].items()}
    K, N = len(t["force"]), 3
    assert K == sum(s["horizon"] for s in data["segments"]) > 0
    assert t["hand_pos"].shape == t["hand_vel"].shape == (K + 1, 2, 2)
    assert t["force"].shape == (K, 2, 2)
    assert t["object_pos"].shape == t["object_vel"].shape == (K + 1, N, 2)
    assert t["grasp"].shape == (K + 1, 2, N)
    assert set(np.unique(t["grasp"])) <= {0, 1}
    assert all(isinstance(g, int) for g in np.ravel(data["trajectory"]["grasp"]).tolist())
    assert len(data["delivered_step"]) == N
    assert all(isinstance(k, int) and 0 <= k <= K for k in data["delivered_step"])
    delivered = sorted(j for s in data["segments"] for j in s["delivered"])
    assert delivered == [0, 1, 2]
    for s in data["segments"]:
        assert s["status"] == "optimal"
        assert isinstance(s["horizon"], int) and s["horizon"] > 0
        assert s["solve_time_s"] >= 0 and s["cost"] >= 0
        assert set(s["delivered"]) <= set(s["objects"]) <= {0, 1, 2}
    assert data["total_cost"] == pytest.approx(sum(s["cost"] for s in data["segments"]))
    assert data["total_cost"] == pytest.approx(np.abs(t["force"]).sum(), abs=1e-6)
    assert data["total_solve_time_s"] == pytest.approx(
        sum(s["solve_time_s"] for s in data["segments"]), abs=1e-3
    )
    # The file is a plan the oracle accepts.
    scenario = load_scenario(str(scenario_path))
    check = verify(scenario, Plan.from_json(data))
    assert check.ok, check.problems


def test_plan_prints_a_table_and_the_verdict(tmp_path, capsys) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    assert main(["plan", str(path), "--rule", "2", "--set", "delivery: rest"]) == 0
    out = capsys.readouterr().out
    assert "rule 2" in out and "delivery rest" in out and "verified" in out


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (["--set", "max_speed: fast"], "max_speed"),
        (["--set", "solver: {time_limt_s: 3}"], "solver.time_limt_s"),
        (["--set", "objects: [{name: a, position: [0, 0], goal: purple}]"], "objects[0].goal"),
        (["--mo", "4"], "m_o"),
    ],
)
def test_bad_scenario_value_exits_nonzero_naming_the_field(tmp_path, capsys, args, field) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    code = main(["plan", str(path), *args])
    err = capsys.readouterr().err
    assert code != 0
    assert field in err and "error" in err


def test_bad_value_in_the_file_exits_nonzero(tmp_path, capsys) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO.replace("rule: 1", "rule: 5"))
    assert main(["plan", str(path)]) != 0
    assert "rule" in capsys.readouterr().err


def test_missing_scenario_file_exits_nonzero(tmp_path, capsys) -> None:
    assert main(["plan", str(tmp_path / "nope.yaml")]) != 0
    assert "nope.yaml" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("rule", "named"),
    [("G ((", "rules[0]"), ("F foo", "foo"), ("G !theta[1]", "theta[1]")],
)
def test_bad_rule_exits_nonzero_with_the_reason(tmp_path, capsys, rule, named) -> None:
    """A rule that does not parse, names an unknown atom or negates a goal atom is a user error:
    a non-zero exit with the reason on stderr, not a traceback."""
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    code = main(["plan", str(path), "--set", f"rules: ['{rule}']"])
    err = capsys.readouterr().err
    assert code != 0 and named in err


def test_infeasible_task_exits_nonzero_with_the_reason(tmp_path, capsys) -> None:
    path = tmp_path / "far.yaml"
    path.write_text(
        "name: far\n"
        "goals: {red: [0.225, 0.575, 1.15, 1.45]}\n"
        "objects: [{name: object1, position: [0.1, 0.1], goal: red}]\n"
        "max_speed: 0.5\nmax_force: 0.5\nrule: 1\nm_o: 1\nn_o: 1\n"
        "solver: {max_horizon: 8}\n"
    )
    out = tmp_path / "plan.json"
    code = main(["plan", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    assert code != 0
    assert "no-throw" in err and "object1" in err
    assert not out.exists()


# --- issue 7: bad input is refused before the work, nothing to do is not an error --------------


def _never_plan(monkeypatch) -> None:
    import dualarm_mpc.planning.sequential

    def transport(*args, **kwargs):
        raise AssertionError("planned although the input was bad")

    monkeypatch.setattr(dualarm_mpc.planning.sequential, "transport", transport)


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [
        ("--out", "{tmp}/missing/plan.json", "argument --out: directory {tmp}/missing does not"),
        ("--out", "{tmp}", "argument --out: {tmp} is a directory"),
        ("--out", "/proc/plan.json", "argument --out: cannot write /proc/plan.json"),
        ("--plot", "{tmp}/plan.xyz", "argument --plot: unknown plot format 'xyz'"),
        ("--plot", "{tmp}/plan", "argument --plot: unknown plot format '(no suffix)'"),
        ("--plot", "{tmp}/missing/plan.png", "argument --plot: directory {tmp}/missing does not"),
    ],
)
def test_output_paths_are_checked_before_planning(tmp_path, capsys, monkeypatch, flag, value,
                                                  message) -> None:
    """Before: the plan was made, then writing it failed with a traceback and the work was
    lost."""
    _never_plan(monkeypatch)
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    with pytest.raises(SystemExit) as exit_:
        main(["plan", str(path), flag, value.format(tmp=tmp_path)])
    assert exit_.value.code == 2
    assert message.format(tmp=tmp_path) in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.yaml"]  # the probe left nothing


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["simulate", "{s}", "--duration", "0"], "argument --duration: must be a positive"),
        (["simulate", "{s}", "--duration", "inf"], "argument --duration: must be a positive"),
        (["simulate", "{s}", "--duration", "-2"], "argument --duration: must be a positive"),
        (["simulate", "{s}", "--html", "{tmp}/no/r.html"], "argument --html: directory"),
        (["simulate", "{s}", "--summary", "{tmp}/no/s.json"], "argument --summary: directory"),
        (["simulate", "{s}", "--plot", "{tmp}/run.xyz"], "argument --plot: unknown plot format"),
        (["simulate", "{s}", "--plot", "{tmp}/no/run.png"], "argument --plot: directory"),
        (["plan", "{s}", "--seed", "-1"], "argument --seed: must be >= 0, got -1"),
        (["plan", "{s}", "--mo", "0"], "argument --mo: must be >= 1, got 0"),
        (["plan", "{s}", "--time-limit", "nan"], "argument --time-limit: must be a positive"),
    ],
)
def test_bad_flags_name_the_flag(tmp_path, capsys, args, message) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    with pytest.raises(SystemExit) as exit_:
        main([a.format(s=path, tmp=tmp_path) for a in args])
    assert exit_.value.code == 2
    assert message.format(tmp=tmp_path) in capsys.readouterr().err


def test_set_takes_field_paths_and_yaml_1_2_numbers(tmp_path, capsys) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    out = tmp_path / "plan.json"
    code = main(["plan", str(path), "--set", "solver.mip_rel_gap: 1e-3",
                 "--set", "objects[2].grasp_half_size: 0.03", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    assert json.loads(out.read_text())["objects"][2]["grasp_half_size"] == 0.03


def test_nothing_to_do_exits_zero_and_writes_the_plan(tmp_path, capsys) -> None:
    """Before: a crash (no trajectory)."""
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    out = tmp_path / "plan.json"
    code = main(["plan", str(path), "--set", "objects: [{name: a, position: [0.3, 0.6], "
                 "goal: red}]", "--mo", "1", "--no", "1", "--out", str(out)])
    stdout = capsys.readouterr().out
    assert code == 0
    assert "nothing to do: every object already rests in its goal" in stdout
    assert "total: 1/1 resting in their goals (1 already there)" in stdout
    data = json.loads(out.read_text())
    assert data["segments"] == [] and data["delivered_step"] == [0]


def test_objects_already_in_their_goals_count_as_resting(tmp_path, capsys) -> None:
    """Before: "1/2 delivered", next to "every object rests in its goal"."""
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    code = main(["plan", str(path), "--set", "objects: [{name: a, position: [0.3, 0.6], "
                 "goal: red}, {name: b, position: [0.1, 0.1], goal: red}]"])
    stdout = capsys.readouterr().out
    assert code == 0
    assert "total: 2/2 resting in their goals (1 already there)" in stdout


def test_an_m_o_beyond_the_objects_left_is_told(tmp_path, capsys) -> None:
    """Before: m_o was lowered to the objects left without a word."""
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    assert main(["plan", str(path), "--mo", "3", "--no", "3", "--set", "objects: "
                 "[{name: a, position: [0.1, 0.1], goal: red}, {name: b, position: [-0.1, 0.2], "
                 "goal: blue}]"]) == 0
    stdout = capsys.readouterr().out
    assert "note: m_o = 3, but 2 object(s) are left to deliver: a step delivers 2" in stdout
    assert "(m_o = 2: the objects left)" in stdout


# --- issue 51: output for people ------------------------------------------------------------------


def test_plan_groups_the_horizons_tried_under_their_step(tmp_path, capsys) -> None:
    """Before: a step's horizons without a plan printed above its numbered line, unlabelled
    (the demo's first line was an orphan ``4 90 infeasible``)."""
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    out = tmp_path / "plan.json"
    assert main(["plan", str(path), "--set", "solver.handover: never", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    segments = json.loads(out.read_text())["segments"]
    start = lines.index("the horizons T each sequential step tried, the step's plan last:")
    assert lines[start + 1].split() == ["T", "binaries", "status", "solve", "[s]", "cost",
                                        "delivered"]
    table = lines[start + 2:lines.index(next(x for x in lines if x.startswith("total:")))]
    headers = [k for k, line in enumerate(table) if line.startswith("step ")]
    assert [table[k].split(":")[0] for k in headers] == [f"step {s + 1}"
                                                         for s in range(len(segments))]
    assert headers[0] == 0  # no row above the first step's header
    for s, (k, end) in enumerate(zip(headers, [*headers[1:], len(table)], strict=True)):
        rows = [line.split() for line in table[k + 1:end]]
        # the step's plan last: its horizon and the objects it delivers
        assert rows[-1][0] == str(segments[s]["horizon"]) and rows[-1][2] == "optimal"
        assert rows[-1][5] == ",".join(str(j + 1) for j in segments[s]["delivered"])
        assert all(r[2] not in ("optimal", "feasible") for r in rows[:-1])


def test_check_prints_objects_that_conflict_alike_as_one_line(tmp_path, monkeypatch,
                                                                capsys) -> None:
    from dualarm_mpc.planning import consistency

    why = "the goal lies beyond the hands' reach (…) and no-throw (18) forbids …"
    alike = [consistency.Conflict((f"object{j}",), ("no-throw (18)",), f"object{j} → red: {why}",
                                  why) for j in (1, 2, 3, 5)]
    other = consistency.Conflict(("object4",), (), "object4 → red: no plan brings it", "no plan")
    monkeypatch.setattr(consistency, "check", lambda *a, **k: consistency.Report(
        (*alike, other), (), 10))
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    assert main(["check", str(path)]) == 3
    assert capsys.readouterr().out.splitlines() == [f"conflict: objects 1–3, 5: {why}",
                                                    "conflict: object4 → red: no plan brings it"]


def _replan(t: float, status: str = "kept", delivered: int = 0, adopted: bool = False,
            objects=(0,), note: str = "on the proven plan"):
    from dualarm_mpc.planning.mpc import Replan

    return Replan(t, 0.01 * (t + 1), status, None, None, objects, delivered, note, t, adopted)


def _table(monkeypatch, capsys, tty: bool):
    from dualarm_mpc.cli.commands import _ReplanTable

    monkeypatch.setattr("sys.stdout.isatty", lambda: tty)
    table = _ReplanTable(load_scenario("table1_vc"), 40.0)
    for r in [_replan(0.0, "optimal", adopted=True), _replan(1.0), _replan(2.0), _replan(3.0),
              _replan(4.0, delivered=2), _replan(5.0, "optimal", 2, True, (1, 2), ""),
              _replan(6.0, "done", 4, True, (), ""), _replan(7.0, "done", 4, True, (), "")]:
        table(r)
    table.finish()
    return capsys.readouterr().out


def test_simulate_prints_a_run_of_replans_that_change_nothing_as_one_line(monkeypatch,
                                                                          capsys) -> None:
    """Before: 45 of the demo's 61 lines were identical ``kept`` lines."""
    out = _table(monkeypatch, capsys, tty=False)
    assert "\r" not in out  # plain lines: no progress line off a terminal
    assert [line.split()[:4] for line in out.splitlines()[1:]] == [
        ["0.0", "0/10", "optimal", "-"],
        ["1.0–3.0", "0/10", "kept", "×3"],  # the longest solve of the three: 3.0's
        ["4.0", "2/10", "kept", "-"],  # objects delivered changed: a line of its own
        ["5.0", "2/10", "optimal", "-"],
        ["6.0–7.0", "4/10", "done", "×2"],  # the same hold at rest
    ]
    assert "0.040  1  (on the proven plan)" in out.splitlines()[2]


def test_simulate_shows_its_progress_in_one_line_on_a_terminal(monkeypatch, capsys) -> None:
    out = _table(monkeypatch, capsys, tty=True)
    shown = [part for part in out.split("\r\x1b[K") if part.startswith("step ")]
    assert len(shown) == 8  # one per replan, each over the last
    assert shown[0] == "step 1, delivered 0/10, t = 0.0 s"
    assert shown[4].startswith("step 1, delivered 2/10, t = 4.0 s, real-time factor ")
    assert " s left" in shown[4] and "step 2, delivered 2/10, t = 5.0 s" in shown[5]
    # a table line clears the progress line first, and the run ends on a line of the table
    assert "\r\x1b[K    1.0–3.0      0/10   kept ×3" in out
    assert out.split("\r\x1b[K")[-1].startswith("    6.0–7.0") and out.endswith("\n")


def test_drakes_irrelevant_log_lines_are_dropped_at_the_source(caplog) -> None:
    """Before: every ``simulate`` printed Drake's deformable half-space warning, and with
    ``--html`` the URL of a Meshcat server nobody was to open."""
    import logging

    from pydrake.geometry import Meshcat, MeshcatParams

    import dualarm_mpc.sim.station  # noqa: F401  (installs the filter)

    drake = logging.getLogger("drake")
    with caplog.at_level(logging.INFO, logger="drake"):
        Meshcat(MeshcatParams(port=0))
        drake.warning("Rigid (non-deformable) half spaces are not currently supported for "
                      "deformable contact; registration is allowed")
        drake.warning("something else")
    assert [r.getMessage() for r in caplog.records] == ["something else"]


def test_plan_mo_all_plans_every_object_in_one_step_with_its_certificate(tmp_path,
                                                                         capsys) -> None:
    """``--mo all``: m_o = n_o = every object, one search; ``--gap`` is solver.mip_rel_gap;
    the certificate is printed and written (docs/formats.md)."""
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    out = tmp_path / "plan.json"
    assert main(["plan", str(path), "--mo", "all", "--gap", "0.01", "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "(m_o, n_o) = (3, 3)" in stdout and "certificate: cost " in stdout
    data = json.loads(out.read_text())
    first = data["segments"][0]
    assert first["objects"] == [0, 1, 2] and first["gap"] <= 0.01
    assert first["bound"] <= first["cost"] and first["search_stats"]["expansions"] >= 1
    assert data["total_bound"] == pytest.approx(sum(s["bound"] for s in data["segments"]))
    # anytime from sequential transportation's plan, joined (task.FIRST_PASS)
    assert "first verified plan: cost " in stdout and "steps, joined" in stdout
    assert first["sequential_steps"] is None  # the search's plan replaced it
    assert 0 < data["first_plan_s"] <= data["total_solve_time_s"] + 1e-3
    assert data["unused_solve_time_s"] > 0


def test_plan_budget_writes_the_best_complete_plan_when_it_runs_out(tmp_path, capsys) -> None:
    """``--budget``: the whole task's search, stopped, leaves its first plan (sequential
    transportation's, joined into one step), written whole and verified, exit 0."""
    out = tmp_path / "plan.json"
    assert main(["plan", "table1_vd", "--mo", "all", "--seed", "2", "--rule", "1",
                 "--set", "random_objects: {count: 5}", "--delivery", "rest",
                 "--budget", "6", "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "budget of 6 s spent: the best complete plan so far" in stdout
    assert "verified: " in stdout and "certificate: " in stdout
    data = json.loads(out.read_text())
    (step,) = data["segments"]
    assert step["sequential_steps"] >= 2 and step["objects"] == [0, 1, 2, 3, 4]
    assert not step["horizon_proven_minimal"]
    assert 0 < step["bound"] < step["cost"]  # the motion bound: no search bounded the cost
    assert all(d is not None for d in data["delivered_step"])
