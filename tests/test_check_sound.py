"""The consistency check is sound: it reports a conflict only where the planner's own MILP has no
plan (issue 37). Random user rules of every operator on small scenes whose first step is the
whole task (m_o = n_o = every object), against the monolithic MILP; and the false conflicts the
issue found, each planned and verified."""

from __future__ import annotations

import dataclasses
import functools

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from scenes import two_objects
from strategies import formulas

from dualarm_mpc.logic.ltl import Atom, Formula
from dualarm_mpc.logic.transform import nnf, rename_atoms
from dualarm_mpc.milp.horizon import solve_options, solve_step
from dualarm_mpc.milp.solver import Status
from dualarm_mpc.model.mld import State
from dualarm_mpc.model.scenario import Scenario, apply_overrides
from dualarm_mpc.model.spec import StepProblem, negated_atoms, specification
from dualarm_mpc.model.verify import verify
from dualarm_mpc.planning.consistency import check
from dualarm_mpc.planning.sequential import transport

# Two objects near their goals and the hands: a horizon of 4 delivers both (from T = 3), so every
# MILP below takes milliseconds. "far" puts b's goal beyond the hands' reach: only a throw
# delivers it, which no-throw (18) forbids — a conflict of the paper's own rules.
SMALL = {
    "name": "small", "dt": 1.0, "max_speed": 0.2, "max_force": 0.2,
    "workspace": [-0.5, 0.5, -0.3, 0.6],
    "goals": {"red": [0.1, 0.3, 0.25, 0.45], "blue": [-0.3, -0.1, 0.25, 0.45],
              "far": [-0.3, -0.1, 0.66, 0.8]},
    "solver": {"max_horizon": 4, "time_limit_s": 10, "workers": 1, "threads": 1},
}
A = {"name": "a", "position": [0.1, 0.1], "goal": "red"}
SCENES = {
    "a": [A],
    "a, b": [A, {"name": "b", "position": [-0.1, 0.1], "goal": "blue"}],
    "a, b far": [A, {"name": "b", "position": [-0.1, 0.2], "goal": "far"}],
}


def small(objects: list[dict], **fields) -> Scenario:
    """:data:`SMALL` with ``objects``, their whole task in one step (m_o = n_o = all) unless
    ``fields`` say otherwise."""
    n = len(objects)
    return apply_overrides(Scenario(), {**SMALL, "objects": objects, "m_o": n, "n_o": n, **fields})


# --- random rules --------------------------------------------------------------------------------


@functools.cache  # built once per size: hypothesis validates a strategy on first use
def rules(n: int) -> st.SearchStrategy[Formula]:
    """User rules over ``n`` objects with every operator (``strategies.formulas``): atoms η and θ
    of numbered objects and of placeholders (i the arm; j, and l when there are two objects).
    A θ in negative position is refused (spec.check_rule), so it becomes an η of its object."""
    objects = [*range(1, n + 1), "j", *(["l"] if n > 1 else [])]
    atoms = [Atom("eta", (i, j)) for i in (1, 2, "i") for j in objects]
    atoms += [Atom("theta", (j,)) for j in objects] * 3  # as likely as an η

    def positive_theta(f: Formula) -> Formula:
        return rename_atoms(f, {a: Atom("eta", ("i", *a.index))
                                for a in negated_atoms(nnf(f)) if a.name == "theta"})

    return formulas(atoms, max_leaves=6).map(positive_theta)


def monolithic_statuses(scenario: Scenario) -> list[Status]:
    """The planner's monolithic MILP of the whole task (one step) at the largest horizon, and at
    every horizon when the specification's feasibility is not monotone in T; stopped at its
    first solution."""
    spec = specification(scenario, list(range(scenario.n_objects)))
    cap = scenario.solver.max_horizon
    options = dataclasses.replace(solve_options(scenario), mip_rel_gap=1.0)
    horizons = [cap] if spec.monotone_in_horizon() else range(1, cap + 1)
    return [solve_step(StepProblem(scenario, State.initial(scenario), spec), T, options).status
            for T in horizons]


def _agrees(data, scene: str, rule: int, delivery: str) -> None:
    """A conflict only where the whole task's MILP has no plan at any horizon it is decided at,
    and — the first step being the whole task — a conflict wherever it has none."""
    objects = SCENES[scene]
    user = data.draw(st.lists(rules(len(objects)), min_size=1, max_size=2), label="rules")
    scenario = small(objects, rule=rule, delivery=delivery, rules=[str(f) for f in user])
    report = check(scenario)
    statuses = monolithic_statuses(scenario)
    has_plan = any(s.has_solution for s in statuses)
    event("a plan" if has_plan else "conflict" if report.conflicts else "no conflict found")
    event(f"{len(statuses)} horizon(s)")
    if report.conflicts:
        event("per object" if len(report.conflicts[0].objects) == 1 else "joint")
        assert all(s is Status.INFEASIBLE for s in statuses), (report.conflicts, statuses)
    if has_plan:
        assert report.consistent, (report.conflicts, statuses)
    elif all(s is Status.INFEASIBLE for s in statuses) and not report.undecided:
        assert report.conflicts, statuses


def _examples(n: int):
    """``n`` random cases (scene, rule, delivery, one or two user rules), the same every run."""
    return lambda test: settings(max_examples=n, deadline=None, derandomize=True, database=None,
                                 suppress_health_check=[HealthCheck.too_slow])(given(
        data=st.data(), scene=st.sampled_from(sorted(SCENES)), rule=st.sampled_from([1, 2]),
        delivery=st.sampled_from(["reach", "rest"]))(test))


@pytest.mark.slow  # about 20 s of one core
@_examples(150)
def test_check_agrees_with_the_monolithic_milp(data, scene: str, rule: int, delivery: str) -> None:
    _agrees(data, scene, rule, delivery)


@pytest.mark.falsify  # `make falsify`: about a minute of one core
@_examples(500)
def test_check_agrees_on_500_cases(data, scene: str, rule: int, delivery: str) -> None:
    _agrees(data, scene, rule, delivery)


# --- the false conflicts of issue 37 -------------------------------------------------------------

SATISFIABLE = [
    "F eta[1,1]",
    "G F eta[1,1]",
    "F theta[1]",  # implied by the task
    "(!eta[1,1] & !eta[2,1]) U theta[2]",  # object 1 waits until object 2 is in its goal
    "theta[2] R (!eta[1,1] & !eta[2,1])",  # the same, weak
    "F theta[1] | G eta[1,2] | G eta[2,2] | G (eta[1,1] & eta[2,1])",
]


@pytest.mark.parametrize("rule", SATISFIABLE)
def test_a_rule_about_another_object_is_no_conflict(rule: str) -> None:
    """Each object's own program once read the other object's atoms as constants (η false, θ
    where it stands), which made these rules false there: a conflict for a task with a plan."""
    scenario = two_objects(rules=[rule], solver={"time_limit_s": 10, "max_horizon": 15})
    report = check(scenario)
    assert report.consistent and not report.undecided, report.conflicts
    p = transport(scenario)
    verdict = verify(scenario, p)
    assert verdict.ok, verdict.problems


def test_an_object_a_later_step_delivers_is_checked_from_anywhere() -> None:
    """b is out of reach within 4 steps from where the hands start, but the step that delivers
    a first (n_o = 1) leaves a hand near b: the sequential plan delivers both. b's own program
    lets the hands start anywhere, as a later step may."""
    scenario = small([A, {"name": "b", "position": [0.4, 0.55], "goal": "reach"}], m_o=1, n_o=1,
                     rule=1, goals={"red": [0.15, 0.35, 0.3, 0.5], "reach": [0.4, 0.6, 0.65, 0.8]},
                     workspace=[-0.5, 0.6, -0.3, 0.8])
    report = check(scenario)
    assert report.consistent and not report.undecided, report.conflicts
    p = transport(scenario)
    assert len(p.segments) == 2
    verdict = verify(scenario, p)
    assert verdict.ok, verdict.problems
