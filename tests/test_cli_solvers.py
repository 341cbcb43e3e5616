"""``--solver NAME`` on the command line: a plan with every installed backend (solved by it, at
the same cost as HiGHS), and one clear line for a solver that is unknown or not installed."""

from __future__ import annotations

import importlib.util
import json

import pytest
from test_backends import EVERY

from dualarm_mpc.cli.app import main
from dualarm_mpc.milp import backends
from dualarm_mpc.milp.solver import BACKENDS

SCENARIO = """\
name: cli_solvers
goals:
  red: [0.2, 0.4, 0.5, 0.7]
objects:
  - {name: object1, position: [0.1, 0.1], goal: red}
rule: 2
m_o: 1
n_o: 1
solver: {time_limit_s: 30, max_horizon: 15}
"""


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    return path


@pytest.fixture(scope="module")
def highs_cost(tmp_path_factory) -> dict[str, float]:
    """HiGHS's cost by search: the skeleton search's default horizon policy (the witness) may
    take a longer, cheaper horizon than the monolithic Algorithm 1's first plan."""
    d = tmp_path_factory.mktemp("highs")
    (d / "s.yaml").write_text(SCENARIO)
    costs = {}
    for search in ("skeleton", "monolithic"):
        out = d / f"{search}.json"
        assert main(["plan", str(d / "s.yaml"), "--search", search, "--out", str(out)]) == 0
        costs[search] = json.loads(out.read_text())["total_cost"]
    return costs


@pytest.mark.parametrize("backend", EVERY)
@pytest.mark.parametrize("search", ["skeleton", "monolithic"])
def test_plan_with_every_installed_solver(scenario, tmp_path, backend, search,
                                          highs_cost, monkeypatch) -> None:
    solved_by = []  # the backend of each solve the plan made, each still the real solve

    def counted(name: str):
        real = backends.ADAPTERS[name]
        return lambda *args: (solved_by.append(name), real(*args))[1]

    for name in BACKENDS:
        monkeypatch.setitem(backends.ADAPTERS, name, counted(name))
    out = tmp_path / "plan.json"
    assert main(["plan", str(scenario), "--solver", backend, "--search", search,
                 "--out", str(out)]) == 0
    assert solved_by and set(solved_by) == {backend}
    assert json.loads(out.read_text())["total_cost"] == pytest.approx(highs_cost[search], rel=2e-4)


def test_an_unknown_solver_is_one_line(scenario, capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["plan", str(scenario), "--solver", "glpk"])
    assert exit_.value.code == 2
    assert "invalid choice: 'glpk'" in capsys.readouterr().err


def test_a_solver_not_installed_is_one_line(scenario, capsys, monkeypatch) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "pyscipopt" else real(name, *a))
    assert main(["plan", str(scenario), "--solver", "scip"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: solver 'scip' is not installed here") and "\n" not in err
