"""Tests for milp.cpsat, the CP-SAT relaxation of a horizon's MILP and the second prover.

Sound: every point of a program maps to a point of its relaxation — on random small programs
(hypothesis: real coefficients, big-M rows, truth columns in the encoder's shapes, equalities met
exactly), and on random small steps, where every plan HiGHS finds is a point of the relaxation and
every horizon the relaxation proves infeasible HiGHS proves infeasible too. Not vacuous: programs
infeasible by a margin well above the units are proven so. The prover beside the search: what it
proves, the search it stops, a stop request; in a step, the horizons the search leaves open.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import time

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scenes import random_scene

pytest.importorskip("ortools", reason="OR-Tools is not installed (pip install '.[ortools]')")

from dualarm_mpc.milp import cpsat  # noqa: E402
from dualarm_mpc.milp.backends import solve_standard_form  # noqa: E402
from dualarm_mpc.milp.horizon import HorizonProgram, solve_options  # noqa: E402
from dualarm_mpc.milp.solver import (  # noqa: E402
    Interrupt,
    SolveOptions,
    SolverUnavailable,
    StandardForm,
    Status,
)
from dualarm_mpc.model.mld import State  # noqa: E402
from dualarm_mpc.model.scenario import ScenarioError, load_scenario  # noqa: E402
from dualarm_mpc.model.spec import StepProblem, specification  # noqa: E402
from dualarm_mpc.planning.sequential import predict_horizon, second_prover  # noqa: E402

QUICK = SolveOptions(time_limit_s=10.0)


def form(rows: list[tuple[dict[int, float], float, float]], lo, hi, integer=None) -> StandardForm:
    """A standard form from rows ({column: coefficient}, lb, ub) and column bounds."""
    n = len(lo)
    A = sp.csr_matrix(([c for r, _, _ in rows for c in r.values()],
                       ([k for k, (r, _, _) in enumerate(rows) for _ in r],
                        [j for r, _, _ in rows for j in r])), shape=(len(rows), n))
    return StandardForm(np.zeros(n), 0.0, A, np.array([r[1] for r in rows], float),
                        np.array([r[2] for r in rows], float), np.asarray(lo, float),
                        np.asarray(hi, float),
                        np.zeros(n, bool) if integer is None else np.asarray(integer, bool))


def proof(f: StandardForm, at=None) -> Status:
    return cpsat.Relaxation(f).solve(QUICK, at).status


# --- by hand --------------------------------------------------------------------------------------


def test_a_point_between_units_is_kept() -> None:
    # x = 1/3 is no count of units; the row's widening keeps it (and 3x = 1 + 1e-3 is out)
    assert proof(form([({0: 3.0}, 1.0, 1.0)], [0], [1])) is Status.FEASIBLE
    assert proof(form([({0: 3.0}, 1.0, 1.0)], [0], [1]), at=np.array([1 / 3])) is Status.FEASIBLE
    assert proof(form([({0: 3.0}, 1.0, 1.0), ({0: 1.0}, 0.3337, 1)], [0], [1])) \
        is Status.INFEASIBLE


def test_big_m_rows_with_real_coefficients() -> None:
    # v ≤ 0.37·(1 − η) + 0.013 and v ≥ 0.2: only η = 0 (tight to within 1e-3: still proven)
    lo, hi = [-0.4, 0], [0.4, 1]
    rows = [({0: 1.0, 1: 0.37}, -np.inf, 0.383), ({0: 1.0}, 0.2, np.inf)]
    assert proof(form(rows + [({1: 1.0}, 1, 1)], lo, hi, [False, True])) is Status.INFEASIBLE
    assert proof(form(rows, lo, hi, [False, True]), at=np.array([0.383, 0.0])) is Status.FEASIBLE
    assert proof(form(rows + [({0: 1.0}, 0.384, np.inf)], lo, hi, [False, True])) \
        is Status.INFEASIBLE


def test_truth_columns_are_booleans_where_the_ceiling_is_safe() -> None:
    # the encoder's ∧ (z ≤ η_1, z ≤ η_2), ∨ (w ≤ z + η_3) and a requirement w ≥ 1
    lo, hi = [0, 0, 0, 0, 0], [1, 1, 1, 1, 1]
    integer = [True, True, True, False, False]
    rows = [({3: 1.0, 0: -1.0}, -np.inf, 0), ({3: 1.0, 1: -1.0}, -np.inf, 0),
            ({4: 1.0, 3: -1.0, 2: -1.0}, -np.inf, 0), ({4: 1.0}, 1, np.inf)]
    relaxation = cpsat.Relaxation(form(rows, lo, hi, integer))
    assert relaxation.truth.tolist() == [False, False, False, True, True]
    # a coefficient 2 on the side the ceiling breaks: z = 0.5 could not become 1
    doubled = [({4: 2.0, 3: -1.0}, -np.inf, 0)] + rows[:2]
    assert cpsat.Relaxation(form(doubled, lo, hi, integer)).truth.tolist() == [False] * 5
    # and a continuous column in a row makes its truth columns continuous, to a fixed point
    mixed = rows + [({3: 1.0, 5: 0.5}, -np.inf, 1)]
    relaxation = cpsat.Relaxation(form(mixed, lo + [0], hi + [1], integer + [False]))
    assert relaxation.truth.tolist() == [False] * 6
    # η_1 = η_2 = 0 leaves the requirement to η_3; η_3 = 0 too, and there is no point
    off = [({0: 1.0}, 0, 0), ({1: 1.0}, 0, 0), ({2: 1.0}, 0, 0)]
    assert proof(form(rows + off, lo, hi, integer)) is Status.INFEASIBLE
    assert proof(form(rows + off[:2], lo, hi, integer)) is Status.FEASIBLE


def test_bounds_no_point_meets_are_infeasible_without_a_solve() -> None:
    relaxation = cpsat.Relaxation(form([({0: 1.0}, 1.0, 0.0)], [0], [1]))
    assert relaxation.empty and relaxation.solve(QUICK).status is Status.INFEASIBLE
    assert cpsat.Relaxation(form([({0: 1.0}, 2.0, 3.0)], [0], [1])).empty


def test_bounds_crossed_by_their_rounding_fix_a_column() -> None:
    # a hand at the edge of its range: reach boxes give 0.9 + 8e-16 ≤ p ≤ 0.9 (HiGHS takes it)
    f = form([({0: 1.0, 1: -1.0}, 0.0, 0.0)], [0.9 + 8e-16, 0], [0.9, 1])
    assert not cpsat.Relaxation(f).empty
    assert proof(f) is Status.FEASIBLE


def test_an_unbounded_column_is_refused() -> None:
    with pytest.raises(ValueError, match="column 0"):
        cpsat.Relaxation(form([({0: 1.0}, 0.0, np.inf)], [0], [np.inf]))


# --- random programs ------------------------------------------------------------------------------


@st.composite
def programs_with_a_point(draw):
    """A random program and a point of it: continuous columns on random ranges, binaries, truth
    columns in the encoder's shapes (z ≤ child, z ≤ Σ children, Σ z ≥ 1, with fractional z);
    rows with real coefficients of several magnitudes, some equalities met exactly by the point,
    some big-M rows on binaries."""
    n_cont = draw(st.integers(1, 5))
    n_bin = draw(st.integers(0, 3))
    reals = st.floats(-2, 2, allow_nan=False)
    lo = np.array([draw(reals) for _ in range(n_cont)])
    hi = lo + np.array([draw(st.sampled_from([1e-3, 0.2, 1.0, 3.7])) for _ in range(n_cont)])
    x = lo + (hi - lo) * np.array([draw(st.floats(0, 1)) for _ in range(n_cont)])
    eta = np.array([draw(st.integers(0, 1)) for _ in range(n_bin)], float)
    n = n_cont + n_bin
    rows = []
    coefficient = st.one_of(st.sampled_from([1.0, -1.0, 0.1, -0.37, 1e-3]), reals)
    for _ in range(draw(st.integers(1, 6))):
        cols = draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=4, unique=True))
        a = {j: draw(coefficient) for j in cols}
        value = sum(c * np.concatenate([x, eta])[j] for j, c in a.items())
        kind = draw(st.sampled_from(["eq", "le", "ge", "range"]))
        slack = draw(st.sampled_from([0.0, 1e-7, 1e-3]))
        lb = value - slack if kind in ("eq", "ge", "range") else -np.inf
        ub = value + slack if kind in ("eq", "le", "range") else np.inf
        rows.append((a, value if kind == "eq" else lb, value if kind == "eq" else ub))
    # truth columns z over the binaries (and each other), each no more than its rows allow
    z = []
    if n_bin:
        for _ in range(draw(st.integers(0, 3))):
            children = draw(st.lists(st.integers(0, n_bin - 1 + len(z)), min_size=1,
                                     max_size=2, unique=True))
            values = [eta[c] if c < n_bin else z[c - n_bin] for c in children]
            index = [n_cont + c if c < n_bin else n + c - n_bin for c in children]
            if draw(st.booleans()):  # ∧: z ≤ each
                top = min(values)
                rows += [({n + len(z): 1.0, k: -1.0}, -np.inf, 0.0) for k in index]
            else:  # ∨: z ≤ Σ
                top = min(1.0, sum(values))
                rows.append(({n + len(z): 1.0, **{k: -1.0 for k in index}}, -np.inf, 0.0))
            z.append(top * draw(st.sampled_from([1.0, 0.5, 0.01])))
        if z and max(z) > 0:
            rows.append(({n + k: 1.0 for k, v in enumerate(z) if v > 0}, 1.0 if sum(z) >= 1
                         else 0.0, np.inf))
    lo_all = np.concatenate([lo, np.zeros(n_bin + len(z))])
    hi_all = np.concatenate([hi, np.ones(n_bin + len(z))])
    integer = np.r_[np.zeros(n_cont, bool), np.ones(n_bin, bool), np.zeros(len(z), bool)]
    point = np.concatenate([x, eta, z])
    return form(rows, lo_all, hi_all, integer), point


@settings(max_examples=150, deadline=None)
@given(programs_with_a_point())
def test_every_point_of_a_program_maps_to_a_point_of_its_relaxation(case) -> None:
    f, point = case
    assert proof(f) is not Status.INFEASIBLE
    assert proof(f, at=point) is Status.FEASIBLE


# --- random small steps ---------------------------------------------------------------------------


@pytest.mark.slow  # about 20 s: eight steps, their MILPs and relaxations at three horizons
@pytest.mark.parametrize("seed", range(8))
def test_the_relaxation_of_a_step_keeps_highs_plans_and_proves_only_what_highs_proves(
        seed: int) -> None:
    s = random_scene(seed)
    state = State.initial(s)
    spec = specification(s, [0, 1, 2])
    first = predict_horizon(StepProblem(s, state, spec))
    proven = 0
    for T in range(max(first - 1, 1), first + 2):
        f = HorizonProgram(s, state, [0, 1, 2], T)._specified(spec)
        highs = solve_standard_form(f, SolveOptions(time_limit_s=30.0))
        relaxation = cpsat.Relaxation(f)
        said = relaxation.solve(dataclasses.replace(QUICK, time_limit_s=5.0)).status
        if said is Status.INFEASIBLE:
            assert highs.status is Status.INFEASIBLE, (seed, T)
            proven += 1
        if highs.status.has_solution:
            assert said is not Status.INFEASIBLE
            assert relaxation.solve(QUICK, at=highs.x).status is Status.FEASIBLE, (seed, T)
    assert proven or first == 1, "no horizon of the step proven infeasible"


# --- the prover beside the search -----------------------------------------------------------------


def no_point_below(T_first: int):
    """Programs by horizon: below ``T_first`` a row no count of units meets (3x = 1 and
    x ≥ 0.3337), from it on the same point x = 1/3 (the relaxation has it)."""
    def form_of(T: int) -> StandardForm:
        tight = [({0: 1.0}, 0.3337, 1.0)] if T < T_first else []
        return form([({0: 3.0}, 1.0, 1.0)] + tight, [0], [1])

    return form_of


def eventually(condition) -> bool:
    """``condition()`` within a minute (the prover runs on its own thread)."""
    end = time.monotonic() + 60
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True


def test_the_prover_proves_what_it_is_asked_and_stops_that_horizons_search() -> None:
    prover = cpsat.Prover(no_point_below(5), QUICK, first_slice_s=0.5)
    try:
        prover.ask([3, 5, 4])
        with prover.searching(4, QUICK) as options:
            assert eventually(options.interrupt.is_set)  # proven while being searched
        assert eventually(lambda: 3 in prover.proofs())
    finally:
        proofs = prover.close()
    assert sorted(proofs) == [3, 4]  # 5 has a point: never proven, tried until closed
    assert proofs[3].status is Status.INFEASIBLE


def test_a_stop_request_stops_the_prover() -> None:
    stop = Interrupt()
    stop.set()
    prover = cpsat.Prover(no_point_below(5), dataclasses.replace(QUICK, interrupt=stop))
    prover.ask([3, 4])
    assert prover.close() == {}


def test_the_prover_needs_ortools(monkeypatch) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "ortools" else real(name, *a))
    with pytest.raises(ScenarioError, match=r"^solver.prover: 'cpsat' needs OR-Tools.*"
                                            r"dualarm_mpc\[ortools\]"):
        load_scenario("table1_vd", {"solver": {"prover": "cpsat"}})
    assert load_scenario("table1_vd").solver.prover == "none"  # the default where missing
    with pytest.raises(SolverUnavailable, match=r"dualarm_mpc\[ortools\]"):
        cpsat.Prover(no_point_below(5), QUICK)


def table2_step():
    """(3,5) rule 2, seed 0 (Table II, reach), the second step's start as the bench planned it
    (the objects of the first step held in their goals let go): its objects 1, 5, 7, 9, 10
    have no plan at T = 11, which the skeleton search proves in 1.6 s of CPU, the monolithic
    MILP in 3.7 s and CP-SAT in 0.75 s (1,242 conflicts: a real proof, not presolve's)."""
    s = load_scenario("table1_vd", {"m_o": 3, "n_o": 5, "rule": 2, "seed": 0,
                                    "delivery": "reach"})
    objects = [[0.0685, -0.1151], [-0.2295, -0.2417], [-0.225, 0.65], [0.267925, 0.708825],
               [-0.225, 0.85], [0.1579, -0.2486], [0.1787, -0.2332], [0.1148, -0.1622],
               [0.1816, 0.0207], [-0.1001, -0.0387]]
    state = State(hand_pos=np.array([[-0.175, 0.7], [-0.275, 0.8]]), hand_vel=np.zeros((2, 2)),
                  object_pos=np.array(objects), object_vel=np.zeros((10, 2)),
                  grasp=np.zeros((2, 10), int))
    return s, state, specification(s, [0, 4, 6, 8, 9])


@pytest.mark.slow  # CP-SAT 1 s and HiGHS 5 s of CPU on a (3,5) step
def test_the_second_prover_proves_a_table2_horizon_and_reports_it() -> None:
    s, state, spec = table2_step()
    tried = []
    with second_prover(StepProblem(s, state, spec), solve_options(s), 1.0, tried.append) as prover:
        prover.ask([10, 11])
        assert eventually(lambda: set(prover.proofs()) == {10, 11})
    assert [(t.horizon, t.status) for t in tried] == [(10, Status.INFEASIBLE),
                                                      (11, Status.INFEASIBLE)]
    assert all(t.message.startswith("CP-SAT") for t in tried)
    f = HorizonProgram(s, state, list(spec.objects), 11).standard_form(spec)
    assert solve_standard_form(f, SolveOptions(time_limit_s=120.0)).status is Status.INFEASIBLE


def test_no_second_prover_proves_nothing() -> None:
    s, state, spec = table2_step()
    s = dataclasses.replace(s, solver=dataclasses.replace(s.solver, prover="none"))
    with second_prover(StepProblem(s, state, spec), solve_options(s), 1.0) as prover:
        prover.ask([10, 11])
        with prover.searching(11, QUICK) as options:
            assert options is QUICK
    assert prover.proofs() == {}
