"""The consistency check: do the task, the rules and the bounds admit a plan at all?

Rules are common sense kept across tasks (§I-B), so a rule that cannot hold together with a new
task must be caught before the robot moves, and named. Each object is checked on its own: a
one-object step — deliver it, under every rule instance over that object alone — at the largest
horizon; then the first sequential step as a whole. These programs carry
no cost: HiGHS stops at the first solution (tens of milliseconds), and only a conflict takes an
infeasibility proof (about a second).

A conflict is reported only with a proof: every program whose infeasibility is reported is a
*relaxation* of the real one — the sequential step that would deliver the objects named, at
some horizon up to ``solver.max_horizon`` — it may drop constraints, never add one:

* **One object j** (:func:`!_check_object`): the model over the hands and j alone, whose rows are
  the real step's rows over these variables (other objects enter the model only through the sums
  of (14)–(15), which fewer objects only loosen); φ_task "j delivered", which every step
  delivering j implies; and the rule instances whose atoms all name j
  (:func:`~dualarm_mpc.model.spec.confined`). An instance naming another object is dropped, never
  handed to the encoder, which would read that object's atoms as constants (η false, θ its value
  now) — an instance such as ``F eta[1,1]`` or ``F theta[1] | …`` would then be false in object 2's
  program although a step over both can satisfy it. A plan of the real step, cut down to the hands
  and j, is a plan of this program. If the first step delivers j (m_o covers every object of the
  step), the program starts from this state; otherwise a later step may deliver j, with the hands
  starting wherever the steps before left them (at rest, as the hands are now): the program lets
  them start anywhere in their range (``hands_anywhere``), so it relaxes every such step too. What
  it does not model is an earlier step that moves j without delivering it (possible when m_o < n_o):
  j starts where it is now.
* **Who holds it** (:func:`!_cases`): the one-object program is solved as three restrictions —
  hand 2 never holds j after now, hand 1 never does, both do at some time — whose plans together
  are exactly its plans; it is infeasible when all three are.
* **Horizons** (:func:`!_feasible`): where feasibility is monotone in T for the program itself
  (:meth:`~dualarm_mpc.model.spec.Specification.monotone_in_horizon`, on the relaxed rules), the
  largest horizon decides every smaller one; otherwise every horizon from 1 up is tried, each
  against the real step at the same horizon.
* **The minimal rule set** (:func:`!_minimal`, a deletion filter): each program it solves is the
  same program with fewer rules, hence a relaxation too, and the set it keeps is one proven
  infeasible: drop any one of its rules and the relaxed program has a plan.
* **"Never held"** (the message only): the same program with the rules of the minimal set, no
  task and "a hand holds j at some time" added; infeasible, it proves those rules forbid every
  grasp of j in every step that holds j.
* **The first step** (joint check): Algorithm 1's first step, its objects and m_o, with the rule
  instances naming objects outside it dropped as above (a later step may hold those objects).
  Objects that conflict only together (a rule over two objects, two objects for one small goal)
  show here.

The objects' spacing (``object_clearance``, (C1)–(C3)) is left out of every program: one object
with the others standing where they are now would not be a relaxation (a step may move them out
of its way first).

For an object no plan can deliver, :func:`!_reason` says why in plain words: the geometry (a goal
beyond the hands' reach) and what each rule of the minimal set forbids.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from dualarm_mpc.logic.ltl import TRUE, And, Eventually, Formula, Or, eta
from dualarm_mpc.milp.horizon import HorizonProgram, solve_options
from dualarm_mpc.milp.solver import SizeLimit, SolveOptions, Status
from dualarm_mpc.model.mld import Rect, State, delivered_objects, target_box
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.model.spec import (
    Specification,
    StepProblem,
    confined,
    rule_formulas,
    specification,
)
from dualarm_mpc.planning.sequential import select_objects, within_cap

JOINT_TIME_LIMIT_S = 20.0  # for the first step's program; beyond, "undecided"

# What each of the paper's rules forbids, in the words of the conflict report.
FORBIDS = {
    "no-throw (18)": "forbids releasing it outside its goal",
    "no-juggle (19)": "forbids passing it from one hand to the other",
    "no-swap (20)": "forbids a hand taking another object right after it",
}


@dataclass(frozen=True)
class Conflict:
    """Rules (a minimal set; none: the bounds alone) under which ``objects`` cannot be
    delivered, and why: ``reason`` whole, ``why`` without the object's name and goal (equal
    for objects that conflict alike, which :func:`grouped` prints as one line)."""

    objects: tuple[str, ...]
    rules: tuple[str, ...]
    reason: str
    why: str = ""

    def __str__(self) -> str:
        return self.reason


def grouped(conflicts: tuple[Conflict, ...] | list[Conflict]) -> list[str]:
    """One line per group of conflicts with the same rules and the same ``why``, in the order
    of their first: ``"objects 1–10: the goal lies beyond …"``; a group of one is its
    ``reason``."""
    groups: dict[tuple, list[Conflict]] = {}
    for c in conflicts:
        groups.setdefault((c.rules, c.why or c.reason), []).append(c)
    return [members[0].reason if len(members) == 1 else
            f"{_names([o for c in members for o in c.objects])}: {why}"
            for (_, why), members in groups.items()]


def _names(names: list[str]) -> str:
    """``objects 1–3, 5`` where every name is ``object`` and a number (the built-in scenes'),
    else the names."""
    split = [re.fullmatch(r"object(\d+)", n) for n in names]
    if not all(split):
        return ", ".join(names)
    numbers = sorted({int(m[1]) for m in split})
    runs: list[list[int]] = []
    for k in numbers:
        if runs and runs[-1][-1] == k - 1:
            runs[-1].append(k)
        else:
            runs.append([k])
    listed = ", ".join(f"{r[0]}–{r[-1]}" if len(r) > 2 else ", ".join(map(str, r)) for r in runs)
    return f"objects {listed}"


@dataclass(frozen=True)
class Report:
    conflicts: tuple[Conflict, ...]
    undecided: tuple[str, ...]  # what the solver could not decide within its time limit
    horizon: int  # the largest horizon, at which everything was decided

    @property
    def consistent(self) -> bool:
        return not self.conflicts


def check(scenario: Scenario, state: State | None = None, joint: bool = True,
          options: SolveOptions | None = None,
          progress: Callable[[int, int], None] | None = None) -> Report:
    """Check every object not yet resting in its goal on its own (in parallel, on
    ``solver.workers`` threads), then — if they all pass and ``joint`` — the first sequential
    step as a whole. ``progress(done, total)`` is called as each object's check ends (from the
    worker threads), so that a long check can say how far it is. ``scenario`` is checked first
    as ``load_scenario`` checks it (:meth:`~dualarm_mpc.model.scenario.Scenario.validate`)."""
    scenario.validate()
    state = State.initial(scenario) if state is None else state
    options = options or solve_options(scenario)
    T = scenario.solver.max_horizon
    named = rule_formulas(scenario)
    done = delivered_objects(scenario, state.object_pos, state.object_vel)
    todo = [int(j) for j in np.flatnonzero(~done)]
    first = select_objects(scenario, state, todo)
    # Objects the first step delivers from this state; any other may be delivered by a later
    # step, whose hands start elsewhere.
    now = set(first) if min(scenario.task.m_o, len(first)) == len(first) else set()
    done = itertools.count(1)

    def one(j: int) -> Conflict | Status:
        verdict = _check_object(scenario, state, j, named, options, anywhere=j not in now)
        if progress is not None:
            progress(next(done), len(todo))  # next() on a count is atomic under the GIL
        return verdict

    with ThreadPoolExecutor(scenario.solver.workers) as pool, _named("one-object programs", T):
        verdicts = list(pool.map(one, todo))
    conflicts = tuple(v for v in verdicts if isinstance(v, Conflict))
    undecided = tuple(scenario.task.objects[j].name for j, v in zip(todo, verdicts, strict=True)
                      if v is Status.TIME_LIMIT)
    if joint and todo and not conflicts and not undecided:
        spec = confined(specification(scenario, first, rules=named))
        problem = StepProblem(scenario, state, spec)
        quick = dataclasses.replace(options, time_limit_s=min(options.time_limit_s,
                                                              JOINT_TIME_LIMIT_S))
        names = tuple(scenario.task.objects[j].name for j in first)
        with _named("first step's program", T):
            status = _feasible(problem, quick)
            if status is Status.INFEASIBLE:
                conflicts = (_joint_conflict(problem, names, quick),)
        if status is Status.TIME_LIMIT:
            undecided = (f"the first step ({', '.join(names)})",)
    return Report(conflicts, undecided, T)


@contextmanager
def _named(program: str, T: int) -> Iterator[None]:
    """A solver's size limit met in the block names the check's program and what sizes it."""
    try:
        yield
    except SizeLimit as err:
        raise SizeLimit(f"the consistency check's {program} (horizons up to solver.max_horizon "
                        f"= {T}): {err}; a smaller solver.max_horizon makes them smaller") from None


def _feasible(problem: StepProblem, options: SolveOptions, anywhere: bool = False) -> Status:
    """Whether ``problem.spec`` has a plan within the largest horizon, decided by its MILPs
    without cost (the first solution ends a search): FEASIBLE, INFEASIBLE or TIME_LIMIT. The
    largest horizon alone decides when feasibility is monotone in T; otherwise every horizon is
    tried. ``anywhere``: from every start of the hands in their range (``problem.state``'s
    velocities)."""
    scenario, state, spec = problem.scenario, problem.state, problem.spec
    cap = scenario.solver.max_horizon
    undecided = False
    for T in [cap] if spec.monotone_in_horizon() else range(1, cap + 1):
        program = HorizonProgram(scenario, state, list(spec.objects), T, hands_anywhere=anywhere,
                                 apart=False)
        for case, allowed in _cases(spec):
            res = program.solve(case, options, hands=(), allowed=allowed)
            if res.status.has_solution:
                return Status.FEASIBLE
            undecided |= res.status is not Status.INFEASIBLE
    return Status.TIME_LIMIT if undecided else Status.INFEASIBLE


def _cases(spec: Specification) -> list[tuple[Specification, np.ndarray | None]]:
    """A one-object program split by who holds the object: hand 1 alone (or neither), hand 2
    alone, both at some time (a hand-over). Every plan is in one of them (``allowed`` bounds η
    from step 1 on; the grasp now is fixed in all three), and each proves infeasible much faster
    than the whole (§V-C, rule 1, T = 40: 0.04, 0.04 and 0.07 s of CPU against 0.84 s). Steps of
    several objects stay whole."""
    if len(spec.objects) != 1:
        return [(spec, None)]
    j = spec.objects[0] + 1
    both = dataclasses.replace(spec, rules=spec.rules + (
        ("both hands hold it", And((Eventually(eta(1, j)), Eventually(eta(2, j))))),))
    return [(spec, np.array([[True], [False]])), (spec, np.array([[False], [True]])),
            (both, None)]


def _minimal(problem: StepProblem, options: SolveOptions, anywhere: bool = False
             ) -> Specification:
    """``problem.spec``, proven infeasible, with a minimal set of its rules that keeps it so (a
    deletion filter: a rule stays only if dropping it makes a plan). Rules without an instance
    here are dropped at once: they constrain nothing."""
    spec = problem.spec
    needed = [r for r in spec.rules if r[1] != TRUE]
    for rule in list(needed):
        rest = tuple(r for r in needed if r is not rule)
        fewer = problem.with_spec(dataclasses.replace(spec, rules=rest))
        if _feasible(fewer, options, anywhere) is Status.INFEASIBLE:
            needed = list(rest)
    return dataclasses.replace(spec, rules=tuple(needed))


def _check_object(scenario: Scenario, state: State, j: int, named: list[tuple[str, Formula]],
                  options: SolveOptions, anywhere: bool) -> Conflict | Status:
    """Object j on its own (``anywhere``: with the hands starting anywhere): FEASIBLE,
    TIME_LIMIT, or the conflict with a minimal rule set."""
    spec = confined(specification(scenario, [j], m_o=1, rules=named))
    problem = StepProblem(scenario, state, spec)
    status = _feasible(problem, options, anywhere)
    if status is not Status.INFEASIBLE:
        return status
    needed = _minimal(problem, options, anywhere)
    # What the proof used: the rules alone (no task, m_o = 0) within the cap, or the rules
    # against every grasp of j, or the rules with the task.
    alone = dataclasses.replace(needed, m_o=0, targets=())
    held = dataclasses.replace(alone, rules=alone.rules + (
        ("held", Eventually(Or((eta(1, j + 1), eta(2, j + 1))))),))
    cause = next((c for c, spec in (("alone", alone), ("never held", held)) if needed.rules and
                  _feasible(problem.with_spec(spec), options, anywhere) is Status.INFEASIBLE),
                 "")
    names = tuple(name for name, _ in needed.rules)
    return Conflict((scenario.task.objects[j].name,), names,
                    _reason(scenario, j, names, cause), _why(scenario, j, names, cause))


def _reason(scenario: Scenario, j: int, rules: tuple[str, ...], cause: str) -> str:
    """Why object j cannot be delivered, in plain words."""
    obj = scenario.task.objects[j]
    return f"{obj.name} → {obj.goal}: " + _why(scenario, j, rules, cause)


def _why(scenario: Scenario, j: int, rules: tuple[str, ...], cause: str) -> str:
    """:func:`!_reason` without the object's name and goal. ``cause``: "alone" where the rules
    have no plan without the task, "never held" where they forbid every grasp of j, else ""."""
    robot = scenario.robot
    bounds = (f"steps of {robot.dt} s with |v| ≤ {robot.max_speed} and |u| ≤ {robot.max_force}")
    if not rules:
        return (f"no plan brings it into its goal {within_cap(scenario)} {bounds} (dt, "
                "max_speed, max_force)")
    listed = " and ".join(rules)
    if cause == "alone":
        return (f"{listed} cannot hold at any horizon {within_cap(scenario)} {bounds}, whatever "
                "the task (a rule that needs more steps needs a larger solver.max_horizon)")
    if cause == "never held":
        return f"{listed} never let a hand hold it, and it is not in its goal"
    beyond = _beyond_reach(scenario, j)
    what = [FORBIDS.get(name, f"({name.split(' ', 1)[-1]})") for name in rules]
    why = " and ".join(f"{name} {w}" if name in FORBIDS else name for name, w in
                       zip(rules, what, strict=True))
    if beyond:
        return f"the goal lies beyond the hands' reach ({beyond}) and {why}"
    return f"delivering it conflicts with {why}"


def _beyond_reach(scenario: Scenario, j: int) -> str:
    """The bounds that keep a held object j out of its goal, the hand range's (plan.png draws
    it) and a held object's centre's (``"hands y ≤ 0.9, a held object's centre y ≤ 0.95"``),
    or ""."""
    ws = Rect.of(scenario.robot.workspace)
    half = scenario.task.objects[j].grasp_half_size
    goal = target_box(scenario, j)
    for axis, name in enumerate("xy"):
        if goal.lo[axis] > ws.hi[axis] + half:
            edge, op, held = ws.hi[axis], "≤", ws.hi[axis] + half
        elif goal.hi[axis] < ws.lo[axis] - half:
            edge, op, held = ws.lo[axis], "≥", ws.lo[axis] - half
        else:
            continue
        return f"hands {name} {op} {edge:.3g}, a held object's centre {name} {op} {held:.3g}"
    return ""


def _joint_conflict(problem: StepProblem, names: tuple[str, ...], options: SolveOptions
                    ) -> Conflict:
    """The first step has no plan although each object has one: a minimal set of its rules."""
    scenario, spec = problem.scenario, problem.spec
    rules = tuple(name for name, _ in _minimal(problem, options).rules)
    said = " and ".join(rules) if rules else "the bounds alone"
    return Conflict(names, rules, f"{spec.m_o} of {', '.join(names)}: no plan delivers them "
                    f"together {within_cap(scenario)} under {said}, though each one alone has "
                    "a plan")
