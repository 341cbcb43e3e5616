"""``dualarm-mpc plan --export DIR``: the monolithic MILP of every horizon tried as an MPS file and
an index naming step, horizon, objects and status; the files read back into HiGHS (and SCIP,
where installed) give the planner's verdicts and optima."""

from __future__ import annotations

import importlib.util
import json

import pytest
from scenes import TWO_OBJECTS, yaml_text

from dualarm_mpc.cli.app import main

SCENARIO = yaml_text(TWO_OBJECTS, name="export", rule=1, m_o=1,
                     solver={"time_limit_s": 30, "max_horizon": 15, "search": "monolithic"})


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    d = tmp_path_factory.mktemp("export")
    (d / "s.yaml").write_text(SCENARIO)
    out = d / "mps"  # made by the run
    assert main(["plan", str(d / "s.yaml"), "--export", str(out),
                 "--out", str(d / "plan.json")]) == 0
    return json.loads((out / "index.json").read_text()), out, \
        json.loads((d / "plan.json").read_text())


def test_the_index_names_every_horizon_tried(exported) -> None:
    index, out, plan = exported
    assert index["scenario"] == "export" and index["search"] == "monolithic"
    rows = index["horizons"]
    assert [r["step"] for r in rows] == sorted(r["step"] for r in rows)
    solved = [r for r in rows if r["status"] == "optimal"]
    assert [r["horizon"] for r in solved] == [s["horizon"] for s in plan["segments"]]
    for r in rows:
        assert r["file"] == f"step{r['step']:02d}_T{r['horizon']:02d}.mps"
        assert (out / r["file"]).is_file()
        assert r["objects"] and set(r["objects"]) <= {"object1", "object2"}
    assert {r["status"] for r in rows} <= {"optimal", "infeasible"}


def _highs(path):
    import highspy

    solver = highspy.Highs()
    solver.setOptionValue("output_flag", False)
    solver.readModel(str(path))
    solver.run()
    return solver.modelStatusToString(solver.getModelStatus()).lower(), \
        solver.getInfo().objective_function_value


def test_the_files_give_the_planners_verdicts_and_optima(exported) -> None:
    index, out, plan = exported
    for r in index["horizons"]:
        status, objective = _highs(out / r["file"])
        assert status == r["status"], r
        if r["cost"] is not None:
            assert objective == pytest.approx(r["cost"], rel=2e-4)


@pytest.mark.skipif(importlib.util.find_spec("pyscipopt") is None,
                    reason="pyscipopt is not installed (pip install '.[scip]')")
def test_another_solver_reads_them(exported) -> None:
    import pyscipopt

    index, out, _ = exported
    for r in index["horizons"]:
        m = pyscipopt.Model()
        m.hideOutput()
        m.readProblem(str(out / r["file"]))
        m.optimize()
        assert m.getStatus() == r["status"], r
        if r["cost"] is not None:
            assert m.getObjVal() == pytest.approx(r["cost"], rel=2e-4)


def test_an_export_path_that_is_a_file_is_refused(tmp_path, capsys) -> None:
    (tmp_path / "s.yaml").write_text(SCENARIO)
    (tmp_path / "taken").write_text("")
    with pytest.raises(SystemExit) as exit_:
        main(["plan", str(tmp_path / "s.yaml"), "--export", str(tmp_path / "taken")])
    assert exit_.value.code == 2
    assert "is not a directory" in capsys.readouterr().err
