"""Tests for planning.consistency: a task that conflicts with the rules or the bounds is named
before planning — which objects, a minimal set of rules, and why in plain words — and a task
that has a plan passes."""

from __future__ import annotations

import pytest
from scenes import TWO_OBJECTS

from dualarm_mpc.model.scenario import load_scenario
from dualarm_mpc.planning.consistency import Conflict, check, grouped


@pytest.fixture
def two(scenario_file):
    """The shared two-object scene (rule 2, both objects in one step), from a file."""
    path = scenario_file(TWO_OBJECTS, solver={"time_limit_s": 10, "max_horizon": 15})
    return lambda **over: load_scenario(path, over)


@pytest.fixture(scope="module")
def vc_rule1():
    return check(load_scenario("table1_vc", {"rule": 1}), joint=False)


@pytest.mark.slow  # ten infeasibility proofs
def test_table1_vc_rule_1_names_no_throw_for_every_object(vc_rule1) -> None:
    """§V-C's goals lie beyond the hands' reach: only a throw delivers, which rule 1 forbids."""
    assert not vc_rule1.consistent
    assert len(vc_rule1.conflicts) == 10
    for c in vc_rule1.conflicts:
        assert c.rules == ("no-throw (18)",)
        # the hand range plan.png draws, and where a held object's centre can go
        assert "beyond the hands' reach (hands y ≤ 0.9, a held object's centre y ≤ 0.95)" \
            in c.reason
        assert "forbids releasing it outside its goal" in c.reason
        assert c.reason.startswith(f"{c.objects[0]} → ")
        assert c.reason.endswith(f": {c.why}")
    # one finding, not ten near-identical lines (issue 51)
    assert grouped(vc_rule1.conflicts) == [f"objects 1–10: {vc_rule1.conflicts[0].why}"]


@pytest.mark.parametrize(("names", "said"), [
    (["object1", "object2", "object3", "object5"], "objects 1–3, 5"),
    (["object7", "object8"], "objects 7, 8"),
    (["box 2", "box 4"], "box 2, box 4"),
    (["a", "object2"], "a, object2"),
])
def test_conflicts_alike_are_one_line_naming_their_objects(names, said) -> None:
    alike = [Conflict((n,), ("no-throw (18)",), f"{n} → red: why", "why") for n in names]
    other = Conflict(("x",), (), "x → red: another reason", "another reason")
    assert grouped([*alike, other]) == [f"{said}: why", "x → red: another reason"]


def test_table1_vc_rule_2_is_consistent() -> None:
    report = check(load_scenario("table1_vc", {"rule": 2}), joint=False)
    assert report.consistent and not report.undecided


def test_a_rule_keeping_both_hands_off_one_object_is_named(two) -> None:
    """Only the object the rule is about conflicts; the paper's rules are not in the set."""
    report = check(two(rules=["G !eta[1,2] & G !eta[2,2]"]), joint=False)
    assert [c.objects for c in report.conflicts] == [("object2",)]
    (conflict,) = report.conflicts
    assert conflict.rules == ("rules[0] G !eta[1,2] & G !eta[2,2]",)
    assert "never let a hand hold it" in conflict.reason


def test_the_bounds_alone_are_named_when_no_rule_is_to_blame(two) -> None:
    """Fast enough on paper (0.1 m/s for 8 steps), but |u| ≤ 0.005 cannot get a hand there."""
    report = check(two(max_speed=0.1, max_force=0.005, solver={"max_horizon": 8}), joint=False)
    assert {c.objects for c in report.conflicts} == {("object1",), ("object2",)}
    for c in report.conflicts:
        assert c.rules == ()
        assert "max_speed" in c.reason and "max_horizon" in c.reason


def test_objects_that_conflict_only_together_show_in_the_joint_check(two) -> None:
    """The left arm never holds anything, and a hand that held one object never holds
    another: each object alone has a plan (by the right arm), both together have none."""
    rules = ["G !eta[2,j]", "G(eta[i,j] -> G !eta[i,l])"]
    alone = check(two(rules=rules), joint=False)
    assert alone.consistent
    report = check(two(rules=rules))
    (conflict,) = report.conflicts
    assert set(conflict.objects) == {"object1", "object2"}
    assert set(conflict.rules) == {f"rules[{n}] {r}" for n, r in enumerate(rules)}
    assert "each one alone has a plan" in conflict.reason


def test_a_consistent_task_passes_the_joint_check(two) -> None:
    report = check(two())
    assert report.consistent and not report.undecided


def test_the_check_says_how_many_objects_it_has_checked(two) -> None:
    """The command line's progress line of a long check counts the objects done."""
    said: list[tuple[int, int]] = []
    check(two(), joint=False, progress=lambda done, total: said.append((done, total)))
    assert sorted(said) == [(1, 2), (2, 2)]


def test_a_rule_not_monotone_in_the_horizon_is_decided_at_every_horizon(two) -> None:
    """``G(eta[1,2] -> WX !eta[1,2])`` (hold object 2 one step at most) does not survive
    idling: the largest horizon alone would not decide it. Object 2 still has a plan (a
    throw), found at some horizon."""
    report = check(two(rules=["G(eta[1,2] -> WX !eta[1,2])"]), joint=False)
    assert report.consistent and not report.undecided


def test_a_rule_about_an_object_outside_the_first_step_is_no_conflict(two) -> None:
    """With n_o = 1 the first step holds object1 alone, and ``F eta[1,2]`` is about object2.
    The encoder reads the atoms of an object outside its program as constants (η false): the
    check drops such an instance, in each object's program and in the first step's, since a
    program holding object2 can satisfy it."""
    report = check(two(m_o=1, n_o=1, rules=["F eta[1,2]"]))
    assert report.consistent and not report.undecided


@pytest.mark.parametrize("rule", ["X[50] true", "F[0:2] theta[1]", "last"])
def test_a_rule_that_cannot_hold_within_the_horizon_cap_says_so(two, rule) -> None:
    """The proof used the rule alone (no task) at every horizon up to the cap: the reason names
    the rule and solver.max_horizon, not "never let a hand hold it" (issue 52)."""
    report = check(two(rules=[rule]), joint=False)
    assert report.conflicts
    for c in report.conflicts:
        assert c.rules == (f"rules[0] {rule}",)
        assert f"rules[0] {rule} cannot hold at any horizon within solver.max_horizon = 15 " \
            "steps" in c.reason and "whatever the task" in c.reason, c.reason


def test_check_and_plan_print_the_same_reason_for_a_rule_beyond_the_cap(scenario_file,
                                                                        capsys) -> None:
    from dualarm_mpc.cli.app import main

    path = str(scenario_file(TWO_OBJECTS, solver={"time_limit_s": 10, "max_horizon": 15},
                             rules=["X[50] true"]))
    lines = {}
    for command in ("check", "plan"):
        capsys.readouterr()
        assert main([command, path]) == 3
        out = capsys.readouterr()
        lines[command] = [line for line in (out.out + out.err).splitlines()
                          if line.startswith("conflict:")]
    assert lines["check"] == lines["plan"]
    assert "solver.max_horizon = 15" in lines["check"][0]


def test_a_proven_conflict_says_what_was_proven_when_the_rest_is_undecided(two) -> None:
    """Every horizon proven to have no plan, the why not decided (here: no time at all) was
    "the solver could not decide the task alone", as if nothing had been proven (issue 52)."""
    import dataclasses

    from dualarm_mpc.milp.horizon import solve_options
    from dualarm_mpc.milp.solver import Interrupt
    from dualarm_mpc.model.mld import State
    from dualarm_mpc.model.spec import StepProblem, specification
    from dualarm_mpc.planning.sequential import diagnose

    scenario = two()
    stop = Interrupt()
    stop.set()
    options = dataclasses.replace(solve_options(scenario), interrupt=stop)
    problem = StepProblem(scenario, State.initial(scenario), specification(scenario, [0, 1]))
    said = diagnose(problem, None, options, proven=True)
    assert said == ("no plan delivering 2 of ['object1', 'object2'] within solver.max_horizon "
                    "= 15, proven for every horizon; whether the task alone or the rules cause "
                    "it was not decided within the time limit (solver.time_limit_s)")
