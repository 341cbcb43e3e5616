"""Tests for search.skeleton (the skeleton search) and the monotonicity check in spec.py.

The search must return the monolithic MILP's optimum of the same horizon: checked on random
small steps (seeded: states, both rules, a user rule, both delivery modes) against
:func:`horizon.solve_step`, with the plan replayed through the model and its specification
evaluated directly (``evaluate.py`` shares no code with either program).
"""

from __future__ import annotations

import dataclasses
import itertools
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scenes import random_scene, scene
from strategies import formulas, traces

from dualarm_mpc.logic.evaluate import evaluate
from dualarm_mpc.logic.ltl import Atom
from dualarm_mpc.logic.parser import parse
from dualarm_mpc.milp.backends import solve_standard_form
from dualarm_mpc.milp.horizon import HorizonProgram, StepResult, solve_options, solve_step
from dualarm_mpc.milp.solver import SolveOptions, Status
from dualarm_mpc.model.mld import (
    POSITION_TOL,
    Model,
    State,
    crowding,
    replay,
    standing,
    violations,
)
from dualarm_mpc.model.scenario import Scenario, load_scenario
from dualarm_mpc.model.spec import (
    RULE_TEXT,
    StepProblem,
    expand,
    rule_formulas,
    specification,
    survives_idling,
    untouchable,
    with_no_throw,
)
from dualarm_mpc.planning.sequential import predict_horizon
from dualarm_mpc.search import skeleton
from dualarm_mpc.search.relaxations import AloneKey, HandKey, Request, solve_relaxation
from dualarm_mpc.search.skeleton import (
    FeasibilityPass,
    StepSearch,
    _without_handover,
    search_step,
)
from dualarm_mpc.search.subprograms import BOTH, WAVE, Node, StepPrograms, lower_bound

# --- untouched objects (spec.untouchable) ---------------------------------------------------------


@pytest.mark.parametrize("rule", [1, 2])
def test_the_paper_rules_let_undelivered_objects_stay_untouched(rule: int) -> None:
    s = scene(rule)
    state = State.initial(s)
    spec = specification(s, [0, 1, 2])
    assert untouchable(spec, state, [0]) == {1, 2}


def test_an_object_held_outside_the_step_leaves_the_others_untouchable() -> None:
    # The state covers every object of the scenario, the step only some: a hand still holding
    # object 0 (delivered by an earlier step) says nothing about the step's objects 1 and 2.
    s = scene(1)
    state = State.initial(s)
    spec = specification(s, [1, 2])
    outside = dataclasses.replace(state, grasp=np.array([[1, 0, 0], [0, 0, 0]]))
    assert untouchable(spec, outside, [2]) == {1}
    inside = dataclasses.replace(state, grasp=np.array([[0, 1, 0], [0, 0, 0]]))
    assert untouchable(spec, inside, [2]) == frozenset()


def test_a_rule_that_needs_an_object_touched_keeps_it_free() -> None:
    s = scene(2, rules=("F eta[1,3]",))
    state = State.initial(s)
    spec = specification(s, [0, 1, 2])
    assert untouchable(spec, state, [0]) == frozenset()


# --- monotone in the horizon ---------------------------------------------------------------------


@pytest.mark.parametrize("name", list(RULE_TEXT))
def test_the_paper_rules_survive_idling(name: str) -> None:
    assert survives_idling(expand(parse(RULE_TEXT[name]), [1, 2, 3]))


@pytest.mark.parametrize(
    "text", ["G(eta[1,2] -> WX !eta[1,2])", "G WX theta[1]", "G(eta[1,1] -> WX G theta[1])"]
)
def test_rules_broken_by_one_more_idle_step_are_found(text: str) -> None:
    assert not survives_idling(parse(text))


# Atoms of different hands and objects: every state of them is one eqs. (14)-(15) allow.
ATOMS = [Atom("eta", (1, 1)), Atom("eta", (2, 2)), Atom("theta", (1,))]


@settings(max_examples=300, deadline=None)
@given(formulas(ATOMS, max_leaves=6), st.integers(0, 3).flatmap(lambda T: traces(ATOMS, T)))
def test_survives_idling_is_sound(formula, trace) -> None:
    """Whenever the check says yes, repeating the last state never falsifies the formula."""
    if not survives_idling(formula):
        return
    T = len(trace[ATOMS[0]]) - 1
    if not evaluate(formula, trace, T):
        return
    longer = {a: v + v[-1:] for a, v in trace.items()}
    assert evaluate(formula, longer, T + 1), (formula, trace)


# --- the search returns the monolithic optimum --------------------------------------------------


def replayed_trace_satisfies(s: Scenario, spec, res, state: State | None = None) -> bool:
    """The independent check: replay through the model, evaluate the specification directly."""
    objects = list(spec.objects)
    model = Model.from_scenario(s, objects)
    traj = res.trajectory
    local = (state or State.initial(s)).select(objects)
    replayed = replay(model, local, traj.force, traj.grasp)
    if violations(model, replayed):
        return False
    def value(atom: Atom, k: int) -> bool:
        if atom.name == "eta":
            i, j = atom.index
            return bool(replayed.grasp[k, i - 1, objects.index(j - 1)])
        (j,) = atom.index
        n = objects.index(j - 1)
        return bool(model.goals[n].contains(replayed.object_pos[k, n], POSITION_TOL))

    return evaluate(spec.formula(), value, res.horizon)


def first_feasible(s: Scenario, spec):
    """The monolithic reference: the shortest feasible horizon and its optimum."""
    state = State.initial(s)
    for T in range(3, 16):
        res = solve_step(StepProblem(s, state, spec), T)
        if res.status is not Status.INFEASIBLE:
            return res
    raise AssertionError("no horizon up to 15")


def held_by_both(res) -> bool:
    g = res.trajectory.grasp[1:]
    return bool((g[:, 0].any(axis=0) & g[:, 1].any(axis=0)).any())


@pytest.mark.slow  # 16 steps solved twice
@pytest.mark.parametrize("seed", range(16))
def test_search_returns_the_monolithic_optimum_of_the_same_horizon(seed: int) -> None:
    s = random_scene(seed)
    spec = specification(s, [0, 1, 2])
    mono = first_feasible(s, spec)
    assert mono.status is Status.OPTIMAL
    state = State.initial(s)
    exact = dataclasses.replace(s, solver=dataclasses.replace(s.solver, handover="always"))
    problem = StepProblem(exact, state, spec)
    found = search_step(problem, mono.horizon)
    assert found.status is Status.OPTIMAL
    assert found.cost == pytest.approx(mono.cost, rel=1e-6, abs=1e-9)
    assert replayed_trace_satisfies(s, spec, found)
    # The shorter horizon has no plan for the search either.
    assert search_step(problem, mono.horizon - 1).status is Status.INFEASIBLE
    # The default search (hand-overs only where needed) matches whenever the monolithic
    # optimum holds no object with both hands, and is never below it.
    auto = search_step(StepProblem(s, state, spec), mono.horizon)
    assert auto.cost >= mono.cost * (1 - 1e-6) - 1e-9
    if not held_by_both(mono):
        assert auto.cost == pytest.approx(mono.cost, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("seed", [5, 7, 14])
def test_objects_kept_apart_row_by_row_as_plans_need_them_give_the_whole_programs_optimum(
        seed: int) -> None:
    """With ``object_clearance`` (C1)–(C2): the rows a solve adds pair by pair, as its solutions
    break them (``HorizonProgram.solve``), give the optimum of the program with all of them, the
    skeleton search (its relaxations keep apart only what they move) the same, and the plan
    keeps every pair apart on its replayed trace (``mld.crowding``). Seeds where the objects'
    extent changes the optimum (seed 7: a horizon longer, 14: both), and pairs in the way."""
    s = random_scene(seed)
    s = dataclasses.replace(s, task=dataclasses.replace(s.task, object_clearance=0.01))
    spec = specification(s, [0, 1, 2])
    state = State.initial(s)
    mono = first_feasible(s, spec)
    assert mono.status is Status.OPTIMAL and mono.apart  # some rows were needed
    whole = HorizonProgram(s, state, [0, 1, 2], mono.horizon)
    assert mono.apart <= whole.apart.pairs()
    every_row = solve_standard_form(whole.standard_form(spec), solve_options(s))
    assert every_row.objective == pytest.approx(mono.cost, rel=1e-4)
    exact = dataclasses.replace(s, solver=dataclasses.replace(s.solver, handover="always"))
    found = search_step(StepProblem(exact, state, spec), mono.horizon)
    assert found.status is Status.OPTIMAL
    assert found.cost == pytest.approx(mono.cost, rel=1e-4)
    model = Model.from_scenario(s, [0, 1, 2])
    for res in (mono, found):
        assert crowding(model, res.trajectory, *standing(state, [0, 1, 2], model.dt)) == []
        assert replayed_trace_satisfies(s, spec, res)


@pytest.mark.parametrize("seed", [2, 6, 54])
def test_search_returns_the_monolithic_optimum_delivering_three(seed: int) -> None:
    """m_o = 3: a hand's larger share is a pair, solved exactly and fetched ahead of the
    feasibility pass's probes (seeds 2 and 6 hand an object over, 54 does not)."""
    s = random_scene(seed)
    s = dataclasses.replace(s, task=dataclasses.replace(s.task, m_o=3),
                            solver=dataclasses.replace(s.solver, handover="always"))
    spec = specification(s, [0, 1, 2])
    mono = first_feasible(s, spec)
    assert mono.status is Status.OPTIMAL
    state = State.initial(s)
    problem = StepProblem(s, state, spec)
    found = search_step(problem, mono.horizon)
    assert found.status is Status.OPTIMAL
    assert found.cost == pytest.approx(mono.cost, rel=1e-6, abs=1e-9)
    assert replayed_trace_satisfies(s, spec, found)
    assert search_step(problem, mono.horizon - 1).status is Status.INFEASIBLE


def test_the_nodes_cover_every_labelling_with_one_widest_hand_over_node_per_delivered_set() -> None:
    s = random_scene(2)
    s = dataclasses.replace(s, task=dataclasses.replace(s.task, m_o=2))
    spec = specification(s, [0, 1, 2])
    programs = StepPrograms(StepProblem(s, State.initial(s), spec), 10,
                            SolveOptions(time_limit_s=5))
    nodes = StepSearch.of(programs, handover="always").skeleton.nodes(relays=False)
    for targets in itertools.combinations(spec.objects, 2):
        mine = [n.hands for n in nodes if n.targets == targets]
        assert mine.count((BOTH, BOTH)) == 1 and len(mine) == 2 ** 2 + 1
        for hands in itertools.product((0, 1, BOTH), repeat=2):  # every plan's skeleton
            assert any(all(h in (g, BOTH) for g, h in zip(hands, node, strict=True))
                       for node in mine)


def relay_step():
    """The third step of Table II's (2,5) rule 2, seed 2, its start rounded to 0.1 mm: both
    hands at the goals, the objects low. At T = 11 each hand carries an object part of the
    way, puts it down and picks up the one the other hand left (no-juggle (19) forbids only
    the direct pass); without a relay the first plan is at T = 12."""
    s = load_scenario("table1_vd", {"m_o": 2, "n_o": 5, "rule": 2, "seed": 2})
    objects = [[-0.1192, -0.1008], [0.1571, -0.204], [-0.225, 0.65], [-0.156, -0.2224],
               [-0.175, 0.85], [0.0311, -0.175], [0.225, 0.65], [0.175, 0.85],
               [0.2337, 0.0915], [-0.0542, -0.1564]]
    state = State(np.array([[0.2103, 0.8], [0.1103, 0.6]]), np.zeros((2, 2)),
                  np.array(objects), np.zeros((10, 2)), np.zeros((2, 10), int))
    return s, state, specification(s, [0, 3, 5, 8, 9], rules=rule_formulas(s))


def test_the_default_search_finds_the_horizon_only_a_relay_makes_feasible() -> None:
    s, state, spec = relay_step()
    assert s.solver.handover == "auto"
    problem = StepProblem(s, state, spec)
    mono = solve_step(problem, 11)
    assert mono.status is Status.OPTIMAL
    found = search_step(problem, 11)
    assert found.status is Status.OPTIMAL
    assert found.cost == pytest.approx(mono.cost, rel=1e-6, abs=1e-9)
    assert held_by_both(found)
    assert replayed_trace_satisfies(s, spec, found, state)
    assert search_step(problem, 10).status is Status.INFEASIBLE


def one_hand_shares_run_out(programs: StepPrograms, request: Request):
    """The real relaxation solver, but every one-hand share it solves "runs out of time": no
    node with one hand per object is decided."""
    res = solve_relaxation(programs, request)
    if isinstance(request.key, HandKey) and request.key.share:
        return dataclasses.replace(res, status=Status.TIME_LIMIT, trajectory=None)
    return res


def test_relays_are_probed_when_the_nodes_without_them_are_left_undecided() -> None:
    s, state, spec = relay_step()
    programs = StepPrograms(StepProblem(s, state, spec), 11, SolveOptions(time_limit_s=60))
    found = StepSearch.of(programs, solver=one_hand_shares_run_out).feasible()
    assert found.status is Status.FEASIBLE and found.relays
    assert held_by_both(found.witness)


@pytest.mark.parametrize("seed", [1, 5])  # scenes whose horizons below carry plans up
def test_plans_carried_up_a_horizon_change_nothing(seed: int) -> None:
    """A step's horizons hand their relaxations with a plan to the next one, where each, idled
    one more step, stands for a probe: the optimum found is that of a search from scratch."""
    s = random_scene(seed)
    spec = specification(s, [0, 1, 2])
    problem = StepProblem(s, State.initial(s), spec)
    below: dict = {}
    carried_up = 0
    for T in range(3, 16):
        carried = search_step(problem, T, below=below)
        if carried.status.has_solution:
            break
        carried_up += len(below)
    assert carried_up > 0  # some horizon without a plan had relaxations with one
    fresh = search_step(problem, T)
    assert carried.status is fresh.status is Status.OPTIMAL
    assert carried.cost == pytest.approx(fresh.cost, rel=1e-6, abs=1e-9)
    assert replayed_trace_satisfies(s, spec, carried)
    assert below and all(r.horizon == T for r in below.values())
    # Some relaxation of the accepted horizon is a plan of the one below, idled: not solved.
    assert any(r.solution is None and r.solve_time_s == 0.0 for r in below.values())


def test_each_relaxation_is_solved_once_and_kept() -> None:
    """The store's solver, counted around the real one: no relaxation is solved twice the same
    way unless its first answer ran out of time, none is probed after its exact solve, and a
    second optimisation of the same horizon takes every bound from the store (no solve)."""
    s = random_scene(1)
    spec = specification(s, [0, 1, 2])
    mono = first_feasible(s, spec)
    answers: list[tuple[Request, Status]] = []

    def counted(programs: StepPrograms, request: Request):
        res = solve_relaxation(programs, request)
        answers.append((request, res.status))
        return res

    programs = StepPrograms(StepProblem(s, State.initial(s), spec), mono.horizon,
                            SolveOptions(time_limit_s=30, mip_rel_gap=1e-7))
    search = StepSearch.of(programs, solver=counted)
    found = search.feasible()
    assert found.status is Status.FEASIBLE
    res = search.run(found)
    assert res.cost == pytest.approx(mono.cost, rel=1e-6, abs=1e-9)
    assert 0 < len(answers) <= search.store.solved  # some decided without a solve
    for n, (request, status) in enumerate(answers):
        later = [r for r, _ in answers[n + 1:] if r.key == request.key]
        if status is not Status.TIME_LIMIT:
            assert all(r.exact != request.exact for r in later), request.key
        if request.exact:
            assert all(r.exact for r in later), request.key
    solves = len(answers)
    again = search.run(found)
    assert len(answers) == solves
    assert again.cost == pytest.approx(res.cost, rel=1e-9)


@pytest.mark.parametrize("rule", [1, 2])
def test_search_matches_the_monolithic_optimum_mid_carry(rule: int) -> None:
    """From states inside a plan, where a hand holds a moving object (the closed loop's replans):
    the relaxations must leave a held object to the hands, or they are no relaxations."""
    s = scene(rule, m_o=1)
    spec = specification(s, [0, 1, 2])
    start = first_feasible(s, spec)
    t = start.trajectory
    held = [k for k in range(1, len(t.grasp) - 1) if t.grasp[k].any()]
    assert held, "the plan carries an object"
    for k in held[:3]:
        problem = StepProblem(s, State.at(t, k), spec)
        for T in range(1, 16):
            mono = solve_step(problem, T)
            found = search_step(problem, T)
            assert found.status.has_solution == mono.status.has_solution, (k, T)
            if mono.status.has_solution:
                assert found.cost == pytest.approx(mono.cost, rel=1e-6, abs=1e-9), (k, T)
                break


def test_the_plan_does_not_depend_on_the_number_of_workers() -> None:
    """Among equal optima the search picks one by its own order, not by thread timing: sweeps run
    with one worker per process must reproduce the plans of a run with two."""
    s = random_scene(5)
    spec = specification(s, [0, 1, 2])
    T = first_feasible(s, spec).horizon
    plans = []
    for workers in (1, 2):
        w = dataclasses.replace(s, solver=dataclasses.replace(s.solver, workers=workers))
        plans.append(search_step(StepProblem(w, State.initial(s), spec), T).trajectory)
    for a, b in zip(plans[0].arrays(), plans[1].arrays(), strict=True):
        np.testing.assert_array_equal(a, b)


# --- the feasibility pass in rounds ---------------------------------------------------------------


class RunsOut:
    """The real relaxation solver, but the relaxations in ``slow`` (every one while it is None)
    "run out of time" while a program may take less than ``needs`` seconds (no clock: the slice
    the pass gives decides); records the slice of every solve."""

    def __init__(self, needs: float = np.inf) -> None:
        self.needs = needs
        self.slow: set | None = None
        self.asked: list[tuple[object, float]] = []

    def __call__(self, programs: StepPrograms, request: Request):
        res = solve_relaxation(programs, request)
        self.asked.append((request.key, request.slice_s))
        if self.slowed(request.key) and request.slice_s < self.needs:
            return dataclasses.replace(res, status=Status.TIME_LIMIT, trajectory=None)
        return res

    def slowed(self, key) -> bool:
        return self.slow is None or key in self.slow

    def search(self, s: Scenario, spec, T: int) -> StepSearch:
        return StepSearch.of(StepPrograms(StepProblem(s, State.initial(s), spec), T,
                                          SolveOptions(time_limit_s=32)), solver=self)

    @property
    def slices(self) -> list[float]:
        return [slice_s for key, slice_s in self.asked if self.slowed(key)]


def rounds_scene():
    s = random_scene(1)  # m_o = 2, rule 2; the horizon below its plan needs solves to decide
    return s, specification(s, [0, 1, 2])


def test_a_node_left_undecided_does_not_hide_a_plan_of_the_next_ones() -> None:
    s, spec = rounds_scene()
    T = first_feasible(s, spec).horizon
    solver = RunsOut()
    search = solver.search(s, spec, T)
    # The first node whose relaxations all need a solve (none ruled out by a route) is left
    # undecided by its first round.
    solved = [[k for k in search.store.keys(node) if isinstance(k, AloneKey) or k.share]
              for node in search.skeleton.single_hand()]
    solver.slow = set(next(keys for keys in solved if keys and not any(
        search.store.share_ruled_out(k.hand, k.share) for k in keys)))
    found = search.feasible()
    assert found.status is Status.FEASIBLE and found.witness is not None  # the plan decides
    assert solver.slices and set(solver.slices) == {2.0}  # a sixteenth of 32 s, one round
    passed = len(solver.asked)
    search.run(found)
    assert len(solver.asked) > passed  # the optimisation after the pass has no slices
    assert all(np.isinf(slice_s) for _, slice_s in solver.asked[passed:])


def test_the_rounds_give_what_ran_out_of_time_four_times_as_long_until_it_is_decided() -> None:
    s, spec = rounds_scene()
    T = first_feasible(s, spec).horizon - 1  # no plan: every node must be proven infeasible
    solver = RunsOut(needs=8.0)
    assert solver.search(s, spec, T).feasible().status is Status.INFEASIBLE
    assert sorted(set(solver.slices)) == [2.0, 8.0]


# --- a node whose joint program runs out ---------------------------------------------------------


class JointRunsOut(StepPrograms):
    """Every joint node program runs out of time before it finds or proves anything."""

    joints = 0

    def joint(self, node, floor, start=None, **kw):
        self.joints += 1
        return dataclasses.replace(super().joint(node, floor, start, **kw),
                                   status=Status.TIME_LIMIT, trajectory=None, cost=np.inf,
                                   bound=-np.inf)


def test_a_composed_plan_does_not_close_its_node_when_the_joint_program_ran_out() -> None:
    """Seed 0's hands' plans, put together, cost more than the node's bound: only the joint
    program can prove that they are its optimum. When it runs out of time, the composed plan
    is the node's best, not its optimum, and the step is not proven optimal."""
    s = random_scene(0)
    spec = specification(s, [0, 1, 2])
    mono = first_feasible(s, spec)
    programs = JointRunsOut(StepProblem(s, State.initial(s), spec), mono.horizon,
                            SolveOptions(time_limit_s=30))
    search = StepSearch.of(programs)
    found = search.feasible()
    assert found.status is Status.FEASIBLE
    res = search.run(found)
    assert programs.joints > 0
    assert res.status is Status.FEASIBLE and res.gap > 1e-4
    assert res.bound <= mono.cost * (1 + 1e-6) <= res.cost * (1 + 1e-6)
    assert replayed_trace_satisfies(s, spec, res)


@pytest.mark.parametrize("seed", [1, 2, 5])
def test_an_incumbent_cuts_the_search_short_and_leaves_its_optimum(seed: int) -> None:
    """The step's no-throw witness as the first incumbent (``below_witness`` at T₁): the same
    optimum, proven, as the search from nothing; and the optimum itself comes back proven."""
    s = random_scene(seed)
    spec = specification(s, [0, 1, 2])
    state = State.initial(s)
    T = first_feasible(s, with_no_throw(spec)).horizon
    witness = search_step(StepProblem(s, state, with_no_throw(spec)), T)
    assert witness.status is Status.OPTIMAL
    problem = StepProblem(s, state, spec)
    plain = search_step(problem, T)
    from_witness = search_step(problem, T, incumbent=witness)
    assert plain.status is from_witness.status is Status.OPTIMAL
    assert from_witness.cost == pytest.approx(plain.cost, rel=1e-6, abs=1e-9)
    assert from_witness.cost <= witness.cost + 1e-9
    assert replayed_trace_satisfies(s, spec, from_witness)
    again = search_step(problem, T, incumbent=plain)
    assert again.status is Status.OPTIMAL
    assert again.cost == pytest.approx(plain.cost, rel=1e-6, abs=1e-9)


def test_an_incumbent_no_object_changes_hands_in_decides_its_horizon(monkeypatch) -> None:
    """A plan in which no object is held by both hands is a plan of a node with one hand per
    object: as the incumbent it decides its horizon as the feasibility pass would, so the pass
    is not run, and the optimum is the search's from nothing. One handed over does not."""
    s = random_scene(1)
    spec = specification(s, [0, 1, 2])
    problem = StepProblem(s, State.initial(s), spec)
    T = first_feasible(s, spec).horizon
    plain = search_step(problem, T)
    assert plain.status is Status.OPTIMAL
    passes = []
    decide = FeasibilityPass.decide
    monkeypatch.setattr(FeasibilityPass, "decide",
                        lambda self: passes.append(self) or decide(self))
    again = search_step(problem, T, incumbent=plain)
    assert passes == [] and again.status is Status.OPTIMAL
    assert again.cost == pytest.approx(plain.cost, rel=1e-6, abs=1e-9)
    assert _without_handover(plain)
    grasp = plain.trajectory.grasp.copy()
    hand, j = np.argwhere(grasp[1:].any(axis=0))[0]
    grasp[-1, 1 - hand, j] = 1  # the other hand holds it too, at the end
    assert not _without_handover(dataclasses.replace(
        plain, trajectory=dataclasses.replace(plain.trajectory, grasp=grasp)))



def four_objects(seed: int) -> StepProblem:
    """The whole task of four objects, rule 1 (minimal horizon T = 15 on seed 1, 20 on seed 5,
    16 on seed 9)."""
    s = load_scenario("table1_vd", {"seed": seed, "random_objects": {"count": 4}, "rule": 1,
                                    "delivery": "rest"})
    s = dataclasses.replace(s, task=dataclasses.replace(s.task, m_o=4, n_o=4))
    return StepProblem(s, State.initial(s), specification(s, [0, 1, 2, 3],
                                                          rules=rule_formulas(s)))


def test_a_share_its_route_rules_out_rules_its_node_out_unsolved() -> None:
    """In a whole task most nodes give one hand more objects than its route allows: the
    feasibility pass rules such a node out with no program solved, the other hand's share
    included (its probe would be wasted)."""
    problem = four_objects(1)
    programs = StepPrograms(problem, predict_horizon(problem), solve_options(problem.scenario))
    search = StepSearch.of(programs)
    store = search.store

    def ruled_out(node) -> list[bool]:
        return [store.share_ruled_out(i, node.share(i)) for i in range(2)]

    crowded = [n for n in search.skeleton.single_hand() if any(ruled_out(n))
               and not all(ruled_out(n))]
    assert len(crowded) >= 8  # of the 16 nodes
    feasibility = FeasibilityPass(programs, store, search.skeleton)
    assert all(feasibility.relaxations_feasible(n) is False for n in crowded)
    assert store.solved == 0 and programs.stats.programs == 0


def test_a_whole_task_probes_a_single_object_only_as_a_share_of_a_node_left_open(
        monkeypatch) -> None:
    """Past m_o = 3 (``SINGLES_M_O``) a single object is a hand's share only beside the other
    hand's m_o − 1, which the route mostly rules out, and a hand with a plan for a share
    delivers each of its objects alone: the whole task's search probes a single only as the
    share of a node the route leaves open, fewer than when it probes them all at once, and
    finds the same optimum (four objects, seed 1, at the minimal horizon T = 15)."""
    problem = four_objects(1)
    objects = set(problem.spec.objects)

    def searched() -> tuple[StepResult, list[HandKey], StepSearch]:
        singles: list[HandKey] = []

        def counted(programs: StepPrograms, request: Request):
            if isinstance(request.key, HandKey) and len(request.key.share) == 1:
                singles.append(request.key)
            return solve_relaxation(programs, request)

        search = StepSearch.of(StepPrograms(problem, 15, solve_options(problem.scenario)),
                               solver=counted)
        return search.run(search.feasible()), singles, search

    res, singles, search = searched()
    assert all(not search.store.share_ruled_out(
        1 - k.hand, tuple(sorted(objects - set(k.share)))) for k in singles)
    monkeypatch.setattr(skeleton, "SINGLES_M_O", len(objects))
    every, all_singles, _ = searched()
    assert len(singles) < len(all_singles)
    assert res.status is every.status is Status.OPTIMAL
    assert res.cost == pytest.approx(every.cost, rel=1e-6, abs=1e-9)


def test_a_joint_part_its_hands_orders_bound_above_the_best_is_closed_unsolved() -> None:
    """A node's joint program split by its hands' orders is bounded part by part by c_i(o),
    each hand alone along its order (the parts of its share's relaxation): a part whose bound
    reaches the best plan so far is closed without its joint solve, and the node's optimum is
    still the best of every part's, each solved jointly in full. Four objects, seed 5, at the
    whole task's minimal horizon: a pair for each hand, four parts."""
    problem = four_objects(5)
    programs = StepPrograms(problem, 20, solve_options(problem.scenario))
    node = Node((0, 1, 2, 3), (0, 1, 1, 0))
    floor = np.array([programs.hand(i, node.share(i)).cost for i in range(2)])
    parts = list(itertools.product(*(programs.orders(i, node.share(i)) for i in range(2))))
    assert len(parts) == 4
    solve, joints = programs.solve, []

    def counted(*args, **kwargs):
        joints.extend([] if kwargs.get("relaxed") else [kwargs["orders"]])
        return solve(*args, **kwargs)

    programs.solve = counted
    found = programs.joint(node, floor)
    assert found.status is Status.OPTIMAL and 0 < len(joints) < len(parts)
    programs.solve = solve
    mask = programs.mask([(h, j) for j, h in zip(node.targets, node.hands, strict=True)])
    every = [programs.solve(programs.node_spec(node), mask, orders=part) for part in parts]
    assert all(r.status in (Status.OPTIMAL, Status.INFEASIBLE) for r in every)
    assert found.cost == pytest.approx(min(r.cost for r in every), rel=1e-6, abs=1e-9)
    assert replayed_trace_satisfies(problem.scenario, problem.spec, found)


def test_a_spread_programs_parts_run_in_waves_each_cut_off_by_those_before() -> None:
    """A node evaluated alone spreads its joint program's parts over the workers, ``WAVE`` at a
    time: the first wave against the incumbent (none here), each later part against the best
    plan of the waves before, and the optimum is the one solved part after part (four objects,
    seed 9, a horizon above its least: four parts, the first wave's plans cut off the second)."""
    problem = four_objects(9)
    node = Node((0, 1, 2, 3), (0, 1, 0, 1))
    found = []
    for pool in (None, ThreadPoolExecutor(2)):
        programs = StepPrograms(problem, 17, solve_options(problem.scenario), pool)
        floor = np.array([programs.hand(i, node.share(i)).cost for i in range(2)])
        solve, cutoffs = programs.solve, []

        def in_waves(*args, solve=solve, cutoffs=cutoffs, **kwargs):
            cutoffs.extend([] if kwargs.get("relaxed") else [kwargs["cutoff"]])
            return solve(*args, **kwargs)

        programs.solve = in_waves
        found.append(programs.joint(node, floor, spread=pool is not None))
    assert found[1].status is Status.OPTIMAL
    assert found[1].cost == pytest.approx(found[0].cost, rel=1e-6, abs=1e-9)
    assert len(cutoffs) > WAVE and np.isinf(cutoffs[:WAVE]).all()
    assert np.isfinite(cutoffs[WAVE:]).all() and min(cutoffs) >= found[1].cost - 1e-9


def test_a_wave_holds_only_parts_its_hands_orders_leave_below_the_best() -> None:
    """Before each wave of a spread program, the parts that the hands' orders bound above the
    best plan so far are closed, the orders still unknown solved alone first: a wave that
    held one beside a part that runs would leave its worker idle. Every part put in a wave is
    solved jointly, and the optimum is the node's (the node of
    ``test_a_joint_part_its_hands_orders_bound_above_the_best_is_closed_unsolved``, against an
    incumbent just above its optimum)."""
    problem = four_objects(5)
    node = Node((0, 1, 2, 3), (0, 1, 1, 0))
    alone = StepPrograms(problem, 20, solve_options(problem.scenario))
    floor = np.array([alone.hand(i, node.share(i)).cost for i in range(2)])
    optimum = alone.joint(node, floor)
    programs = StepPrograms(problem, 20, solve_options(problem.scenario), ThreadPoolExecutor(2))
    floor = np.array([programs.hand(i, node.share(i)).cost for i in range(2)])
    solve, pool_map, joints, waves = programs.solve, programs.map, [], []

    def counted(*args, **kwargs):
        joints.extend([] if kwargs.get("relaxed") else [kwargs["orders"]])
        return solve(*args, **kwargs)

    def in_waves(f, items):
        waves.extend([items] if items and isinstance(items[0], tuple) else [])
        return pool_map(f, items)

    programs.solve, programs.map = counted, in_waves
    found = programs.joint(node, floor, cutoff=optimum.cost * 1.01, spread=True)
    assert found.status is Status.OPTIMAL
    assert found.cost == pytest.approx(optimum.cost, rel=1e-6, abs=1e-9)
    assert 0 < len(joints) < 4 and sorted(joints) == sorted(p for w in waves for p in w)


def test_a_part_bounded_within_the_gap_below_the_best_is_closed_with_its_own_bound() -> None:
    """"Optimal" means within ``mip_rel_gap``, for a part as for a node: a part whose hands'
    orders bound it that close below the best plan is closed without its joint solve (five
    objects, seed 2: 24 s proving 3.3302 against 3.3303), and its bound is its own, not the
    cutoff's, so the step's gap stays a proof."""
    problem = four_objects(5)
    node = Node((0, 1, 2, 3), (0, 1, 1, 0))
    programs = StepPrograms(problem, 20, solve_options(problem.scenario))
    floor = np.array([programs.hand(i, node.share(i)).cost for i in range(2)])
    optimum = programs.joint(node, floor)
    least = min(sum(programs.order_bound(o) for o in part) for part in itertools.product(
        *(programs.orders(i, node.share(i)) for i in range(2))))
    cutoff = least / (1 - programs.options.mip_rel_gap / 2)
    solve, joints = programs.solve, []

    def counted(*args, **kwargs):
        joints.extend([] if kwargs.get("relaxed") else [kwargs["orders"]])
        return solve(*args, **kwargs)

    programs.solve = counted
    closed = programs.joint(node, floor, cutoff=cutoff)
    assert closed.status is Status.INFEASIBLE and not joints
    assert floor.sum() - 1e-9 <= least <= optimum.cost + 1e-9
    assert lower_bound(closed) == pytest.approx(least)


@pytest.mark.slow
def test_a_relaxation_is_solved_against_what_its_nodes_may_still_cost() -> None:
    """The best-first loop solves c_i(S) against the incumbent less the least bound of the
    other hand's share among the open nodes with it, not against the incumbent: in a whole
    task each share has one node, and a solve that cannot go below that closes it. Five
    objects, seed 0, at the minimal horizon (T = 23): a pair is solved against less than the
    optimum itself, once its node's triple is known, and the search's optimum is that of the
    same search with no cutoff on any relaxation."""
    s = load_scenario("table1_vd", {"seed": 0, "random_objects": {"count": 5}, "rule": 1,
                                    "delivery": "rest"})
    s = dataclasses.replace(s, task=dataclasses.replace(s.task, m_o=5, n_o=5))
    problem = StepProblem(s, State.initial(s), specification(s, [0, 1, 2, 3, 4],
                                                             rules=rule_formulas(s)))
    found, requests = [], []
    for targeted in (True, False):
        def solver(programs: StepPrograms, request: Request, targeted=targeted):
            requests.extend([request] if targeted else [])
            return solve_relaxation(programs, request if targeted else
                                    dataclasses.replace(request, cutoff=np.inf))

        programs = StepPrograms(problem, 23, solve_options(s), ThreadPoolExecutor(2))
        search = StepSearch.of(programs, solver=solver)
        found.append(search.run(search.feasible()))
    assert all(r.status is Status.OPTIMAL for r in found)
    assert found[0].cost == pytest.approx(found[1].cost, rel=1e-6, abs=1e-9)
    assert any(r.exact and isinstance(r.key, HandKey) and r.cutoff < found[0].cost
               for r in requests)


def test_an_orders_bound_from_a_solve_against_a_cutoff_goes_no_further_than_the_cutoff() -> None:
    """The later orders of a hand's share are solved against the best before them. HiGHS then
    prunes every subtree bounded at that cutoff, and it returned one order's plan above it as
    "optimal" (five objects, seed 5, T = 25: 1.589 against a cutoff of 1.147). Taken as the
    order's bound, that closed the joint part that held the whole task's optimum, and the
    search proved a plan of 3.659 optimal where one of 3.560 exists. What the orders' solves
    prove of each order is at most its optimum."""
    s = load_scenario("table1_vd", {"seed": 5, "random_objects": {"count": 5}, "rule": 1,
                                    "delivery": "rest"})
    s = dataclasses.replace(s, task=dataclasses.replace(s.task, m_o=5, n_o=5))
    problem = StepProblem(s, State.initial(s), specification(s, [0, 1, 2, 3, 4],
                                                             rules=rule_formulas(s)))
    chained = StepPrograms(problem, 25, solve_options(s))
    chained.hand(0, (1, 3))
    for order in chained.orders(0, (1, 3)):
        alone = StepPrograms(problem, 25, solve_options(s))
        best = alone.solve(*alone._relaxation((1, 3), (0,)), hands=(0,), orders=(order,),
                           relaxed=True)
        assert best.status is Status.OPTIMAL
        assert chained.order_bound(order) <= best.cost + 1e-9
