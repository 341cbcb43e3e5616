"""bench/solvers.py: the side-by-side table counts models over a licence apart, compares costs
only where both solvers have a plan, and times on the same steps; one real step per backend."""

from __future__ import annotations

import argparse

import pytest
import solvers

from dualarm_mpc.milp.solver import installed_backends


def solve(backend, method, step, status, cost, cpu, constraints=900):
    return {"m_o": 2, "n_o": 5, "rule": 1, "seed": 0, "step": step, "horizon": 6,
            "variables": 400, "constraints": constraints, "backend": backend, "method": method,
            "load_avg_1min": 1.0, "status": status, "cost": cost, "wall_s": cpu, "cpu_s": cpu}


def test_the_summary_compares_like_with_like() -> None:
    solves = [solve("highs", "search", 1, "optimal", 1.0, 2.0),
              solve("highs", "search", 2, "optimal", 3.0, 4.0, constraints=1500),
              solve("cplex", "monolithic", 1, "optimal", 1.0, 0.5),
              {**solve("cplex", "monolithic", 2, "over_licence", None, None, 1500),
               "cost": None, "wall_s": None, "cpu_s": None}]
    rows = {(s["backend"], s["method"]): s
            for s in solvers.summarize(solves, ["highs", "cplex"])}
    cplex = rows["cplex", "monolithic"]
    assert (cplex["models"], cplex["within_licence"], cplex["largest_within"]) == (2, 1, 900)
    assert cplex["cost"] == cplex["highs_search_cost"] == 1.0
    assert (cplex["cpu_s"], cplex["highs_search_cpu_s"]) == (0.5, 2.0)
    assert rows["highs", "search"]["cost"] == 4.0
    assert rows["cplex", "search"]["models"] == 0
    text = solvers.report(solves, argparse.Namespace(seeds=[0], time_limit=10.0,
                                                     solvers=["highs", "cplex"]))
    assert "| (2,5) rule 1 | cplex | monolithic | 1/2 (900) | 1/1 | 1.000 (1.000) |" in text


@pytest.mark.parametrize("backend", installed_backends())
def test_one_step_on_every_installed_backend(backend) -> None:
    from dualarm_mpc.model.mld import State
    from dualarm_mpc.model.scenario import load_scenario
    from dualarm_mpc.model.spec import StepProblem, specification
    from dualarm_mpc.planning.sequential import predict_horizon

    s = load_scenario("table1_vd", {"m_o": 1, "n_o": 1, "rule": 2, "delivery": "reach"})
    problem = StepProblem(s, State.initial(s), specification(s, [0]))
    T = predict_horizon(problem)
    got = [solvers.solve_one(problem, T + 1, backend, m) for m in solvers.METHODS]
    assert [g["status"] for g in got] == ["optimal", "optimal"]
    assert got[0]["cost"] == pytest.approx(got[1]["cost"], rel=2e-4)
