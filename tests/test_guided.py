"""The whole task's route-guided plan (``planning/guided.py``): one joint program along the
share and orders the route bound finds fastest gives six objects a plan shorter than
sequential transportation's, which ``dm.plan`` verifies and takes in its place; it is not
tried where the exact search is the better tool or where it would not be a plan."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import dualarm_mpc as dm
from dualarm_mpc.milp.horizon import solve_options
from dualarm_mpc.model.mld import in_goal
from dualarm_mpc.model.verify import verify
from dualarm_mpc.planning.guided import guided_plan
from dualarm_mpc.planning.sequential import predict_horizon
from dualarm_mpc.planning.task import _guided, _whole_step

# Six objects, seed 5: sequential transportation's plan takes 32 steps, the route bound 29.
SEQUENTIAL_MAKESPAN = 32


def six_objects(**overrides) -> dm.Scenario:
    return dm.whole_task(dm.load_scenario("table1_vd", {
        "seed": 5, "rule": 1, "delivery": "rest", "random_objects": {"count": 6},
        "solver": {"time_limit_s": 45.0}, **overrides}))


@pytest.fixture(scope="module")
def planned():
    """The route-guided plan as ``dm.plan`` makes it, after the first plan (sequential
    transportation's, joined), before the search (``task._guided``)."""
    scenario = six_objects()
    stop = dm.Interrupt()
    first = dm.plan(scenario, stop=stop, on_first_plan=lambda _: stop.set())
    assert first.segments[0].sequential_steps and first.makespan == SEQUENTIAL_MAKESPAN
    guided = _guided(scenario, first, solve_options(scenario))
    assert guided is not None
    assert guided.first_plan_s == first.first_plan_s  # the time to the first plan stays
    return guided


def test_the_guided_plan_is_shorter_than_sequential_transportation_s(planned) -> None:
    scenario = six_objects()
    (step,) = planned.segments
    assert step.guided and step.sequential_steps is None
    assert planned.verified and verify(scenario, planned).ok
    assert predict_horizon(_whole_step(scenario)) <= planned.makespan < SEQUENTIAL_MAKESPAN
    last = planned.trajectory
    for j, o in enumerate(scenario.task.objects):  # every object at rest in its goal
        assert in_goal(last.object_pos[-1, j], scenario.task.goals[o.goal])
        assert np.allclose(last.object_vel[-1, j], 0.0)
    # its cost is unproven: no bound of the restricted program is the whole task's
    assert step.bound == 0.0 and step.status == "feasible"
    assert dm.Plan.from_json(planned.to_json()).segments[0].guided


@pytest.mark.parametrize("overrides", [{"random_objects": {"count": 5}}, {"rule": 2}])
def test_it_is_not_tried_on_five_objects_or_where_an_object_may_be_thrown(overrides) -> None:
    scenario = six_objects(**overrides)
    problem = _whole_step(scenario)
    assert guided_plan(problem, 40, solve_options(scenario)) is None


def test_it_says_nothing_once_stopped() -> None:
    scenario = six_objects()
    stop = dm.Interrupt()
    stop.set()
    options = dataclasses.replace(solve_options(scenario), interrupt=stop)
    assert guided_plan(_whole_step(scenario), SEQUENTIAL_MAKESPAN, options) is None
