"""A task's plan as the library gives it: the consistency check, sequential transportation
(Algorithm 1) and the verification every plan passes, in one call (``dualarm_mpc.plan``; the
``plan`` command prints what this returns)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from dualarm_mpc.milp.horizon import StepResult, solve_options
from dualarm_mpc.milp.solver import Interrupt, SolveOptions, Status
from dualarm_mpc.model import band, motion
from dualarm_mpc.model.mld import Model, State
from dualarm_mpc.model.plan import Plan, Segment, relative_gap
from dualarm_mpc.model.scenario import MAX_STEP_DELIVERIES, Scenario, ScenarioError
from dualarm_mpc.model.spec import StepProblem, specification
from dualarm_mpc.model.verify import verify
from dualarm_mpc.planning.consistency import Report, check
from dualarm_mpc.planning.guided import guided_plan
from dualarm_mpc.planning.sequential import (
    HorizonTried,
    KeptSteps,
    PlanningError,
    one_step,
    predict_horizon,
    transport,
    unproven,
)
from dualarm_mpc.planning.shorten import shortened

__all__ = ["ConflictError", "VerificationError", "first_pass", "plan", "whole_task"]

# (m_o, n_o) of the sequential transportation whose plan, joined into one step, is the whole
# task's first (``plan --mo all``): Table II's first row, the quickest.
FIRST_PASS = (2, 5)
# ... and of the one tried next, under no-throw (18), on whole tasks of ``LARGER_STEPS_FROM``
# objects or more, past what the search (five) and the route-guided plan (six) reach in a run's
# budget: steps of four, each a whole task the search proves in seconds. On §V-D's ten objects
# its plan is 0–4 Δt shorter than FIRST_PASS's on every seed, in 11–39 s; steps of three or
# five are longer (docs/search.md, "The anytime plan"). Under rule 2 its steps' searches take
# the run's budget and give no shorter plan.
LARGER_STEPS = (4, 4)
LARGER_STEPS_FROM = 7


class ConflictError(PlanningError):
    """The consistency check proved that the task, the rules and the bounds admit no plan;
    ``report.conflicts`` names each conflict (which objects, which rules, why)."""

    def __init__(self, report: Report) -> None:
        super().__init__("; ".join(map(str, report.conflicts)), proven=True)
        self.report = report


class VerificationError(PlanningError):
    """The plan, replayed through the model, breaks its specification: ``problems`` say where.
    ``plan`` is the plan itself (``verified`` false), kept for inspection."""

    def __init__(self, plan: Plan, problems: list[str]) -> None:
        super().__init__("the plan fails verification: " + "; ".join(problems), plan)
        self.plan = plan
        self.problems = problems


def whole_task(scenario: Scenario) -> Scenario:
    """``scenario`` planned as one task (``plan --mo all``): m_o = n_o = its number of objects,
    so φ_task (13) asks for every object and Algorithm 1's first step is one search over all of
    them, exact as every step (minimal horizon, then minimal cost at it, eq. 17); its
    certificate (``Segment.bound``, ``gap``, ``horizon_proven_minimal``) is then the whole
    plan's. Under delivery ``reach`` an object may pass through its goal without resting
    there, and a second step delivers it. More objects than a step may deliver
    (``MAX_STEP_DELIVERIES``, docs/scenarios.md "Caps") is a :class:`ScenarioError`."""
    n = scenario.n_objects
    if n > MAX_STEP_DELIVERIES:
        raise ScenarioError(f"--mo all (the whole task in one step): {n} objects, more than one "
                            f"step may deliver (m_o at most {MAX_STEP_DELIVERIES}); plan it in "
                            f"steps of at most {MAX_STEP_DELIVERIES}")
    whole = dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, m_o=n, n_o=n))
    whole.validate()
    return whole


def plan(scenario: Scenario, *, check_first: bool = True,
         progress: Callable[[Segment], None] | None = None,
         on_try: Callable[[HorizonTried], None] | None = None,
         stop: Interrupt | None = None,
         on_first_plan: Callable[[Plan], None] | None = None,
         on_shorter_plan: Callable[[Plan], None] | None = None) -> Plan:
    """Plan every object of ``scenario`` into its goal and verify the plan (re-simulated through
    the model, each step's LTL checked by the independent evaluator).

    An anytime plan: a complete verified plan first, then the search that may better it.
    Of the whole task (:func:`whole_task`), the first is sequential transportation's at
    ``FIRST_PASS``, joined into one step (:meth:`~dualarm_mpc.model.plan.Plan.as_one_step`), or
    the route-guided plan (:mod:`~dualarm_mpc.planning.guided`) or sequential transportation at
    ``LARGER_STEPS``, joined, where that is shorter, then re-timed where steps come out of it
    (:mod:`~dualarm_mpc.planning.shorten`), and the whole-task search's plan replaces it where
    it is proven (optimal at a proven-minimal horizon), or its makespan is shorter, or as short
    and cheaper; at the first plan's horizon the search starts from it (its incumbent), and
    where it betters nothing the first plan stays, with the search's certificate. Within it,
    and for every
    other task, where the rules allow throws the first is each step's no-throw witness, then
    Algorithm 1 by the horizon policy, which takes every search of the first pass it meets
    again, and the cheaper complete plan is returned. Where neither applies (rule 1, or no
    witness in reach) Algorithm 1 is the one pass.

    ``check_first``: run the consistency check (without its joint step) first and raise
    :class:`ConflictError` on a conflict. ``progress`` hears of each sequential step of each
    pass, ``on_try`` of each horizon tried, ``on_first_plan`` of the first verified plan when a
    search follows it, ``on_shorter_plan`` of a whole task's route-guided plan, plan in
    ``LARGER_STEPS`` or re-timed plan where it takes the first plan's place, before the search.
    ``stop``, once set (from another thread), ends the search: the best complete plan so far,
    or else the steps planned so far as a partial plan (``partial``), not verified.

    Raises :class:`~dualarm_mpc.planning.sequential.PlanningError` when a step has no plan
    (``proven``: none exists up to the horizon cap) and no complete plan exists,
    :class:`VerificationError` when a plan fails verification. Returns the plan with
    ``verified`` true otherwise, and its ``first_plan_s``: the wall seconds from the start of
    planning (after the check) until the first complete plan passed verification.
    ``scenario`` is checked first as ``load_scenario`` checks it
    (:meth:`~dualarm_mpc.model.scenario.Scenario.validate`)."""
    scenario.validate()
    if check_first:
        report = check(scenario, joint=False)
        if report.conflicts:
            raise ConflictError(report)
    options = solve_options(scenario)
    if stop is not None:
        options = dataclasses.replace(options, interrupt=stop)
    t0 = time.perf_counter()
    first = _sequential_first(scenario, options, progress, on_try, on_first_plan, t0)
    if first is None:
        return _passes(scenario, options, progress, on_try, on_first_plan, t0)
    spent, bettered = first.total_solve_time_s, False
    for better in (_guided, _in_larger_steps, _shortened):
        if options.stopped():
            break
        t1 = time.perf_counter()
        found = better(scenario, first, options)
        spent += time.perf_counter() - t1
        if found is not None:
            first, bettered = found, True
    if on_shorter_plan and bettered:
        on_shorter_plan(first)
    # No horizon past the first plan's can better it: the search's cap is that horizon, and a
    # proof that none up to it has a plan contradicts the first plan.
    capped = dataclasses.replace(scenario, solver=dataclasses.replace(
        scenario.solver, max_horizon=first.makespan))
    horizons = _Horizons(capped, options, on_try)
    if options.stopped():
        return _motion_bounded(scenario, horizons.certify(first))
    try:
        whole = _passes(capped, options, progress, horizons, None, t0, known=first)
    except PlanningError as err:
        if isinstance(err, VerificationError) or err.proven:
            raise  # a defect, or a proof that contradicts the first plan: never hidden
        whole = None  # out of time: the first plan stands
    # The search's plan where it answers the task as posed (every step optimal at a proven
    # minimal horizon; under delivery ``reach`` a step of rests may follow the whole step and
    # make it longer) or is no worse by the whole task's order: makespan, then cost (eq. 17).
    better = whole is not None and not whole.partial and (
        (whole.horizon_proven_minimal and all(s.proven_optimal for s in whole.segments))
        or (whole.makespan, whole.total_cost) <= (first.makespan, first.total_cost))
    best = _origin(whole, first) if better else horizons.certify(first)
    spent += 0.0 if whole is None else whole.total_solve_time_s
    return dataclasses.replace(_motion_bounded(scenario, best), first_plan_s=first.first_plan_s,
                               unused_solve_time_s=max(0.0, spent - sum(
                                   s.solve_time_s for s in best.segments)))


def _guided(scenario: Scenario, first: Plan, options: SolveOptions) -> Plan | None:
    """The whole task's route-guided plan (``planning/guided.py``) where it is shorter than
    ``first``, verified, with ``first``'s ``first_plan_s``; None where there is none."""
    problem = _whole_step(scenario)
    t0, cpu0 = time.perf_counter(), time.process_time()
    found = guided_plan(problem, first.makespan, options)
    if found is None:
        return None
    return _whole_plan(scenario, problem, found, time.perf_counter() - t0,
                       time.process_time() - cpu0, first, guided=True)


def _in_larger_steps(scenario: Scenario, first: Plan, options: SolveOptions) -> Plan | None:
    """Sequential transportation at ``LARGER_STEPS``, joined into one step and verified as the
    whole task's plan, where it betters ``first`` by the whole task's order (makespan, then
    cost), with ``first``'s ``first_plan_s``; None where it does not, is not tried (fewer than
    ``LARGER_STEPS_FROM`` objects, or one that may be thrown), or is stopped."""
    steps = _in_steps(scenario, LARGER_STEPS)
    if steps is None or scenario.n_objects < LARGER_STEPS_FROM \
            or not _whole_step(scenario).spec.no_throw_for_all():
        return None
    try:
        found = _passes(steps, options, None, None, None, time.perf_counter())
    except VerificationError:
        raise  # a defect, never hidden
    except PlanningError:
        return None  # out of time, or stopped: the first plan stands
    one = None if found.partial else _joined(scenario, steps, found)
    if one is None or (one.makespan, one.total_cost) >= (first.makespan, first.total_cost):
        return None
    return dataclasses.replace(one, first_plan_s=first.first_plan_s)


def _shortened(scenario: Scenario, first: Plan, options: SolveOptions) -> Plan | None:
    """``first``, the whole task's first plan, made shorter by re-timing its hands
    (``planning/shorten.py``) and verified, with ``first``'s marks, ``first_plan_s`` and
    solve time added to; None where no step could be taken out."""
    problem = _whole_step(scenario)
    t0, cpu0 = time.perf_counter(), time.process_time()
    found = shortened(problem, first.trajectory.grasp, options)
    if found is None:
        return None
    res, taken = found
    (own,) = first.segments
    return _whole_plan(scenario, problem, res, own.solve_time_s + time.perf_counter() - t0,
                       own.cpu_time_s + time.process_time() - cpu0, first,
                       **{**_marks(own), "shortened": taken})


def _whole_plan(scenario: Scenario, problem: StepProblem, found: StepResult, wall_s: float,
                cpu_s: float, first: Plan, **marks) -> Plan:
    """``found``, a plan of the whole step ``problem`` made outside the search, as the whole
    task's plan: its cost unproven, ``marks`` on its step (:func:`_marks`), verified, with
    ``first``'s ``first_plan_s``."""
    plan = one_step(problem, unproven(found), wall_s, cpu_s)
    plan = dataclasses.replace(plan, segments=[dataclasses.replace(plan.segments[0], **marks)])
    return _verified(scenario, plan, first.first_plan_s)


def _marks(step: Segment) -> dict:
    """Where a whole-task step's plan came from, as ``Segment`` fields: joined sequential
    steps, the route-guided plan, steps taken out."""
    return {"guided": step.guided, "sequential_steps": step.sequential_steps,
            "sequential_row": step.sequential_row, "shortened": step.shortened}


def _joined(scenario: Scenario, steps: Scenario, found: Plan) -> Plan | None:
    """``found``, a complete plan of ``steps`` (the whole task ``scenario`` in sequential
    steps), joined into one step and verified as the whole task's plan; None where the joined
    steps break a rule of the whole task."""
    one = found.as_one_step((steps.task.m_o, steps.task.n_o))
    return dataclasses.replace(one, verified=True) if verify(scenario, one).ok else None


def _origin(whole: Plan, first: Plan) -> Plan:
    """The search's plan ``whole``, marked as ``first`` where it is ``first`` itself: the
    search's incumbent at its horizon (:func:`_incumbent`), bettered by nothing, whose
    certificate the search gave."""
    if whole.makespan != first.makespan or len(whole.segments) != 1 or \
            not np.array_equal(whole.trajectory.force, first.trajectory.force):
        return whole
    (step,), (own,) = whole.segments, first.segments
    return dataclasses.replace(whole, segments=[dataclasses.replace(step, **_marks(own))])


def _incumbent(first: Plan) -> StepResult:
    """The whole task's first plan as a plan of its one step (:func:`_whole_step`): the
    search's first incumbent at its horizon, so that a search that reaches that horizon
    starts from it (no feasibility pass) and betters it or bounds its cost."""
    (step,) = first.segments
    return StepResult.replayed(Status.FEASIBLE, step.horizon, first.trajectory, step.cost,
                               gap=step.gap)


def _motion_bounded(scenario: Scenario, result: Plan) -> Plan:
    """The whole task's plan with its step's bound raised to the motion bound
    (``model/motion.py``) at its horizon where that is higher, or where an object may be
    thrown, to the band bound (``model/band.py``): no plan of that horizon or shorter costs
    less, so neither does the task's optimum, whose horizon is at most this one. Unchanged
    where neither applies (an object that may be thrown and swapped for another the step
    after, a second step of rests under delivery ``reach``)."""
    if result.partial or len(result.segments) != 1:
        return result
    (step,) = result.segments
    whole = _whole_step(scenario)
    objects, spec = list(whole.spec.objects), whole.spec
    model = Model.from_scenario(scenario)
    if spec.no_throw_for_all():
        bound = motion.task_bound(model, whole.state, objects, step.horizon)
    elif band.holds(spec):
        bound = band.task_bound(model, whole.state, objects, step.horizon)
    else:
        return result
    if bound <= step.bound:
        return result
    return dataclasses.replace(result, segments=[dataclasses.replace(
        step, bound=bound, gap=relative_gap(step.cost, bound))])


def _whole_step(scenario: Scenario) -> StepProblem:
    """The whole task as one step: every object, from the scenario's start."""
    objects = list(range(scenario.n_objects))
    return StepProblem(scenario, State.initial(scenario), specification(scenario, objects))


class _Horizons:
    """What the whole task's search proved of the whole step's horizons, heard through
    ``on_try`` (and passed on to ``on_try``): the first it tries is predictT, below which no
    horizon has a plan (reachability, the route bound); those it proves infeasible after it."""

    def __init__(self, scenario: Scenario, options: SolveOptions,
                 on_try: Callable[[HorizonTried], None] | None) -> None:
        self.scenario, self.options, self.on_try = scenario, options, on_try
        self.first: int | None = None
        self.empty: set[int] = set()

    def __call__(self, tried: HorizonTried) -> None:
        if tried.step == 1:
            T = tried.result.horizon
            self.first = T if self.first is None else min(self.first, T)
            if tried.result.status is Status.INFEASIBLE:
                self.empty.add(T)
        if self.on_try:
            self.on_try(tried)

    def certify(self, first: Plan) -> Plan:
        """The whole task's first plan (one joined step) with what the search proved of the
        shorter horizons: from predictT, the horizons up to the first not proven empty have no
        plan and the rest below the plan's are undecided; none undecided, its horizon is
        proven minimal. Stopped before the first horizon was tried, predictT is counted here,
        without the route bound that the stop ends: reachability alone."""
        (step,) = first.segments
        least = self.first
        if least is None:
            least = predict_horizon(_whole_step(self.scenario), self.options)
        while least in self.empty:
            least += 1
        undecided = list(range(least, step.horizon))
        return dataclasses.replace(first, segments=[dataclasses.replace(
            step, horizons_undecided=undecided, horizon_proven_minimal=not undecided)])


def first_pass(scenario: Scenario) -> Scenario | None:
    """The sequential transportation whose plan is the whole task's first: ``scenario`` at
    ``FIRST_PASS``'s (m_o, n_o); None where ``scenario`` is not a whole task
    (:func:`whole_task`) of more than that m_o objects."""
    return _in_steps(scenario, FIRST_PASS)


def _in_steps(scenario: Scenario, row: tuple[int, int]) -> Scenario | None:
    """The whole task ``scenario`` as sequential transportation at ``row`` = (m_o, n_o); None
    where ``scenario`` is not a whole task of more than m_o objects."""
    task, n = scenario.task, scenario.n_objects
    m_o, n_o = row
    if not task.m_o == task.n_o == n > m_o:
        return None
    return dataclasses.replace(scenario, task=dataclasses.replace(task, m_o=m_o,
                                                                  n_o=min(n_o, n)))


def _sequential_first(scenario: Scenario, options, progress, on_try, on_first_plan,
                      t0: float) -> Plan | None:
    """The whole task's first plan: sequential transportation by :func:`first_pass`, anytime
    itself (:func:`_passes`: under rule 2 its no-throw witnesses, then Algorithm 1), each of
    its complete plans joined into one step and verified as the whole task's, the first told
    to ``on_first_plan``; the last of them, or None where there is no first pass or it gives no
    complete plan (the whole-task search then runs alone and says why)."""
    steps = first_pass(scenario)
    if steps is None:
        return None
    told: list[Plan] = []

    def joined(found: Plan) -> None:
        one = _joined(scenario, steps, found)
        if one is not None:
            told.append(dataclasses.replace(one, first_plan_s=told[0].first_plan_s if told else
                                            time.perf_counter() - t0))
            if on_first_plan and len(told) == 1:
                on_first_plan(told[0])

    try:
        found = _passes(steps, options, progress, on_try, joined, t0)
    except VerificationError:
        raise  # a defect, never hidden
    except PlanningError:
        return told[-1] if told else None
    if not found.partial and (not told or found.total_cost < told[-1].total_cost):
        joined(found)  # Algorithm 1's plan after its witnesses, or the only pass's
    return told[-1] if told else None


def _passes(scenario: Scenario, options, progress, on_try, on_first_plan, t0: float,
            known: Plan | None = None) -> Plan:
    """Algorithm 1 by the scenario's policies, anytime from each step's no-throw witness where
    the rules allow throws (:func:`plan`). ``known``: the whole task's first plan, the search's
    incumbent at its horizon (:func:`_incumbent`)."""
    kept = KeptSteps(first_sight=known is None)
    if known is not None:
        kept.known[KeptSteps.key(_whole_step(scenario))] = _incumbent(known)
    first = transport(scenario, options, progress, on_try, kept, quick=True)
    if first.partial:
        return first
    first = _verified(scenario, first, time.perf_counter() - t0)
    if options.stopped() or not kept.any_witness:  # without a witness, the second = the first
        return first
    if on_first_plan:
        on_first_plan(first)
    second = transport(scenario, options, progress, on_try, kept)
    spent = first.total_solve_time_s + second.total_solve_time_s - kept.reused_s
    if not second.partial:
        second = _verified(scenario, second, first.first_plan_s)
    best = second if not second.partial and second.total_cost <= first.total_cost else first
    return dataclasses.replace(best, unused_solve_time_s=max(
        0.0, spent - best.total_solve_time_s))


def _verified(scenario: Scenario, result: Plan, first_plan_s: float) -> Plan:
    """``result`` verified (with ``first_plan_s``), or :class:`VerificationError`."""
    verification = verify(scenario, result)
    result = dataclasses.replace(result, verified=verification.ok,
                                 first_plan_s=first_plan_s if verification.ok else None)
    if not verification.ok:
        raise VerificationError(result, verification.problems)
    return result
