"""Every installed solver backend (``backends.py``) on the same small programs and steps: the
same optima as HiGHS, the same statuses, bounds and gaps, MIP starts, time limits, stop
requests, and a one-line error for a backend that cannot solve (unknown, not installed, a model
over its free licence). The ``test`` extra installs every backend, Gurobi and CPLEX with their pip
packages' size-limited licences, within which every program here stays. A backend not installed
is skipped with the reason, except under CI, where that fails (conftest.py)."""

from __future__ import annotations

import dataclasses
import importlib.util
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from pydrake.solvers import MathematicalProgram
from test_program import knapsack, market_split

from dualarm_mpc.milp import backends
from dualarm_mpc.milp.backends import solve, solve_standard_form
from dualarm_mpc.milp.horizon import HorizonProgram, solve_step
from dualarm_mpc.milp.solver import (
    BACKENDS,
    Interrupt,
    SolveOptions,
    SolverUnavailable,
    Status,
    installed_backends,
    standard_form,
)
from dualarm_mpc.model.mld import State
from dualarm_mpc.model.scenario import SOLVER_BACKENDS, load_scenario
from dualarm_mpc.model.spec import StepProblem, specification
from dualarm_mpc.planning.sequential import predict_horizon, select_objects
from dualarm_mpc.search.skeleton import search_step


def _param(name: str):
    module, extra = BACKENDS[name]
    missing = importlib.util.find_spec(module) is None
    return pytest.param(name, id=name, marks=pytest.mark.skipif(
        missing, reason=f"{module} is not installed (pip install '.[{extra}]')"))


EVERY = [_param(name) for name in BACKENDS]
OTHERS = [_param(name) for name in BACKENDS if name != "highs"]


# What each solver says when its time limit stopped it, and when a stop request did: a solve
# that ended for another reason (a limit not passed on, a stop not heard) fails the tests.
SAYS_TIME_LIMIT = {"highs": "Time limit reached", "scip": "SCIP status timelimit",
                   "gurobi": "Gurobi status 9", "cplex": "time limit exceeded"}
SAYS_INTERRUPTED = {"highs": "Interrupted by user", "scip": "SCIP status userinterrupt",
                    "gurobi": "Gurobi status 11", "cplex": "aborted"}


def options(backend: str, **kw) -> SolveOptions:
    return SolveOptions(backend=backend, **{"time_limit_s": 60.0, **kw})


def test_the_scenario_knows_every_backend() -> None:
    assert SOLVER_BACKENDS == tuple(BACKENDS)


# --- small programs ----------------------------------------------------------------------------


@pytest.mark.parametrize("backend", EVERY)
def test_a_known_milp(backend) -> None:
    prog, _ = knapsack()  # with an objective constant
    r = solve(prog, options(backend))
    assert r.status is Status.OPTIMAL and r.backend == backend
    assert r.objective == pytest.approx(-6.5)
    np.testing.assert_allclose(r.x, [1, 0, 1, 0], atol=1e-6)
    assert r.bound <= r.objective and r.gap <= 1e-4


@pytest.mark.parametrize("backend", EVERY)
def test_an_infeasible_milp(backend) -> None:
    prog, v = knapsack()
    prog.AddLinearConstraint(v[0] + v[1] >= 1.5)
    r = solve(prog, options(backend))
    assert r.status is Status.INFEASIBLE and r.x is None
    assert r.objective == np.inf and r.bound == np.inf and r.gap == np.inf


@pytest.mark.parametrize("backend", EVERY)
def test_a_cutoff_asks_only_for_cheaper_solutions(backend) -> None:
    """Above the optimum a cutoff changes nothing; below it, the backend proves that nothing is
    cheaper ("infeasible"): the skeleton search closes a program against its incumbent so."""
    prog, _ = knapsack()  # optimum −6.5, with an objective constant
    above = solve(prog, options(backend, cutoff=-6.0))
    assert above.status is Status.OPTIMAL and above.objective == pytest.approx(-6.5)
    below = solve(prog, options(backend, cutoff=-7.0))
    assert below.status is Status.INFEASIBLE and below.x is None, below


@pytest.mark.parametrize("backend", EVERY)
def test_a_pure_lp_is_bounded_by_its_optimum(backend) -> None:
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(2, "x")
    prog.AddLinearCost(np.array([1.0, 2.0]), 0.0, x)
    prog.AddBoundingBoxConstraint(0.0, 1.0, x)
    prog.AddLinearConstraint(x[0] + x[1] >= 1.5)
    prog.AddLinearConstraint(x[0] - x[1] >= -0.5)
    prog.AddLinearConstraint(np.array([[-2.0, 1.0]]), [-1.0], [1.0], x)  # a two-sided row
    r = solve(prog, options(backend))
    assert r.status is Status.OPTIMAL
    np.testing.assert_allclose(r.x, [5 / 6, 2 / 3], atol=1e-6)
    assert r.objective == pytest.approx(13 / 6) and r.bound == pytest.approx(r.objective)


@pytest.mark.parametrize("backend", EVERY)
def test_an_unbounded_lp(backend) -> None:
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(2, "x")
    prog.AddLinearCost(np.array([-1.0, 0.0]), 0.0, x)
    prog.AddLinearConstraint(x[0] - x[1] <= 1.0)
    prog.AddBoundingBoxConstraint(0.0, np.inf, x)
    assert solve(prog, options(backend)).status is Status.UNBOUNDED


@pytest.mark.parametrize("backend", EVERY)
def test_mip_starts_complete_and_partial(backend) -> None:
    """On the hard market split, only the planted start gives the optimum at once: the first
    solution (gap 1) is the start's, and with the binaries given the slacks follow."""
    prog, start = market_split(planted=True)
    full = solve(prog, options(backend, mip_rel_gap=1.0), start=start)
    assert full.status is Status.OPTIMAL and full.objective == pytest.approx(0.0, abs=1e-6)
    binaries = np.arange(40)  # the slacks are left to the solver
    part = solve(prog, options(backend, time_limit_s=10.0), start=(binaries, start[binaries]))
    assert part.status is Status.OPTIMAL and part.objective == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("backend", EVERY)
def test_a_time_limit_stops_a_hard_milp_honestly(backend) -> None:
    prog, _ = market_split(planted=True)
    r = solve(prog, options(backend, time_limit_s=0.3, threads=1))
    assert r.status in (Status.FEASIBLE, Status.TIME_LIMIT), r
    assert SAYS_TIME_LIMIT[backend] in r.message
    if r.status is Status.FEASIBLE:
        assert r.objective > 0 and r.bound <= r.objective
        assert r.gap == pytest.approx((r.objective - r.bound) / r.objective) and r.gap > 1e-4
    else:
        assert r.x is None and r.objective == np.inf and r.gap == np.inf


@pytest.mark.parametrize("backend", EVERY)
@pytest.mark.parametrize("when", ["before", "during"])
def test_a_stop_request_ends_the_solve(backend, when) -> None:
    """The closed loop and Ctrl-C stop running solves through an Interrupt: every backend must
    end a solve that would otherwise run for minutes, and one asked to stop before it began.
    The solver says that the stop ended it: a stop not heard runs into the time limit."""
    prog, _ = market_split(planted=True)
    stop = Interrupt()
    if when == "before":
        stop.set()
    else:
        threading.Timer(0.3, stop.set).start()
    r = solve(prog, options(backend, time_limit_s=20.0, interrupt=stop))
    assert r.status in (Status.FEASIBLE, Status.TIME_LIMIT), r
    assert SAYS_INTERRUPTED[backend] in r.message, r


# --- the steps of the planner -------------------------------------------------------------------


def step(m_o: int, n_o: int, rule: int):
    s = load_scenario("table1_vd", {"m_o": m_o, "n_o": n_o, "rule": rule, "seed": 2})
    state = State.initial(s)
    objects = select_objects(s, state, list(range(s.n_objects)))
    spec = specification(s, objects)
    return s, state, spec, predict_horizon(StepProblem(s, state, spec))


STEPS = [(1, 1, 2), (1, 2, 1), (2, 2, 2)]


@pytest.fixture(scope="module")
def highs_steps() -> dict:
    """HiGHS's monolithic optimum of each step at the first horizon with a plan, and the
    skeleton search's result at that horizon ((2, 2) rule 2: none without a hand-over)."""
    out = {}
    for key in STEPS:
        s, state, spec, T = step(*key)
        problem = StepProblem(s, state, spec)
        while (mono := solve_step(problem, T)).status is Status.INFEASIBLE:
            T += 1
        assert mono.status is Status.OPTIMAL
        out[key] = mono, search_step(problem, T)
    return out


@pytest.mark.parametrize("backend", OTHERS)
@pytest.mark.parametrize("key", STEPS, ids=lambda k: f"{k[0]},{k[1]} rule {k[2]}")
def test_the_same_step_optima_as_highs(backend, key, highs_steps) -> None:
    """The monolithic MILP of the same step and horizon, the horizon before (infeasible), and
    the skeleton search (whose programs are narrowed standard forms) on the backend."""
    s, state, spec, _ = step(*key)
    mono_ref, search_ref = highs_steps[key]
    T = mono_ref.horizon
    s = dataclasses.replace(s, solver=dataclasses.replace(s.solver, backend=backend))
    problem = StepProblem(s, state, spec)
    mono = solve_step(problem, T)
    assert mono.status is Status.OPTIMAL
    assert mono.cost == pytest.approx(mono_ref.cost, rel=2e-4)
    if T > predict_horizon(problem):
        assert solve_step(problem, T - 1).status is Status.INFEASIBLE
    found = search_step(problem, T)
    assert found.status is search_ref.status
    if found.status.has_solution:
        assert found.cost == pytest.approx(search_ref.cost, rel=2e-4)


# --- backends that cannot solve: one clear line -------------------------------------------------


def test_an_unknown_backend_is_named() -> None:
    prog, _ = knapsack()
    with pytest.raises(SolverUnavailable, match=r"^unknown solver 'glpk' \(one of highs, scip"):
        solve(prog, SolveOptions(backend="glpk"))


def test_a_backend_not_installed_says_how_to_install_it(monkeypatch) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "pyscipopt" else real(name, *a))
    assert "scip" not in installed_backends()
    prog, _ = knapsack()
    with pytest.raises(SolverUnavailable, match=r"'scip' is not installed.*dualarm_mpc\[scip\]"):
        solve(prog, SolveOptions(backend="scip"))


def _large(variables: int) -> MathematicalProgram:
    prog = MathematicalProgram()
    x = prog.NewBinaryVariables(variables, "x")
    prog.AddLinearCost(np.ones(variables), 0.0, x)
    prog.AddLinearConstraint(np.ones((1, variables)), [1.0], [np.inf], x)
    return prog


@pytest.mark.parametrize("backend", [_param("gurobi"), _param("cplex")])
def test_a_model_over_the_free_licence_is_one_clear_line(backend) -> None:
    limit = {"gurobi": backends.GUROBI_LIMIT, "cplex": backends.CPLEX_LIMIT}[backend]
    f = standard_form(_large(limit[0] + 1))
    with pytest.raises(SolverUnavailable) as err:
        solve_standard_form(f, SolveOptions(backend=backend))
    line = str(err.value)
    assert "\n" not in line and f"{limit[0] + 1} variables" in line
    assert f"{limit[0]} variables and {limit[1]} constraints of the free licence" in line
    assert solve_standard_form(standard_form(_large(limit[0])),
                               SolveOptions(backend=backend)).status is Status.OPTIMAL


@pytest.mark.parametrize("backend", [_param("cplex")])
def test_a_step_over_cplex_community_limits_is_refused_before_solving(backend) -> None:
    """A Table II step with (2, 5) has more than CPLEX Community's 1000 rows."""
    s, state, spec, T = step(2, 5, 2)
    f = HorizonProgram(s, state, list(spec.objects), T).standard_form(spec)
    assert len(f.c) < backends.CPLEX_LIMIT[0] < f.A.shape[0]
    with pytest.raises(SolverUnavailable, match=rf"^solver 'cplex': this MILP has {len(f.c)} "
                       r"variables and \d+ constraints, over the 1000 variables and 1000 "
                       r"constraints of the free licence"):
        solve_standard_form(f, SolveOptions(backend=backend))


def test_no_backend_prints_anything() -> None:
    """Solver banners (HiGHS's, Gurobi's licence line, CPLEX's log) went to stdout, into the
    CLI's table."""
    code = ("from test_program import knapsack\n"
            "from dualarm_mpc.milp.backends import solve\n"
            "from dualarm_mpc.milp.solver import SolveOptions, installed_backends\n"
            "for b in installed_backends():\n"
            "    assert solve(knapsack()[0], SolveOptions(backend=b)).status.value == 'optimal'\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True, cwd=Path(__file__).parent)
    assert run.stdout == "" and run.stderr == "", (run.stdout, run.stderr)


@pytest.mark.parametrize("backend", [_param("cplex")])
def test_the_check_s_program_over_a_size_limit_is_named_with_what_sizes_it(backend) -> None:
    """The limit's line quoted "this MILP" without saying it was the consistency check's."""
    from dualarm_mpc.model.scenario import load_scenario
    from dualarm_mpc.planning.consistency import check

    scenario = load_scenario("table1_vc", {"solver": {"backend": backend}})
    with pytest.raises(SolverUnavailable, match=r"^the consistency check's one-object programs "
                       r"\(horizons up to solver.max_horizon = 40\): solver 'cplex': this MILP "
                       r"has .* a smaller solver.max_horizon makes them smaller$"):
        check(scenario, joint=False)
