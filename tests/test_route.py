"""Tests for dualarm_mpc.model.route (the route bound): it never exceeds what the MILP allows.

Soundness is what matters: when the bound says hand i needs more than T steps to deliver a set,
the one-hand program of horizon T (the search's relaxation, the same MILP the search would
solve) must be infeasible; when the step bound says no plan delivers m_o objects within T, the
monolithic MILP must have none. Checked at T = bound − 1 on seeded random states — moving
hands, both rules, sets of one and two objects — and the bound is checked to be worth having.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from dualarm_mpc.milp.backends import solve_standard_form
from dualarm_mpc.milp.horizon import HorizonProgram, solve_step
from dualarm_mpc.milp.solver import SolveOptions, Status
from dualarm_mpc.model import route
from dualarm_mpc.model.mld import N_HANDS, Model, State, in_goal
from dualarm_mpc.model.route import axis_steps, axis_times, horizon_bound, orders, route_steps
from dualarm_mpc.model.scenario import load_scenario
from dualarm_mpc.model.spec import StepProblem, restricted, specification


def test_one_axis_counts_the_steps_of_a_bang_bang_move() -> None:
    # From rest at 0 to rest anywhere in [0.5, 0.6] with v_max 0.2, u_max 0.1, Δt 1: the
    # position after k steps from rest is at most 0.1 + 0.2 + 0.2 + ... and the hand must
    # brake; 0.1 + 0.2 + 0.2 + 0.1 = 0.6 in 4 moves plus the step that ends at rest.
    axis = (1.0, 0.2, 0.1, -1.0, 1.0)
    visit = ((0.5, 0.6, 0.0),)
    assert axis_steps(axis, (0.0, 0.0), (visit,), 40) == 5
    # Out of the hand range: never.
    assert axis_steps(axis, (0.0, 0.0), (((1.5, 1.6, 0.0),),), 40) == 41


def test_a_held_object_travels_its_whole_distance_whatever_offset_the_hand_grabbed_it_at() -> None:
    # An object at 0 (half size 0.05) to a goal [0.65, 0.75], the hand at rest at 0. On the
    # hand alone, "deliver" is the hand in [0.6, 0.8]: it gets there at rest in 5 steps (0.1,
    # 0.3, 0.5, 0.6), but then the object it grabbed at step 1 stands at 0.6, outside. Followed
    # itself (from its grab at step 1, at 0 with at most 0.1 m/s), the object is first in its
    # goal at step 5 (0.7) and still moving: at rest at step 6, like every plan.
    axis = (1.0, 0.2, 0.1, -1.0, 1.0)
    grab = ((-0.05, 0.05, 0.0),)
    assert axis_times(axis, (0.0, 0.0), (grab, ((0.6, 0.8, 0.0),)), 40) == (1, 5, 5)
    held = (route._Grab(grab, 0.0, 0.05), route._Release(((0.65, 0.75, 0.0),), 0.05))
    assert axis_times(axis, (0.0, 0.0), held, 40) == (1, 5, 6)
    # From any state (None), the grab at step 1 can leave the object moving at 0.2 m/s
    # towards its goal: 0, 0.2, 0.4, 0.6, 0.7 at rest, four steps after the grab.
    assert axis_times(axis, None, held, 40) == (1, 5, 5)


def test_one_step_of_a_polygon_is_the_hull_of_its_moved_vertices() -> None:
    # The one-pass Minkowski step against the definition: every vertex sheared (x + Δt·v)
    # and moved by ±Δt·u_max, then the convex hull (as a set: the same vertices, any start).
    rng = np.random.default_rng(0)
    axis = (0.2, 0.2, 0.5, -1.0, 1.0)
    dt, v_max, u_max, lo, hi = axis
    for _ in range(200):
        poly = route._hull([tuple(p) for p in rng.uniform(-0.3, 0.3, (rng.integers(1, 8), 2))])
        du = dt * u_max
        expected = route._hull([(x + dt * v, v + d) for x, v in poly for d in (du, -du)])
        expected = route._slab(route._slab(expected, -v_max, v_max, speed=True), lo, hi)
        got = route._step(axis, poly)
        assert {tuple(p) for p in np.round(route._hull(got), 12)} \
            == {tuple(p) for p in np.round(route._hull(expected), 12)}


def test_routes_that_share_their_first_visits_answer_as_if_alone() -> None:
    # Stages are shared between routes with the same first visits and resumed from one cap to
    # the next: the answers must not depend on what was asked before.
    axis = (0.2, 0.2, 0.5, -1.0, 1.0)
    a, b, c = (((0.3, 0.35, 0.0),),), (((-0.5, -0.45, 0.0),),), (((0.8, 0.85, 0.0),),)
    routes = [a + b, a + c, a + b + c, a, b + a]
    asked = [(r, cap) for r in routes for cap in (5, 40)]
    alone = []
    for r, cap in asked:
        route._STAGES.clear()
        alone.append(axis_times(axis, (0.0, 0.0), r, cap))
    route._STAGES.clear()
    assert [axis_times(axis, (0.0, 0.0), r, cap) for r, cap in asked] == alone
    assert [axis_times(axis, (0.0, 0.0), r, cap) for r, cap in reversed(asked)] == alone[::-1]


def _random_state(scenario, objects, rng) -> State:
    """The scenario's objects, hands anywhere in their range with eq. (16), moving."""
    state = State.initial(scenario)
    ws = scenario.robot.workspace
    x = np.sort(rng.uniform(ws[0], ws[1], 2))[::-1]
    x[1] = min(x[1], x[0] - scenario.robot.hand_gap)
    hand_pos = np.column_stack([x, rng.uniform(ws[2], ws[3], 2)])
    hand_vel = rng.uniform(-1, 1, (2, 2)) * scenario.robot.max_speed * (rng.random() < 0.5)
    return State(hand_pos, hand_vel, state.object_pos, state.object_vel, state.grasp)


@pytest.mark.slow
@pytest.mark.parametrize("rule", [1, 2])
@pytest.mark.parametrize("seed", range(3))
def test_the_bound_never_rules_out_a_horizon_the_one_hand_program_allows(rule, seed) -> None:
    scenario = load_scenario("table1_vd", {"rule": rule, "seed": seed, "delivery": "reach",
                                           "random_objects": {"count": 4}})
    rng = np.random.default_rng(seed)
    objects = [0, 1, 2, 3]
    state = _random_state(scenario, objects, rng)
    spec = specification(scenario, objects)
    model = Model.from_scenario(scenario, objects)
    local = state.select(objects)
    no_throw = frozenset(objects.index(j) for j in spec.released_only_in_goal())
    assert no_throw == (frozenset(range(4)) if rule == 1 else frozenset())
    options = SolveOptions(time_limit_s=60.0, mip_rel_gap=1.0, small_trees=True)
    shares = [(j,) for j in objects] + list(itertools.combinations(objects, 2))[:3]
    checked = 0
    for i in range(N_HANDS):
        for share in shares:
            bound = route_steps(model, local, i, tuple(objects.index(j) for j in share),
                                no_throw, scenario.solver.max_horizon)
            if bound <= 1:
                continue
            program = HorizonProgram(scenario, state, objects, bound - 1)
            allowed = np.zeros((N_HANDS, len(objects)), bool)
            allowed[i, [objects.index(j) for j in share]] = True
            res = program.solve(restricted(spec, share, share), options, allowed=allowed,
                                hands=(i,))
            assert res.status is Status.INFEASIBLE, (i, share, bound)
            checked += 1
    assert checked >= 10  # the bound speaks for most sets


def test_under_no_throw_a_hand_finishes_one_object_before_the_next() -> None:
    scenario = load_scenario("table1_vd", {"rule": 1, "seed": 0, "delivery": "reach"})
    objects = [0, 1, 2]
    model = Model.from_scenario(scenario, objects)
    state = State.initial(scenario).select(objects)
    singles = [route_steps(model, state, 0, (n,), frozenset({0, 1, 2}), 40) for n in range(3)]
    pair = route_steps(model, state, 0, (0, 1), frozenset({0, 1, 2}), 40)
    free = route_steps(model, state, 0, (0, 1), frozenset(), 40)
    # Two trips to the goals and back take longer than either trip; a hand that may put an
    # object down is bounded by the slower trip alone.
    assert pair > max(singles[:2]) + 3
    assert free == max(route_steps(model, state, 0, (n,), frozenset(), 40) for n in (0, 1))


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "m_o"), [(0, 1), (1, 2), (2, 2), (3, 2)])
def test_the_step_bound_never_rules_out_a_horizon_the_monolithic_milp_allows(seed, m_o) -> None:
    """Under no-throw, every plan's hands make the routes of some m_o objects, hand-overs or
    not: at one step below the bound the whole MILP (both hands, every rule) has no plan."""
    scenario = load_scenario("table1_vd", {"rule": 1, "seed": seed, "delivery": "reach",
                                           "m_o": m_o, "n_o": 3,
                                           "random_objects": {"count": 3}})
    rng = np.random.default_rng(seed)
    state = _random_state(scenario, [0, 1, 2], rng)
    spec = specification(scenario, [0, 1, 2])
    bound = horizon_bound(Model.from_scenario(scenario, [0, 1, 2]), state,
                          m_o, frozenset({0, 1, 2}), scenario.solver.max_horizon)
    assert bound > 1
    res = solve_step(StepProblem(scenario, state, spec), bound - 1,
                     SolveOptions(time_limit_s=120.0, mip_rel_gap=1.0))
    assert res.status is Status.INFEASIBLE, bound


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2))
def test_splitting_a_share_by_order_keeps_its_optimum_and_every_plan(seed) -> None:
    """Under no-throw, hand i's program for a pair is the union of its orders' programs: the
    best order has the whole program's optimum, and the whole program's plan follows one order
    without grabbing an object, or having it in its goal, before that order's route allows, nor
    grabbing an object later than the rest of its route allows: an order's program with the
    first grab forced after that step has no plan."""
    scenario = load_scenario("table1_vd", {"rule": 1, "seed": seed, "delivery": "reach",
                                           "random_objects": {"count": 4}})
    objects = [0, 1, 2, 3]
    state = _random_state(scenario, objects, np.random.default_rng(seed + 10))
    spec = specification(scenario, objects)
    model = Model.from_scenario(scenario, objects)
    options = SolveOptions(time_limit_s=120.0, small_trees=True)
    for i, share in ((0, (0, 1)), (1, (2, 3))):
        found = orders(model, state.select(objects), i, share, frozenset(objects),
                       scenario.solver.max_horizon)
        assert len(found) == 2
        allowed = np.zeros((N_HANDS, len(objects)), bool)
        allowed[i, list(share)] = True
        task = restricted(spec, share, share)
        for horizon in range(found[0].steps, found[0].steps + 10):  # the first with a plan
            program = HorizonProgram(scenario, state, objects, horizon)
            whole = program.solve(task, options, allowed=allowed, hands=(i,))
            if whole.status is not Status.INFEASIBLE:
                break
        parts = [program.solve(task, options, allowed=allowed, hands=(i,), orders=(o,))
                 for o in found if o.steps <= horizon]
        assert whole.status is Status.OPTIMAL
        best = min(p.cost for p in parts if p.status is Status.OPTIMAL)
        assert best == pytest.approx(whole.cost, rel=1e-6, abs=1e-9)
        grasp = whole.trajectory.grasp[:, i]
        first_grab = [int(np.argmax(grasp[1:, n])) + 1 for n in share]
        first_goal = [next(k for k in range(horizon + 1)
                           if in_goal(whole.trajectory.object_pos[k, n], model.goals[n]))
                      for n in share]
        order = next(o for o in found if list(o.objects) == sorted(share, key=dict(
            zip(share, first_grab, strict=True)).get))
        for m, n in enumerate(order.objects):
            assert order.grab[m] <= first_grab[share.index(n)] <= order.latest(horizon)[m]
            assert first_goal[share.index(n)] >= order.goal[m]
        first = dataclasses.replace(options, mip_rel_gap=1.0)
        for o in (o for o in found if o.steps <= horizon):
            unbounded = dataclasses.replace(o, after=(0,) * len(o.objects))
            for n, latest in zip(o.objects, o.latest(horizon), strict=True):
                f = program.standard_form(task, allowed=allowed, hands=(i,), orders=(unbounded,))
                f.col_ub[program.x.eta[1:latest + 1, i, n]] = 0.0  # first grabbed after latest
                assert solve_standard_form(f, first).status is Status.INFEASIBLE, (o, n)


@pytest.mark.parametrize("seed", range(3))
def test_under_no_throw_both_hands_deliver_an_object_no_sooner_than_one_hand_could(seed) -> None:
    """The search skips c(j), both hands delivering j, when neither hand's route reaches j's
    goal within the horizon: the first hand to hold j holds it until j is in its goal, hand-over
    or not. So at one step below the lesser route bound, c(j)'s program has no plan."""
    scenario = load_scenario("table1_vd", {"rule": 1, "seed": seed, "delivery": "reach",
                                           "random_objects": {"count": 3}})
    objects = [0, 1, 2]
    state = _random_state(scenario, objects, np.random.default_rng(seed + 20))
    spec = specification(scenario, objects)
    model = Model.from_scenario(scenario, objects)
    options = SolveOptions(time_limit_s=60.0, mip_rel_gap=1.0, small_trees=True)
    for n, j in enumerate(objects):
        bound = min(route_steps(model, state.select(objects), i, (n,), frozenset(range(3)),
                                scenario.solver.max_horizon) for i in range(N_HANDS))
        assert bound > 1
        allowed = np.zeros((N_HANDS, len(objects)), bool)
        allowed[:, n] = True
        res = HorizonProgram(scenario, state, objects, bound - 1).solve(
            restricted(spec, (j,), (j,)), options, allowed=allowed)
        assert res.status is Status.INFEASIBLE, (j, bound)


@pytest.mark.parametrize("seed", range(4))
def test_the_bound_over_delivered_sets_is_the_least_over_the_orders(seed) -> None:
    """Held–Karp (``route._delivered``) against the enumeration it replaced: for every share
    of up to four no-throw objects, from the start and from moving hands, the least over the
    share's orders of the slower axis's route (``axis_steps`` along each order) is the bound."""
    scenario = load_scenario("table1_vd", {"rule": 1, "seed": seed,
                                           "random_objects": {"count": 4}})
    objects = [0, 1, 2, 3]
    model = Model.from_scenario(scenario, objects)
    no_throw = frozenset(objects)
    for state in (State.initial(scenario), _random_state(scenario, objects,
                                                         np.random.default_rng(seed))):
        for i in range(N_HANDS):
            for k in range(1, 5):
                for share in itertools.combinations(objects, k):
                    by_orders = min(
                        max(axis_steps(*route._route(model, state, i, order, a, no_throw), 60)
                            for a in range(2))
                        for order in itertools.permutations(share))
                    assert route_steps(model, state, i, share, no_throw, 60) == by_orders, \
                        (i, share)


def test_the_axes_share_each_visit_s_step() -> None:
    """Each axis counted alone may make a visit at a step at which the other cannot yet; every
    plan makes it at one step on both. With the times shared (``route._times``), a pair of
    five objects (seed 9, hand 0 delivering objects 2 and 4) needs two steps more than each
    axis alone says, and that is its exact least horizon: the one-hand program has no plan one
    step below it and has one at it."""
    scenario = load_scenario("table1_vd", {"rule": 1, "seed": 9, "delivery": "rest",
                                           "random_objects": {"count": 5}})
    objects = [0, 1, 2, 3, 4]
    model, state = Model.from_scenario(scenario), State.initial(scenario)
    spec, share = specification(scenario, objects), (2, 4)
    no_throw = frozenset(objects)
    alone = route_steps(model, state, 0, share, no_throw, 60)
    shared = min(o.steps for o in orders(model, state, 0, share, no_throw, 60))
    assert (alone, shared) == (16, 18)
    allowed = np.zeros((N_HANDS, len(objects)), bool)
    allowed[0, list(share)] = True
    options = SolveOptions(time_limit_s=120.0, mip_rel_gap=1.0, small_trees=True)
    status = [HorizonProgram(scenario, state, objects, horizon).solve(
        restricted(spec, share, share), options, allowed=allowed, hands=(0,)).status
              for horizon in (shared - 1, shared)]
    assert status[0] is Status.INFEASIBLE and status[1].has_solution


class _StopAfter:
    """A ``stopped`` that says yes from its ``polls``-th call on, counting the calls."""

    def __init__(self, polls: int) -> None:
        self.polls, self.calls = polls, 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.calls >= self.polls


def test_a_stop_ends_the_largest_step_s_bound_at_its_next_poll() -> None:
    """The largest step a scenario may ask, ten objects of ten delivered (m_o = 10, the cap):
    the bound polls the stop as it counts and, once stopped, each count left returns at its
    first poll (at most the 2 × 10 single objects' and the loop's) with 0, ruling nothing out."""
    scenario = load_scenario("table1_vd", {"rule": 1, "m_o": 10, "n_o": 10})
    objects = list(range(10))
    model = Model.from_scenario(scenario, objects)
    state = State.initial(scenario).select(objects)
    for polls in (1, 30):
        stop = _StopAfter(polls)
        assert horizon_bound(model, state, 10, frozenset(objects), 40, stop) == 0
        assert stop.calls <= polls + 2 * 10 + 1
        route._STAGES.clear()
    stop = _StopAfter(5)
    assert route_steps(model, state, 0, tuple(objects), frozenset(objects), 40, stop) == 0
    assert stop.calls == 5
