"""Tests for dualarm_mpc.model.band (the band bound): never above what a plan costs where objects
may be thrown and handed over.

Soundness is what matters: the bound at a horizon must not exceed the optimum of the monolithic
MILP at that horizon (one and two objects of §V-C, where every object is thrown, and one object
anywhere, under rule 2), nor the cost of any verified plan (§V-C's ten objects, §V-D's);
and it must say something: within a small factor of those optima. The whole task's plan under
rule 2 carries it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import dualarm_mpc as dm
from dualarm_mpc.milp.horizon import solve_options, solve_step
from dualarm_mpc.milp.solver import Status
from dualarm_mpc.model import band
from dualarm_mpc.model.mld import Model, State
from dualarm_mpc.model.scenario import load_scenario, scenario_path
from dualarm_mpc.model.spec import StepProblem, specification

VC_OBJECTS = yaml.safe_load(scenario_path("table1_vc").read_text())["objects"]


def _optimum(scenario, horizon: int) -> float | None:
    """The monolithic MILP's proven optimum of the whole task at ``horizon`` (None: no plan)."""
    objects = list(range(scenario.n_objects))
    problem = StepProblem(scenario, State.initial(scenario), specification(scenario, objects))
    options = dataclasses.replace(solve_options(scenario), mip_rel_gap=1e-6, time_limit_s=60.0)
    result = solve_step(problem, horizon, options)
    if result.status is Status.INFEASIBLE:
        return None
    assert result.status is Status.OPTIMAL
    return result.bound


def _bound(scenario, horizon: int) -> float:
    return band.task_bound(Model.from_scenario(scenario), State.initial(scenario),
                           list(range(scenario.n_objects)), horizon)


def _vc(objects: list[int]):
    return load_scenario("table1_vc", {"objects": [VC_OBJECTS[k] for k in objects],
                                       "m_o": len(objects), "n_o": len(objects)})


@pytest.mark.parametrize(("objects", "horizon"), [([0], 5), ([1], 6), ([0], 8), ([0, 1], 6),
                                                  ([0, 1], 8), ([2, 8], 7)])
def test_the_bound_is_below_the_optimum_where_every_object_is_thrown(objects, horizon) -> None:
    scenario = _vc(objects)
    optimum = _optimum(scenario, horizon)
    assert optimum is not None
    bound = _bound(scenario, horizon)
    assert 0.4 * optimum < bound <= optimum


@pytest.mark.parametrize(("objects", "horizon"), [([0, 1, 2], 5), ([0, 1, 2], 7), ([2, 8], 6)])
def test_the_bound_of_any_one_object_is_below_the_optimum(objects, horizon) -> None:
    scenario = dataclasses.replace(_vc(objects), task=dataclasses.replace(
        _vc(objects).task, m_o=1))
    optimum = _optimum(scenario, horizon)
    assert optimum is not None
    bound = band.task_bound(Model.from_scenario(scenario), State.initial(scenario),
                            objects=list(range(len(objects))), horizon=horizon, m_o=1)
    assert 0.4 * optimum < bound <= optimum


@pytest.mark.slow  # 12 examples of one object's MILP: about 12 s
@settings(max_examples=12, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(scene=st.sampled_from(["table1_vc", "table1_vd", "low"]),
       place=st.tuples(st.floats(-0.3, 0.3), st.floats(0.0, 0.3)),
       goal=st.sampled_from(["red", "green", "blue"]), delivery=st.sampled_from(["rest", "reach"]),
       extra=st.integers(0, 4))
@example(scene="low", place=(0.1, 0.2), goal="blue", delivery="rest", extra=2)
def test_the_bound_is_below_the_optimum_of_one_object_anywhere(scene, place, goal, delivery,
                                                                extra) -> None:
    # "low": §V-D with every goal below the objects, so that they move down
    low = {"goals": {name: [x0, x1, -0.3, -0.2] for name, (x0, x1) in
                     (("red", (0.225, 0.575)), ("green", (-0.175, 0.175)),
                      ("blue", (-0.575, -0.225)))}} if scene == "low" else {}
    scenario = load_scenario("table1_vd" if scene == "low" else scene, {
        "random_objects": None, "objects": [{"name": "object1", "position": list(place),
                                             "goal": goal}],
        "m_o": 1, "n_o": 1, "rule": 2, "delivery": delivery, **low})
    horizon = 5 + extra if scene == "table1_vc" else 8 + extra
    optimum = _optimum(scenario, horizon)
    bound = _bound(scenario, horizon)
    assert bound > 0
    if optimum is not None:
        assert bound <= optimum


def _first_plan(scenario) -> dm.Plan:
    """The whole task's first plan (sequential transportation's, joined)."""
    stop = dm.Interrupt()
    return dm.plan(dm.whole_task(scenario), check_first=False, stop=stop,
                   on_first_plan=lambda _: stop.set())


@pytest.mark.parametrize("scene", ["table1_vc", "table1_vd"])
def test_every_verified_plan_that_throws_costs_at_least_the_bound(scene) -> None:
    scenario = load_scenario(scene, {"rule": 2, "delivery": "rest"})
    plan = _first_plan(scenario)
    assert plan.verified
    (step,) = plan.segments
    bound = _bound(scenario, step.horizon)
    assert step.bound == bound
    assert 0.25 * step.cost < bound <= step.cost
    assert plan.gap == pytest.approx(1 - bound / step.cost)


def test_every_rule_2_step_carries_the_bound() -> None:
    # §V-C: steps of two objects out of six, each the step's no-throw witness or Algorithm 1's
    scenario = load_scenario("table1_vc")
    plan = dm.plan(scenario)
    assert plan.verified
    offset = 0
    for step in plan.segments:
        start = State.at(plan.trajectory, offset).select(step.objects)
        bound = band.task_bound(Model.from_scenario(scenario, step.objects), start,
                                list(range(len(step.objects))), step.horizon, m_o=2)
        assert step.gap == 0 or step.bound >= bound > 0
        offset += step.horizon
    assert plan.gap < 0.9


def test_the_bound_says_nothing_where_it_does_not_hold() -> None:
    scenario = _vc([0, 1])
    model, state = Model.from_scenario(scenario), State.initial(scenario)
    assert band.task_bound(model, state, [0, 1], 8) > 0
    moving = dataclasses.replace(state, hand_vel=np.array([[0.1, 0.0], [0.0, 0.0]]))
    assert band.task_bound(model, moving, [0, 1], 8) == 0.0
    sliding = dataclasses.replace(state, object_vel=np.array([[0.0, 0.2], [0.0, 0.0]]))
    assert band.task_bound(model, sliding, [0, 1], 8) == 0.0
    beside = dataclasses.replace(state, hand_pos=state.object_pos[[0, 1]])
    held = dataclasses.replace(beside, grasp=np.array([[1, 0], [0, 0]]))  # one more grasp
    assert band.task_bound(model, held, [0, 1], 8) == band.task_bound(model, beside, [0, 1], 8)
    placed = dataclasses.replace(state, object_pos=np.array([g.lo + 0.01 for g in model.goals]))
    assert band.task_bound(model, placed, [0, 1], 8) == 0.0
