"""The anytime plan (``dm.plan``'s two passes, docs/search.md): under a rule that allows throws,
each step's no-throw witness gives a complete plan first, verified against the scenario's own
rules and carrying no claim beyond its own; Algorithm 1 then refines it, and a stop between the
passes returns the first plan whole. The whole task (``--mo all``) is anytime from sequential
transportation's plan, joined into one step."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np
import pytest

import dualarm_mpc as dm
from dualarm_mpc.milp.horizon import StepResult, solve_options
from dualarm_mpc.milp.solver import Status
from dualarm_mpc.model.mld import Model, State, in_goal, reachability
from dualarm_mpc.model.verify import verify
from dualarm_mpc.planning import sequential
from dualarm_mpc.planning.sequential import HorizonTried, predict_horizon, solve_horizon
from dualarm_mpc.planning.shorten import _removals, shortened
from dualarm_mpc.planning.task import (
    FIRST_PASS,
    LARGER_STEPS,
    _Horizons,
    _in_larger_steps,
    _origin,
    _sequential_first,
    _shortened,
    _whole_step,
    first_pass,
)


def four_objects(rule: int) -> dm.Scenario:
    return dm.load_scenario("table1_vd", {"seed": 1, "random_objects": {"count": 4},
                                          "rule": rule, "m_o": 2, "n_o": 4})


def optimised_spy(heard: list) -> Callable:
    """``sequential.optimised``, telling ``heard`` of each witness it gets and what it returns."""
    real = sequential.optimised

    def spy(problem, found, *args, **kw):
        res = real(problem, found, *args, **kw)
        heard.append((problem, found, res))
        return res

    return spy


@pytest.fixture(scope="module")
def refined():
    """Rule 2: the plan, the first pass's plan as ``on_first_plan`` heard of it, and each
    witness the second pass optimised: (step problem, the first pass's, the optimised)."""
    firsts: list[dm.Plan] = []
    heard: list = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sequential, "optimised", optimised_spy(heard))
        return dm.plan(four_objects(2), on_first_plan=firsts.append), firsts, heard


def test_the_first_plan_is_complete_verified_and_claims_no_more_than_it_has(refined) -> None:
    plan, firsts, _ = refined
    assert len(firsts) == 1
    first = firsts[0]
    assert first.verified and not first.partial
    assert all(d is not None for d in first.delivered_step)
    assert verify(four_objects(2), first).ok  # the no-throw witnesses obey rule 2 too
    for step in first.segments:  # a witness's bound and horizons are its restriction's
        assert step.witness_cost == pytest.approx(step.cost)
        assert step.bound == 0.0 and step.status == "feasible"
    assert first.gap == 1.0


def test_the_refined_plan_is_no_worse_and_counts_every_search(refined) -> None:
    plan, (first,), _ = refined
    assert plan.verified and not plan.partial
    assert plan.total_cost <= first.total_cost + 1e-9
    assert plan.first_plan_s == first.first_plan_s
    # the second pass took the first step's witness; the first pass's other steps were its own
    assert plan.unused_solve_time_s > 0
    assert plan.total_solve_time_s == pytest.approx(
        sum(s.solve_time_s for s in plan.segments) + plan.unused_solve_time_s)
    assert plan.first_plan_s < plan.total_solve_time_s
    assert dm.Plan.from_json(plan.to_json()).unused_solve_time_s == pytest.approx(
        plan.unused_solve_time_s, abs=1e-4)


def test_the_second_pass_optimises_the_witnesses_the_first_took_at_first_sight(refined) -> None:
    """The first pass takes each witness as its search first finds it (the first plan comes
    sooner); the second pass meets the first step again and optimises its witness at its
    horizon before it searches the shorter ones: never worse."""
    _, (first,), heard = refined
    (problem, found, _), *_ = heard
    assert problem.spec.objects == tuple(first.segments[0].objects)
    assert found.cost == pytest.approx(first.segments[0].cost)
    for _, before, after in heard:
        assert after.horizon == before.horizon and after.cost <= before.cost + 1e-9


def test_a_stop_after_the_first_plan_returns_it_whole() -> None:
    stop = dm.Interrupt()
    firsts: list[dm.Plan] = []

    def heard(first: dm.Plan) -> None:
        firsts.append(first)
        stop.set()

    plan = dm.plan(four_objects(2), stop=stop, on_first_plan=heard)
    assert plan.verified and not plan.partial
    assert plan.total_cost == firsts[0].total_cost
    assert [s.cost for s in plan.segments] == [s.cost for s in firsts[0].segments]


def test_without_a_witness_one_pass_is_the_plan() -> None:
    """Rule 1 has no-throw already: no witness, so one pass, which is Algorithm 1."""
    firsts: list[dm.Plan] = []
    plan = dm.plan(four_objects(1), on_first_plan=firsts.append)
    assert firsts == [] and plan.verified
    assert plan.unused_solve_time_s == 0.0
    assert plan.first_plan_s >= plan.total_solve_time_s - 1e-3


def test_the_whole_task_under_rule_2_searches_from_its_no_throw_witness(monkeypatch) -> None:
    """``plan --mo all`` under rule 2: after the first plan (sequential transportation's,
    joined), the whole task's search starts from its no-throw witness, one step over every
    object; the plan returned is no worse than either and says what it has not proven. (Seed
    0: the witness's horizon is below the first plan re-timed, planning/shorten.py; on seed 1
    it is not, and the search runs without one.)"""
    scenario = dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 0, "random_objects": {"count": 3}, "rule": 2, "delivery": "rest"}))
    firsts: list[dm.Plan] = []
    heard: list = []
    monkeypatch.setattr(sequential, "optimised", optimised_spy(heard))
    plan = dm.plan(scenario, on_first_plan=firsts.append)
    # the whole step's witness is optimised at once: the first plan exists already, and the
    # search's first pass is what a stop leaves; only sequential transportation's are not
    assert heard and all(problem.spec.m_o == FIRST_PASS[0] for problem, _, _ in heard)
    (first,) = firsts
    assert [s.objects for s in first.segments] == [[0, 1, 2]]
    assert first.segments[0].sequential_steps >= 2
    assert first.verified and first.first_plan_s == plan.first_plan_s
    assert plan.verified and [sorted(s.objects) for s in plan.segments] == [[0, 1, 2]]
    assert (plan.makespan, plan.total_cost) <= (first.makespan, first.total_cost + 1e-9)
    steps = dm.plan(first_pass(scenario))  # never worse than its plan, witnesses refined
    assert (plan.makespan, plan.total_cost) <= (steps.makespan, steps.total_cost + 1e-9)
    step = plan.segments[0]
    assert step.sequential_steps is None and step.witness_cost is not None
    assert step.cost <= step.witness_cost + 1e-9
    assert plan.total_bound <= plan.total_cost + 1e-9
    assert step.horizon_proven_minimal == (not step.horizons_undecided
                                           and step.shorter_plan is None)


def whole_of_four() -> dm.Scenario:
    return dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 1, "random_objects": {"count": 4}, "rule": 1, "delivery": "rest"}))


def test_the_whole_task_is_anytime_from_sequential_transportation() -> None:
    """``plan --mo all``: the first plan is sequential transportation's at ``FIRST_PASS``,
    joined into one step over every object, verified as the whole task's and claiming nothing
    beyond being a plan; the whole-task search's plan, proven, replaces it and is never
    longer."""
    scenario = whole_of_four()
    firsts: list[dm.Plan] = []
    plan = dm.plan(scenario, on_first_plan=firsts.append)
    (first,) = firsts
    (joined,) = first.segments
    m_o, n_o = FIRST_PASS
    steps = dm.plan(dataclasses.replace(scenario, task=dataclasses.replace(
        scenario.task, m_o=m_o, n_o=min(n_o, 4))))
    assert joined.sequential_steps == len(steps.segments) >= 2
    assert first.makespan == steps.makespan
    assert first.total_cost == pytest.approx(steps.total_cost)
    assert first.verified and verify(scenario, first).ok
    assert joined.objects == [0, 1, 2, 3] and joined.delivered == [0, 1, 2, 3]
    assert joined.bound == 0 and joined.status == "feasible" and not joined.horizon_proven_minimal
    (step,) = plan.segments
    assert step.sequential_steps is None
    assert step.proven_optimal and step.horizon_proven_minimal
    assert plan.makespan <= first.makespan and plan.verified
    assert plan.first_plan_s == first.first_plan_s
    assert plan.total_solve_time_s == pytest.approx(
        step.solve_time_s + plan.unused_solve_time_s, abs=1e-4)
    assert plan.unused_solve_time_s >= joined.solve_time_s - 1e-3


@pytest.fixture(scope="module")
def stopped_at_first():
    stop = dm.Interrupt()
    return dm.plan(whole_of_four(), stop=stop, on_first_plan=lambda first: stop.set())


def test_a_stop_after_the_whole_tasks_first_plan_returns_it_whole(stopped_at_first) -> None:
    plan = stopped_at_first
    (joined,) = plan.segments
    assert plan.verified and not plan.partial and joined.sequential_steps >= 2
    assert all(d is not None for d in plan.delivered_step)
    # no search ran: below its horizon only what reachability rules out (predictT without
    # the route bound the stop ends), every object's first step in its goal
    scenario = whole_of_four()
    first_goal = reachability(Model.from_scenario(scenario), State.initial(scenario),
                              scenario.solver.max_horizon).first_goal
    assert joined.horizons_undecided == list(range(int(first_goal.max()), joined.horizon))
    assert 1 < first_goal.max() < joined.horizon and not joined.horizon_proven_minimal


def test_the_first_plan_carries_the_horizons_the_stopped_search_proved_empty(
        stopped_at_first) -> None:
    """From predictT (the first horizon the search tries), each horizon proven empty in a row
    leaves the undecided ones; all of them proven, the joined plan's horizon is minimal."""
    (joined,) = stopped_at_first.segments
    T = joined.horizon

    def heard(*results: tuple[int, Status]) -> _Horizons:
        scenario = whole_of_four()
        horizons = _Horizons(scenario, solve_options(scenario), None)
        for horizon, status in results:
            horizons(HorizonTried(1, None, StepResult.no_plan(status, horizon)))
        horizons(HorizonTried(2, None, StepResult.no_plan(Status.INFEASIBLE, T - 1)))
        return horizons

    (step,) = heard((T - 5, Status.INFEASIBLE), (T - 3, Status.INFEASIBLE),
                    (T - 4, Status.TIME_LIMIT)).certify(stopped_at_first).segments
    assert step.horizons_undecided == [T - 4, T - 3, T - 2, T - 1]  # T − 3: not in a row
    assert not step.horizon_proven_minimal
    (step,) = heard(*((t, Status.INFEASIBLE) for t in range(T - 3, T))).certify(
        stopped_at_first).segments
    assert step.horizons_undecided == [] and step.horizon_proven_minimal
    # the cost bounded by the motion bound alone (model/motion.py), as the plan was
    assert step.bound == joined.bound > 0 and step.status == "feasible"


def test_the_whole_search_reaches_past_the_horizon_cap_up_to_the_first_plan() -> None:
    """No step of sequential transportation needs more than 14 steps here, the whole task
    needs 15: the first plan, 17 steps long, lifts the search's cap to its own horizon (none
    longer can better it), and the search's plan replaces it."""
    scenario = dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 1, "random_objects": {"count": 4}, "rule": 1, "delivery": "rest",
        "solver": {"max_horizon": 14, "time_limit_s": 120}}))  # time to spare under load
    firsts: list[dm.Plan] = []
    plan = dm.plan(scenario, on_first_plan=firsts.append)
    (first,) = firsts
    (step,) = plan.segments
    assert step.sequential_steps is None and step.horizon_proven_minimal
    assert 14 < step.horizon < first.makespan and plan.verified


def test_the_search_starts_from_the_first_plan_at_its_horizon(monkeypatch) -> None:
    """Four objects, seed 3: sequential transportation's plan, joined, is 20 steps long, and so
    is the whole task's least horizon. The search meets the first plan there as its incumbent
    and betters it: a cheaper plan at the same horizon, proven optimal."""
    incumbents: dict[int, StepResult | None] = {}

    def heard(*args, incumbent=None, **kw) -> StepResult:
        if args[0].spec.m_o == 4:  # the whole step's
            incumbents[args[1]] = incumbent
        return solve_horizon(*args, incumbent=incumbent, **kw)

    monkeypatch.setattr(sequential, "solve_horizon", heard)
    scenario = dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 3, "random_objects": {"count": 4}, "rule": 1, "delivery": "rest",
        "solver": {"time_limit_s": 120}}))  # time to spare under load
    firsts: list[dm.Plan] = []
    plan = dm.plan(scenario, on_first_plan=firsts.append)
    (first,) = firsts
    (step,) = plan.segments
    known = incumbents[first.makespan]
    assert known is not None and known.cost == pytest.approx(first.total_cost)
    assert all(v is None for T, v in incumbents.items() if T != first.makespan)
    assert plan.verified and plan.makespan == first.makespan
    assert step.horizon_proven_minimal and step.status == "optimal"
    assert plan.total_cost < first.total_cost and step.sequential_steps is None


def test_the_search_s_plan_that_is_its_incumbent_keeps_the_first_plan_s_mark() -> None:
    """Where the search returns its incumbent, the first plan, bettered by nothing, the plan is
    still sequential transportation's (its ``sequential_steps``) with the search's certificate;
    any other plan of the search is its own."""
    stop = dm.Interrupt()
    first = dm.plan(whole_of_four(), stop=stop, on_first_plan=lambda _: stop.set())
    (own,) = first.segments
    assert own.sequential_steps
    certified = dataclasses.replace(own, sequential_steps=None, status="optimal",
                                    bound=own.cost, gap=0.0)
    searched = dataclasses.replace(first, segments=[certified])
    (step,) = _origin(searched, first).segments
    assert step.sequential_steps == own.sequential_steps and not step.guided
    assert step.status == "optimal" and step.bound == own.cost
    force = first.trajectory.force.copy()
    force[0, 0, 0] += 1e-3
    other = dataclasses.replace(searched, trajectory=dataclasses.replace(
        first.trajectory, force=force))
    assert _origin(other, first).segments[0].sequential_steps is None


def test_a_stop_within_a_horizon_keeps_the_plan_it_found(monkeypatch) -> None:
    """A stop that ends the whole task's search within a horizon after it found a plan (here
    at the last moment of the search) keeps that plan: shorter than the joined first plan,
    verified, its optimum claimed only as far as the search proved it."""
    stop = dm.Interrupt()

    def stopped_once_planned(*args, **kw) -> StepResult:
        res = solve_horizon(*args, **kw)
        if res.status.has_solution and args[0].spec.m_o == 4:  # the whole step's
            stop.set()
        return res

    monkeypatch.setattr(sequential, "solve_horizon", stopped_once_planned)
    firsts: list[dm.Plan] = []
    plan = dm.plan(whole_of_four(), stop=stop, on_first_plan=firsts.append)
    (first,) = firsts
    (step,) = plan.segments
    assert stop.is_set() and plan.verified and not plan.partial
    assert step.sequential_steps is None and plan.makespan < first.makespan
    assert step.bound <= step.cost and (step.status == "optimal") == (
        step.gap <= whole_of_four().solver.mip_rel_gap)


# --- the whole task in larger steps ------------------------------------------------------------


def seven_objects(rule: int = 1) -> dm.Scenario:
    return dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 1, "random_objects": {"count": 7}, "rule": rule, "delivery": "rest",
        "solver": {"time_limit_s": 60}}))  # time to spare under load


@pytest.fixture(scope="module")
def in_larger_steps():
    """Seven objects, rule 1: the whole task's first plan (``FIRST_PASS``'s four steps, 40 Δt)
    and sequential transportation at ``LARGER_STEPS`` after it, joined (two steps, 35 Δt), as
    ``on_shorter_plan`` hears of it; stopped there, before the search."""
    scenario, stop, heard = seven_objects(), dm.Interrupt(), []
    plan = dm.plan(scenario, stop=stop, on_first_plan=heard.append,
                   on_shorter_plan=lambda better: (heard.append(better), stop.set()))
    (first, larger) = heard
    assert plan.makespan == larger.makespan and plan.verified  # the stop keeps it
    return first, larger


def test_the_whole_task_in_larger_steps_replaces_a_longer_first_plan(in_larger_steps) -> None:
    first, larger = in_larger_steps
    scenario = seven_objects()
    assert first.segments[0].sequential_row == list(FIRST_PASS)
    assert larger is not None and larger.verified and verify(scenario, larger).ok
    (step,) = larger.segments
    assert step.sequential_row == list(LARGER_STEPS) and step.sequential_steps == 2
    assert predict_horizon(_whole_step(scenario)) <= larger.makespan < first.makespan
    assert larger.first_plan_s == first.first_plan_s  # the time to the first plan stays
    last = larger.trajectory
    for j, o in enumerate(scenario.task.objects):  # every object at rest in its goal
        assert in_goal(last.object_pos[-1, j], scenario.task.goals[o.goal])
        assert np.allclose(last.object_vel[-1, j], 0.0)
    assert step.bound == 0.0 and step.status == "feasible"  # it claims nothing more
    assert dm.Plan.from_json(larger.to_json()).segments[0].sequential_row == list(LARGER_STEPS)


@pytest.mark.parametrize("overrides", [{"rule": 2}, {"random_objects": {"count": 6}}])
def test_larger_steps_are_not_tried_where_an_object_may_be_thrown_or_on_fewer_objects(
        in_larger_steps, overrides) -> None:
    first, _ = in_larger_steps
    scenario = dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 1, "random_objects": {"count": 7}, "rule": 1, "delivery": "rest", **overrides}))
    assert _in_larger_steps(scenario, first, solve_options(scenario)) is None


def test_larger_steps_say_nothing_once_stopped(in_larger_steps) -> None:
    first, _ = in_larger_steps
    scenario, stop = seven_objects(), dm.Interrupt()
    stop.set()
    options = dataclasses.replace(solve_options(scenario), interrupt=stop)
    assert _in_larger_steps(scenario, first, options) is None


# --- the first plan re-timed (planning/shorten.py) ---------------------------------------------


@pytest.fixture(scope="module")
def re_timed():
    """Seven objects, rule 2: the whole task's first plan, sequential transportation's at
    (2, 5), joined (39 Δt), and that plan re-timed, as ``plan`` takes it before the search."""
    scenario = seven_objects(rule=2)
    options = solve_options(scenario)
    first = _sequential_first(scenario, options, None, None, None, time.perf_counter())
    return first, _shortened(scenario, first, options)


def grasps(plan: dm.Plan) -> list[list[int]]:
    """Each hand's objects in the order it first grabs them."""
    g = plan.trajectory.grasp
    return [sorted((j for j in range(g.shape[2]) if g[:, i, j].any()),
                   key=lambda j: int(np.argmax(g[:, i, j]))) for i in range(2)]


def test_a_re_timed_plan_delivers_every_object_sooner_with_the_same_grasps(re_timed) -> None:
    first, shorter = re_timed
    scenario = seven_objects(rule=2)
    assert shorter is not None and shorter.verified and verify(scenario, shorter).ok
    (step,) = shorter.segments
    assert step.shortened >= 1 and shorter.makespan == first.makespan - step.shortened
    assert grasps(shorter) == grasps(first)  # which hand holds what, in what order: kept
    last = shorter.trajectory
    for j, o in enumerate(scenario.task.objects):  # every object at rest in its goal
        assert in_goal(last.object_pos[-1, j], scenario.task.goals[o.goal])
        assert np.allclose(last.object_vel[-1, j], 0.0)
    # it claims nothing beyond being a plan, and keeps where it came from
    assert step.bound == 0.0 and step.status == "feasible"
    (own,) = first.segments
    assert (step.sequential_row, step.sequential_steps) == (own.sequential_row,
                                                            own.sequential_steps)
    assert shorter.first_plan_s == first.first_plan_s
    assert dm.Plan.from_json(shorter.to_json()).segments[0].shortened == step.shortened


def test_no_step_comes_out_of_a_plan_at_its_proven_minimal_horizon() -> None:
    scenario = dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 3, "random_objects": {"count": 2}, "rule": 1, "delivery": "rest"}))
    plan = dm.plan(scenario)
    assert plan.horizon_proven_minimal  # so no plan is one step shorter
    assert shortened(_whole_step(scenario), plan.trajectory.grasp,
                     solve_options(scenario)) is None


def test_a_stopped_search_takes_no_step_out(re_timed) -> None:
    first, _ = re_timed
    scenario, stop = seven_objects(rule=2), dm.Interrupt()
    stop.set()
    options = dataclasses.replace(solve_options(scenario), interrupt=stop)
    assert _shortened(scenario, first, options) is None


def test_each_removal_takes_one_step_out_of_each_hand_and_keeps_the_start() -> None:
    grasp = np.zeros((7, 2, 2), int)
    grasp[1:3, 0, 0] = 1  # arm 1 holds object 0 at steps 1-2
    grasp[2:6, 1, 1] = 1  # arm 2 holds object 1 at steps 2-5: it ends later, so goes first
    removals = list(_removals(grasp))
    # arm 2: out of its way to object 1, its carry, or its last step (arm 1 its last); arm 1:
    # out of its carry; both: steps 1 and 2 (the rest are schedules already given)
    assert len(removals) == len({r.tobytes() for r in removals}) == 3 + 1 + 2
    assert all(r.shape == (6, 2, 2) and (r[0] == grasp[0]).all() for r in removals)
    assert removals[0][:, 1, 1].tolist() == [0, 1, 1, 1, 1, 0]  # arm 2's step 1 out
    assert removals[0][:, 0, 0].tolist() == grasp[:6, 0, 0].tolist()  # arm 1's last out
