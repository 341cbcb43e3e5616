"""A task's plan as the library gives it: the consistency check, sequential transportation
(Algorithm 1) and the verification every plan passes, in one call (``dualarm_mpc.plan``; the
``plan`` command prints what this returns)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

from dualarm_mpc.milp.horizon import solve_options
from dualarm_mpc.milp.solver import Interrupt
from dualarm_mpc.model.plan import Plan, Segment
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.model.verify import verify
from dualarm_mpc.planning.consistency import Report, check
from dualarm_mpc.planning.sequential import HorizonTried, KeptSteps, PlanningError, transport

__all__ = ["ConflictError", "VerificationError", "plan", "whole_task"]


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
    there, and a second step delivers it."""
    n = scenario.n_objects
    whole = dataclasses.replace(scenario, task=dataclasses.replace(scenario.task, m_o=n, n_o=n))
    whole.validate()
    return whole


def plan(scenario: Scenario, *, check_first: bool = True,
         progress: Callable[[Segment], None] | None = None,
         on_try: Callable[[HorizonTried], None] | None = None,
         stop: Interrupt | None = None,
         on_first_plan: Callable[[Plan], None] | None = None) -> Plan:
    """Plan every object of ``scenario`` into its goal and verify the plan (re-simulated through
    the model, each step's LTL checked by the independent evaluator).

    An anytime plan, in two passes where the rules allow throws: first each step's no-throw
    witness (a complete plan soon, verified against the scenario's own rules), then Algorithm 1
    by the horizon policy, which takes every search of the first pass it meets again; the
    cheaper complete plan is returned, the first where ``stop`` ends the second. Where no step
    has a witness (rule 1, or none in reach) the first pass is Algorithm 1 itself.

    ``check_first``: run the consistency check (without its joint step) first and raise
    :class:`ConflictError` on a conflict. ``progress`` hears of each sequential step of each
    pass, ``on_try`` of each horizon tried, ``on_first_plan`` of the first pass's verified plan
    when a second pass follows. ``stop``, once set (from another thread), ends the search: the
    best complete plan so far, or else the steps planned so far as a partial plan
    (``partial``), not verified.

    Raises :class:`~dualarm_mpc.planning.sequential.PlanningError` when a step has no plan
    (``proven``: none exists up to the horizon cap), :class:`VerificationError` when the plan
    fails verification. Returns the plan with ``verified`` true otherwise, and its
    ``first_plan_s``: the wall seconds from the start of planning (after the check) until it
    passed verification. ``scenario`` is checked first as ``load_scenario`` checks it
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
    kept = KeptSteps()
    first = transport(scenario, options, progress, on_try, kept, quick=True)
    if first.partial or (stop is not None and stop.is_set()):
        return first
    first = _verified(scenario, first, time.perf_counter() - t0)
    if not kept.any_witness:  # the second pass would take every step of the first
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
