"""Tests for milp.program (the MILP of one horizon) and milp.solver (HiGHS adapter).

The solver's raw solution of a step must be the model's own trajectory: replaying its forces and
grasps through :func:`mld.replay` (which shares no code with the MILP) reproduces its positions.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scenes
from pydrake.solvers import MathematicalProgram
from scenes import OBJECT1, OBJECT2

from dualarm_mpc.milp.backends import solve
from dualarm_mpc.milp.horizon import HorizonProgram, build_program, solve_step
from dualarm_mpc.milp.solver import SolveOptions, Status, standard_form
from dualarm_mpc.model.mld import Model, State, replay, violations
from dualarm_mpc.model.scenario import Scenario, load_scenario
from dualarm_mpc.model.spec import StepProblem, specification
from dualarm_mpc.planning import sequential


def two_objects(**overrides) -> Scenario:
    """The shared scene with object 2 further out, at (−0.3, 0.3), under rule 2."""
    return scenes.two_objects(**{"objects": [OBJECT1, {**OBJECT2, "position": [-0.3, 0.3]}],
                                 "rule": 2, "solver": {}, **overrides})


def thrown() -> Scenario:
    """§V-C (goals out of the hands' reach): delivering means throwing."""
    return load_scenario("table1_vc", {"rule": 2, "solver": {"max_horizon": 10}})


def step(scenario: Scenario, objects: list[int]):
    # These tests read the monolithic program's own solution (search.py composes its plans).
    scenario = replace(scenario, solver=replace(scenario.solver, search="monolithic"))
    state = State.initial(scenario)
    spec = specification(scenario, objects)
    result, _ = sequential.plan_step(StepProblem(scenario, state, spec))
    return state, spec, result


# --- the solution satisfies the model -------------------------------------------------------------


@pytest.mark.parametrize(
    ("case", "objects"),
    [("two", [0, 1]), ("two_rule1", [0, 1]), ("throw", [0]), ("throw", [1, 9])],
)
def test_solution_replays_through_the_model(case: str, objects: list[int]) -> None:
    scenario = {
        "two": lambda: two_objects(),
        "two_rule1": lambda: two_objects(rule=1),
        "throw": thrown,
    }[case]()
    state, spec, res = step(scenario, objects)
    assert res.status is Status.OPTIMAL
    x, v = res.variables, res.solution
    model = Model.from_scenario(scenario, objects)
    local = state.select(objects)
    eta = v[x.eta]
    assert np.abs(eta - np.round(eta)).max() < 1e-6  # integral
    replayed = replay(model, local, v[x.force], np.round(eta).astype(int))
    for name in ("hand_pos", "hand_vel", "object_pos", "object_vel"):
        np.testing.assert_allclose(
            v[getattr(x, name)], getattr(replayed, name), atol=1e-6, err_msg=name
        )
    assert violations(model, replayed) == []
    # The one-sided atoms hold in the solver's own solution: θ = 1 → in the goal box.
    theta = np.round(v[x.theta]).astype(bool)
    for j in range(len(objects)):
        inside = model.goals[j].contains(v[x.object_pos][:, j], 1e-6)
        assert (inside | ~theta[:, j]).all()
    # Cost (17) is the L1 norm of the forces.
    assert res.cost == pytest.approx(np.abs(v[x.force]).sum(), abs=1e-6)
    # The step ends at rest (docs/model.md) with every object of the step delivered.
    np.testing.assert_allclose(replayed.hand_vel[-1], 0.0, atol=1e-9)
    np.testing.assert_allclose(replayed.object_vel[-1], 0.0, atol=1e-9)


def test_a_throw_releases_at_speed_and_lands_beyond_the_reach() -> None:
    scenario = thrown()
    _, _, res = step(scenario, [0])
    t = res.trajectory
    assert t.object_pos[-1, 0, 1] > 0.9 + 0.05  # beyond every point a hand can reach
    released = np.flatnonzero(t.grasp[:-1, :, 0].any(axis=1) & ~t.grasp[1:, :, 0].any(axis=1))
    assert len(released) >= 1
    k = released[-1] + 1  # first step without a hand
    assert np.abs(t.object_vel[k, 0]).max() > 0.1  # it slides with its release velocity
    np.testing.assert_allclose(t.object_pos[k + 1, 0], t.object_pos[k, 0] + t.object_vel[k, 0])


# --- big-M from the bounds ------------------------------------------------------------------------


def _matrix(scenario: Scenario, T: int = 6):
    state = State.initial(scenario)
    spec = specification(scenario, [0, 1])
    prog, x, model, local = build_program(StepProblem(scenario, state, spec), T)
    return prog, standard_form(prog), model, local


@pytest.mark.parametrize("max_speed", [0.2, 0.35])
def test_big_m_is_finite_and_derived_from_the_bounds(max_speed: float) -> None:
    prog, f, model, local = _matrix(two_objects(max_speed=max_speed))
    assert np.isfinite(f.A.data).all()
    assert np.isfinite(f.col_lb).all() and np.isfinite(f.col_ub).all()  # every variable bounded
    region = model.object_region(local.object_pos)
    largest = float(np.max(region.hi - region.lo))
    assert np.abs(f.A.data).max() <= largest + 1e-9  # no fixed M = 1000
    # eq. (8) linearized with M_v = v_max + (object speed bound) = 2 v_max here
    assert np.isclose(np.abs(f.A.data), 2 * max_speed).any()


def test_big_m_changes_with_the_bounds() -> None:
    def coefficients(**overrides) -> set[float]:
        return set(np.round(np.abs(_matrix(two_objects(**overrides))[1].A.data), 9))

    base = coefficients()
    assert coefficients(max_speed=0.3) != base
    assert coefficients(workspace=[-0.8, 0.8, 0.0, 0.8]) != base  # within the arms' reach


def test_constraints_are_added_in_blocks() -> None:
    """One constraint per family, whatever the horizon and the number of objects."""
    counts = set()
    for T in (3, 12):
        for n in (1, 3):
            scenario = thrown()
            state = State.initial(scenario)
            spec = specification(scenario, list(range(n)))
            prog, *_ = build_program(StepProblem(scenario, state, spec), T)
            counts.add(len(prog.GetAllConstraints()))
    assert len(counts) == 1 and counts.pop() <= 30


def test_a_six_object_program_reads_into_standard_form() -> None:
    scenario = load_scenario("table1_vc")
    state = State.initial(scenario)
    spec = specification(scenario, [0, 3, 5, 6, 8, 9])
    prog, *_ = build_program(StepProblem(scenario, state, spec), 10)
    f = standard_form(prog)
    assert f.A.shape == (len(f.row_lb), prog.num_vars()) and f.A.shape[0] > 1000


@pytest.mark.parametrize("rule", [1, 2])
def test_a_specification_read_into_a_standard_form_directly_is_the_programs(rule: int) -> None:
    """The search encodes a specification straight into a standard form (no MathematicalProgram
    to read back): rows, bounds and integrality are those of the whole program."""
    scenario = load_scenario("table1_vd", {"rule": rule, "seed": 0, "n_o": 4})
    state = State.initial(scenario)
    spec = specification(scenario, [0, 1, 2, 3])
    h = HorizonProgram(scenario, state, list(spec.objects), 8)
    direct, read = h.standard_form(spec), standard_form(h.program(spec))
    assert direct.A.shape == read.A.shape and direct.A.shape[0] > h.form.A.shape[0]
    assert abs(direct.A - read.A).max() == 0
    for field in ("c", "row_lb", "row_ub", "col_lb", "col_ub", "integer"):
        np.testing.assert_array_equal(getattr(direct, field), getattr(read, field), field)


# --- pruning --------------------------------------------------------------------------------------


@pytest.mark.parametrize(("case", "objects"), [("two", [0, 1]), ("throw", [0, 9])])
def test_pruning_does_not_change_feasibility_or_optimal_cost(case: str, objects) -> None:
    scenario = two_objects() if case == "two" else thrown()
    state = State.initial(scenario)
    spec = specification(scenario, objects)
    problem = StepProblem(scenario, state, spec)
    fixed = {}
    for T in range(1, 11):
        results = {}
        for pruning in (True, False):
            results[pruning] = solve_step(problem, T, pruning=pruning)
            prog, *_ = build_program(problem, T, pruning=pruning)
            f = standard_form(prog)
            fixed[pruning] = int(((f.col_ub == 0) & f.integer).sum())
        on, off = results[True], results[False]
        assert on.status is off.status, T
        assert fixed[True] > fixed[False]  # pruning really fixes binaries
        if on.status is Status.OPTIMAL:
            assert on.cost == pytest.approx(off.cost, abs=1e-6)
            break
    else:
        pytest.fail("no horizon up to 10 was feasible")
    assert T >= sequential.predict_horizon(problem)  # predictT is a lower bound


# --- the HiGHS adapter ---------------------------------------------------------------------------


def knapsack() -> tuple[MathematicalProgram, np.ndarray]:
    """min −5a −4b −3c + y + 1.5 s.t. 2a + 3b + c ≤ 4, y ≥ 0.5 − a, 0 ≤ y ≤ 10; a, b, c binary.
    Optimum a = c = 1, b = 0, y = 0: objective −6.5."""
    prog = MathematicalProgram()
    abc = prog.NewBinaryVariables(3, "abc")
    y = prog.NewContinuousVariables(1, "y")
    prog.AddLinearCost(np.array([-5.0, -4.0, -3.0, 1.0]), 1.5, np.concatenate([abc, y]))
    prog.AddLinearConstraint(2 * abc[0] + 3 * abc[1] + abc[2] <= 4)
    prog.AddLinearConstraint(y[0] + abc[0] >= 0.5)
    prog.AddBoundingBoxConstraint(0.0, 10.0, y)
    return prog, np.concatenate([abc, y])


def test_known_milp() -> None:
    prog, _ = knapsack()
    r = solve(prog)
    assert r.status is Status.OPTIMAL and r.status.has_solution
    assert r.objective == pytest.approx(-6.5)
    np.testing.assert_allclose(r.x, [1, 0, 1, 0], atol=1e-9)
    assert r.gap == 0.0
    assert r.bound <= r.objective + 1e-9
    assert r.wall_time_s > 0.0


def test_infeasible_milp() -> None:
    prog, v = knapsack()
    prog.AddLinearConstraint(v[0] + v[1] >= 1.5)  # a = b = 1: weight 5 > 4
    r = solve(prog)
    assert r.status is Status.INFEASIBLE and not r.status.has_solution
    assert r.x is None and r.objective == np.inf


def market_split(m: int = 5, n: int = 40, seed: int = 1, planted: bool = False):
    """Cornuéjols–Dawande market split: Σ_j a_ij x_j = b_i, x binary — tiny and very hard for
    branch and bound. ``planted``: b from a known solution, equalities relaxed by slacks whose
    sum is minimized (optimum 0, the LP bound is 0 too, so only a solution proves it)."""
    rng = np.random.default_rng(seed)
    A = rng.integers(0, 100, size=(m, n)).astype(float)
    prog = MathematicalProgram()
    x = prog.NewBinaryVariables(n, "x")
    if not planted:
        prog.AddLinearEqualityConstraint(A, np.floor(A.sum(axis=1) / 2), x)
        return prog, None
    solution = rng.integers(0, 2, n).astype(float)
    slack = prog.NewContinuousVariables(2 * m, "slack")
    prog.AddBoundingBoxConstraint(0.0, np.inf, slack)
    prog.AddLinearEqualityConstraint(
        np.hstack([A, np.eye(m), -np.eye(m)]), A @ solution, np.concatenate([x, slack])
    )
    prog.AddLinearCost(np.ones(2 * m), 0.0, slack)
    return prog, np.concatenate([solution, np.zeros(2 * m)])


def test_time_limit_on_a_hard_milp() -> None:
    prog, _ = market_split()
    r = solve(prog, SolveOptions(time_limit_s=0.3))
    assert r.status in (Status.FEASIBLE, Status.TIME_LIMIT), r
    assert r.wall_time_s >= 0.3  # it ran to the limit (how far past it is the machine's load)
    if r.status is Status.TIME_LIMIT:
        assert r.x is None and r.objective == np.inf and not r.status.has_solution


def test_time_limit_with_a_solution_reports_feasible_and_the_gap() -> None:
    prog, _ = market_split(planted=True)
    r = solve(prog, SolveOptions(time_limit_s=0.3))
    assert r.status is Status.FEASIBLE, r  # HiGHS finds some slack > 0, cannot prove 0
    assert r.objective > 0 and 0 < r.gap <= 1.0 and r.x is not None
    assert r.bound <= r.objective


def test_mip_start_is_used() -> None:
    prog, start = market_split(planted=True)
    r = solve(prog, SolveOptions(time_limit_s=0.3), start=start)
    assert r.status is Status.OPTIMAL and r.objective == pytest.approx(0.0, abs=1e-9)


def test_mip_start_outside_the_bounds_is_clipped_and_harmless() -> None:
    prog, v = knapsack()
    r = solve(prog, start=np.array([3.0, -1.0, 0.5, 50.0]))
    assert r.status is Status.OPTIMAL and r.objective == pytest.approx(-6.5)


def test_lp_bound_is_a_lower_bound() -> None:
    """``SolveResult.bound`` is "the proven lower bound"; for a program without binaries HiGHS has
    no MIP dual bound and the adapter reports 0.0 — above the optimum −1 here."""
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(1, "x")
    prog.AddLinearCost(np.array([-1.0]), 0.0, x)
    prog.AddBoundingBoxConstraint(-5.0, 1.0, x)
    r = solve(prog)
    assert r.status is Status.OPTIMAL and r.objective == pytest.approx(-1.0)
    assert r.bound <= r.objective + 1e-9, r


def test_unbounded_program_is_not_reported_as_a_solution() -> None:
    """An unbounded LP has no optimal solution; the adapter must not report FEASIBLE with
    objective 0 (HiGHS's model status is 'Unbounded')."""
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(1, "x")
    prog.AddLinearCost(np.array([-1.0]), 0.0, x)
    r = solve(prog)
    assert not r.status.has_solution, r
