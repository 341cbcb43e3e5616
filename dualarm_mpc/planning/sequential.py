"""Planning: predictT, the horizon of a step, and sequential transportation (Algorithm 1).

``plan_step`` finds a step's shortest feasible horizon and its optimum there — by the skeleton
search (``search.py``) or the monolithic MILP (``horizon.py``) — and ``plan`` repeats steps
until every object rests in its goal.

Why one module of this length: the horizon policies (exact, witness) and the loop of steps share
one record of what each horizon tried and proved, from which every step's certificate (its bound,
whether its horizon is minimal) is read; apart, the certificate would be rebuilt from outside.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from dualarm_mpc.milp.horizon import HorizonProgram, StepResult, solve_options, solve_step
from dualarm_mpc.milp.solver import SolveOptions, Status
from dualarm_mpc.model import band
from dualarm_mpc.model.mld import Model, Rect, State, delivered_objects, in_goal, reachability
from dualarm_mpc.model.plan import Plan, Segment, Trajectory, relative_gap
from dualarm_mpc.model.route import horizon_bound
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.model.spec import StepProblem, rule_formulas, specification, with_no_throw
from dualarm_mpc.search.relaxations import Key
from dualarm_mpc.search.skeleton import horizon_has_plan, horizon_ruled_out, search_step
from dualarm_mpc.search.subprograms import SearchStats, satisfies

# Seconds a step may go without a plan before the largest horizon is checked (plan_step): the
# check costs up to CAP_CHECK_TIME_S, wasted when the step has a plan, so only a step that has
# already spent several times that is checked.
CHECK_CAP_AFTER_S = 10.0
CAP_CHECK_TIME_S = 3.0  # the whole of that check
# The witness policy (below_witness): the step's budget after its witness, as a share of the
# per-horizon time limit; the first round's slice of it for each horizon below T₁; and the
# least time a horizon is given (less decides nothing).
STEP_BUDGET_SHARE = 1 / 3
FIRST_SLICE_SHARE = 1 / 8
MIN_HORIZON_TIME_S = 1.0
# The second prover (solver.prover, cpsat.Prover) takes the horizons the search has left
# undecided, beside the search's next ones: its first slice on each, as a share of the time
# limit (under the witness policy, the search's first slice).
PROVER_FIRST_SLICE_SHARE = 1 / 16


class PlanningError(RuntimeError):
    """No plan was found; the message says why (e.g. which rules conflict). ``partial`` holds
    the steps completed before (a partial :class:`Plan`), if any. ``proven``: the step has no
    plan at all (every horizon up to the cap proven infeasible); otherwise the planner ran out
    of time or stalled, which decides nothing."""

    def __init__(self, message: str, partial: Plan | None = None, proven: bool = False) -> None:
        super().__init__(message)
        self.partial = partial
        self.proven = proven


@dataclass(frozen=True)
class HorizonTried:
    """One horizon the planner tried: the ``step``-th sequential step (from 1), its
    ``problem`` (scenario, the state it starts from, its specification) and what the solve of
    that horizon gave."""

    step: int
    problem: StepProblem
    result: StepResult


class Interrupted(Exception):
    """The step's solves were stopped through ``SolveOptions.interrupt`` (e.g. Ctrl-C)."""


def _stop_if_asked(options: SolveOptions | None) -> None:
    if options is not None and options.stopped():
        raise Interrupted


def solve_horizon(problem: StepProblem, horizon: int, options: SolveOptions | None = None,
                  start=None, below: dict[Key, StepResult] | None = None,
                  incumbent: StepResult | None = None) -> StepResult:
    """The optimum of one horizon by the scenario's ``solver.search``: the skeleton search or
    the monolithic MILP (the same optimum; the search is much faster on hard steps). ``start``
    is a MIP start for the monolithic MILP (:func:`~dualarm_mpc.milp.horizon.solve_step`); ``below``
    carries the search's relaxations from one horizon to the next, and ``incumbent`` is a plan of
    the horizon to start the search's optimisation from
    (:func:`~dualarm_mpc.search.skeleton.search_step`)."""
    if problem.scenario.solver.search == "monolithic":
        return solve_step(problem, horizon, options, start)
    return search_step(problem, horizon, options, below, incumbent)


def predict_horizon(problem: StepProblem, options: SolveOptions | None = None) -> int:
    """predictT: the smallest horizon the reachability bound does not rule out (§IV-C.2) — the
    m_o-th smallest step at which an object of the step can first be in its goal — or, where
    no-throw (18) holds for every object of the step, the route bound of the hands
    (:func:`~dualarm_mpc.model.route.horizon_bound`) if larger: the horizons below either have no
    plan. A stop (``options.interrupt``) ends the route bound, which then says nothing."""
    scenario, state, spec = problem.scenario, problem.state, problem.spec
    objects = list(spec.objects)
    model = Model.from_scenario(scenario, objects)
    cap = scenario.solver.max_horizon
    local = state.select(objects)
    reach = reachability(model, local, cap)
    first = np.sort(reach.first_goal)
    no_throw = frozenset(objects.index(j) for j in spec.released_only_in_goal())
    routes = horizon_bound(model, local, spec.m_o, no_throw, cap,
                           options.stopped if options else None)
    return int(min(max(first[spec.m_o - 1], routes, 1), cap))


def select_objects(scenario: Scenario, state: State, remaining: list[int]) -> list[int]:
    """Algorithm 1, line 2: the n_o remaining objects cheapest to deliver, by the distance from
    the nearer hand to the object plus the object's distance to its goal box."""
    def estimate(j: int) -> float:
        p = state.object_pos[j]
        goal = Rect.of(scenario.task.goals[scenario.task.objects[j].goal])
        to_goal = np.linalg.norm(np.maximum(goal.lo - p, 0) + np.maximum(p - goal.hi, 0))
        to_hand = np.linalg.norm(state.hand_pos - p, axis=1).min()
        return float(to_hand + to_goal)

    return sorted(sorted(remaining, key=lambda j: (estimate(j), j))[: scenario.task.n_o])


class KeptSteps:
    """What ``task.plan``'s first pass (the anytime plan) searched, by step problem, for its
    second: each step's no-throw witness and each step planned in full, with the wall seconds
    it took. Where the second pass meets a step problem of the first (the same objects from the
    same state: its first step, and every step after one whose plan was its witness) it takes
    them instead of searching again. ``known``: a plan of a step problem found before its
    search (the whole task's first plan), the search's first incumbent at its horizon.

    ``first_sight``: the first pass takes each witness as its search first finds it, not
    optimised (:func:`witness`'s ``first``), so that the first plan comes sooner; the second
    pass optimises it (:func:`optimised`) before it goes on. Not where a plan exists already
    (the whole task's search, after its first plan): there the first pass's plan is what a
    stop leaves, and its witnesses are optimised at once."""

    def __init__(self, first_sight: bool = True) -> None:
        self.first_sight = first_sight
        self.witnesses: dict[tuple, tuple[StepResult | None, float, dict | None]] = {}
        self.unoptimised: set[tuple] = set()  # the first pass's witnesses taken at first sight
        self.steps: dict[tuple, tuple[StepResult, float]] = {}
        self.known: dict[tuple, StepResult] = {}
        self.reused_s = 0.0  # seconds of the first pass's searches the second took

    @staticmethod
    def key(problem: StepProblem) -> tuple:
        s = problem.state
        return (tuple(problem.spec.objects), problem.spec.m_o,
                *(np.asarray(a).tobytes() for a in (s.hand_pos, s.hand_vel, s.object_pos,
                                                     s.object_vel, s.grasp)))

    @property
    def any_witness(self) -> bool:
        """Some step of the first pass was its witness: the second pass has work to do."""
        return any(found is not None for found, _, _ in self.witnesses.values())


def plan_step(problem: StepProblem, options: SolveOptions | None = None,
              on_try: Callable[[StepResult], None] | None = None,
              kept: KeptSteps | None = None, quick: bool = False) -> tuple[StepResult, float]:
    """Lines 4–6 of Algorithm 1 by the scenario's ``solver.horizons`` policy. Returns the
    result (with :attr:`~dualarm_mpc.milp.horizon.StepResult.minimal` and the witness's cost and
    horizon) and the step's total solve time (wall time, everything included).

    ``exact`` (:func:`first_plan`): from predictT, raise T until a plan is found. ``witness``
    (the skeleton search's default): first the no-throw witness (:func:`witness`), then
    Algorithm 1 on the horizons below its T₁ within one budget for the step, its plan taken
    where it is cheaper than the witness (:func:`below_witness`); the step's plan is never
    worse than its witness. ``quick``: the witness itself, where there is one (the anytime
    plan's first pass), with no claim beyond its own (:func:`as_step`). ``kept``: what a first
    pass searched, taken where this is one of its step problems, and added to where ``quick``;
    a witness it took at first sight (``KeptSteps.first_sight``) is optimised before it is
    used.

    The result's ``search_stats`` add up the skeleton search's work over every horizon the
    step searched, the witness's included (None under the monolithic MILP)."""
    t0 = time.perf_counter()
    key = None if kept is None else kept.key(problem)
    if kept is not None and key in kept.steps and not quick:
        res, seconds = kept.steps[key]
        kept.reused_s += seconds
        return res, seconds
    found = None
    solver = problem.scenario.solver
    stats = SearchStats.Sum()

    def tried(res: StepResult) -> None:
        stats.add(res.search_stats)
        if on_try:
            on_try(res)

    if solver.horizons == "witness" and solver.search == "skeleton":
        if kept is not None and key in kept.witnesses:
            found, seconds, record = kept.witnesses[key]
            kept.reused_s += seconds
            t0 -= seconds  # the step's time is its witness's and what follows
            stats.add(record)
            if not quick and key in kept.unoptimised:  # taken at first sight by the first pass
                found = optimised(problem, found, options,
                                  lambda res: stats.add(res.search_stats))
                kept.unoptimised.discard(key)
                kept.witnesses[key] = (found, time.perf_counter() - t0, stats.record())
        else:
            witness_stats = SearchStats.Sum()
            first = quick and kept is not None and kept.first_sight
            found = witness(problem, options, lambda res: witness_stats.add(res.search_stats),
                            first=first)
            stats.add(witness_stats.record())
            if kept is not None:
                kept.witnesses[key] = (found, time.perf_counter() - t0, witness_stats.record())
                if first and found is not None:
                    kept.unoptimised.add(key)
        if quick and found is not None:  # no bound: the first plan comes first (0.2 s a step)
            return (dataclasses.replace(as_step(problem, found, options),
                                        search_stats=stats.record()),
                    time.perf_counter() - t0)
    if found is None:
        res = first_plan(problem, options, tried, None if kept is None else kept.known.get(key))
    else:
        res = below_witness(problem, found, options, tried)
    res = dataclasses.replace(band_bounded(problem, res), search_stats=stats.record())
    total = time.perf_counter() - t0
    if kept is not None and quick:
        kept.steps[key] = (res, total)
    return res, total


def band_bounded(problem: StepProblem, res: StepResult) -> StepResult:
    """``res`` with its bound raised to the band bound (``model/band.py``) at its horizon where
    an object may be thrown and that is higher: no plan of the step within that horizon costs
    less. Not of the anytime plan's first pass, whose witnesses claim nothing."""
    spec = problem.spec
    objects = list(spec.objects)
    if res.gap <= 0 or spec.no_throw_for_all() or not band.holds(spec):
        return res
    model = Model.from_scenario(problem.scenario, objects)
    bound = band.task_bound(model, problem.state.select(objects), list(range(len(objects))),
                            res.horizon, spec.m_o)
    if bound <= res.bound:
        return res
    return dataclasses.replace(res, bound=bound, gap=relative_gap(res.cost, bound))


def as_step(problem: StepProblem, found: StepResult, options: SolveOptions | None) -> StepResult:
    """The witness ``found`` as the step's plan: a plan of the step, whose own bound and
    horizon proofs hold for the restriction only; so its bound is 0 and the horizons from
    predictT below its own are undecided."""
    below = tuple(range(predict_horizon(problem, options), found.horizon))
    return dataclasses.replace(unproven(found), witness_cost=found.cost,
                               witness_horizon=found.horizon, proofs=(), undecided=below,
                               passed_over=None)


def unproven(found: StepResult) -> StepResult:
    """The witness ``found`` without its bound, which holds for the restriction only."""
    return dataclasses.replace(found, bound=0.0, gap=1.0 if found.cost > 0 else 0.0,
                               status=Status.FEASIBLE if found.cost > 0 else Status.OPTIMAL)


def witness(problem: StepProblem, options: SolveOptions | None,
            on_try: Callable[[StepResult], None] | None = None,
            first: bool = False) -> StepResult | None:
    """The step's witness: the plan of ``spec`` with no-throw (18) for every object
    (:func:`~dualarm_mpc.model.spec.with_no_throw`, a restriction: quick where ``spec`` allows
    relays), at its own first horizon T₁ by :func:`first_plan`, checked against ``spec`` itself by
    the evaluator (:func:`~dualarm_mpc.search.subprograms.satisfies`); None where ``spec`` has
    no-throw already, or the restriction has no plan or none in time. ``on_try`` hears of each
    horizon of the restriction tried. ``first``: the first plan the search finds at T₁ (its
    feasibility pass), not optimised there (the anytime plan's first pass; :func:`optimised`
    does the rest)."""
    restricted = _restriction(problem)
    if restricted is None:
        return None
    objects = list(problem.spec.objects)
    model = Model.from_scenario(problem.scenario, objects)
    cap = problem.scenario.solver.max_horizon
    if horizon_bound(model, problem.state.select(objects), problem.spec.m_o,
                     frozenset(range(len(objects))), cap,
                     options.stopped if options else None) > cap:
        return None  # no route delivers m_o objects without a throw (§V-C's goals)
    if first:
        options = dataclasses.replace(options or solve_options(problem.scenario),
                                      mip_rel_gap=1.0)  # any plan is within the gap
    try:
        res = first_plan(restricted, options, on_try)
    except PlanningError:
        return None
    return _checked(problem, model, unproven(res) if first else res)


def optimised(problem: StepProblem, found: StepResult, options: SolveOptions | None,
              on_try: Callable[[StepResult], None] | None = None) -> StepResult:
    """The witness ``found``, taken at first sight (:func:`witness` with ``first``), optimised
    at its horizon: the restriction's search from it, as :func:`witness` would have gone on;
    ``found`` itself where that finds nothing cheaper in time."""
    res = solve_horizon(_restriction(problem), found.horizon, options, incumbent=found)
    if on_try:
        on_try(res)
    model = Model.from_scenario(problem.scenario, list(problem.spec.objects))
    better = _checked(problem, model, res) if res.status.has_solution else None
    if better is None or better.cost > found.cost:
        return found
    return dataclasses.replace(better, undecided=found.undecided, proofs=found.proofs)


def _restriction(problem: StepProblem) -> StepProblem | None:
    """The step with no-throw (18) for every object, searched without the second prover (the
    witness's own horizons need no proofs); None where ``spec`` has no-throw already."""
    restricted = with_no_throw(problem.spec)
    if restricted is None:
        return None
    scenario = problem.scenario
    alone = dataclasses.replace(scenario, solver=dataclasses.replace(scenario.solver,
                                                                     prover="none"))
    return dataclasses.replace(problem, scenario=alone, spec=restricted)


def _checked(problem: StepProblem, model: Model, res: StepResult) -> StepResult | None:
    """A plan of the restriction as the step's witness: checked against the step's own
    specification (``model``: of its objects), its solver values dropped."""
    if not satisfies(problem, model, res.trajectory):
        return None
    # Its solver values are those of the restriction's program (other LTL columns): a MIP start
    # from its forces and grasps instead (subprograms._start).
    return dataclasses.replace(res, solution=None, variables=None)


def below_witness(problem: StepProblem, found: StepResult, options: SolveOptions | None,
                  on_try: Callable[[StepResult], None] | None = None) -> StepResult:
    """Algorithm 1 bounded by the witness ``found`` (horizon T₁, cost c_W): the horizons from
    predictT up to T₁ are searched for the first with a plan, as :func:`first_plan` does (T₁
    has one: the witness, the search's first incumbent there), and the step's plan is the
    cheaper of its optimum and the witness. What is left of the budget then goes to the step's
    plan: where the first plan costs more than the witness, T₁ is searched from the witness
    for a cheaper plan or the proof that there is none; else the first plan's horizon, from it,
    where the plan is not yet proven optimal.

    All of it within one budget for the step, ``STEP_BUDGET_SHARE`` of
    ``solver.time_limit_s``, in rounds: each horizon still undecided gets ``FIRST_SLICE_SHARE``
    of the budget, four times as much in the next round, so that one hard horizon does not
    take the time the others would be decided in. Beside the search, the second prover
    (:func:`second_prover`) tries to prove the horizons below T₁ that the search has left
    undecided to have no plan. The step's horizon is proven minimal
    (:attr:`~dualarm_mpc.milp.horizon.StepResult.minimal`) when every horizon below it was proven to
    have no plan, by either."""
    options = options or solve_options(problem.scenario)
    budget = STEP_BUDGET_SHARE * options.time_limit_s
    deadline = time.perf_counter() + budget
    undecided = list(range(predict_horizon(problem, options), found.horizon + 1))
    left_open: set[int] = set()  # the horizons the search has left undecided once
    first = None  # the plan of the lowest horizon that has one
    slice_s = FIRST_SLICE_SHARE * budget

    def solve(T: int, o: SolveOptions, incumbent: StepResult | None) -> StepResult:
        res = solve_horizon(problem, T, o, incumbent=incumbent)
        _stop_if_asked(options)  # a stopped solve decides nothing, even with an incumbent
        if on_try:
            on_try(res)
        return res

    with second_prover(problem, options, slice_s, on_try) as prover:
        while undecided:
            for T in list(undecided):
                undecided = [t for t in undecided if t not in prover.proofs()]
                if T not in undecided:
                    continue
                _stop_if_asked(options)
                left = deadline - time.perf_counter()
                if left < MIN_HORIZON_TIME_S:
                    break
                limit = max(min(slice_s, left), MIN_HORIZON_TIME_S)
                with prover.searching(T, dataclasses.replace(options, time_limit_s=limit)) as o:
                    res = solve(T, o, found if T == found.horizon else None)
                if res.status.has_solution:
                    first = res
                    undecided = [t for t in undecided if t < T]  # the higher ones matter no more
                elif res.status is Status.INFEASIBLE:
                    undecided.remove(T)
                else:
                    left_open.add(T)
                prover.ask([t for t in undecided if t in left_open and t < found.horizon])
                if first is res:
                    break
            if deadline - time.perf_counter() < MIN_HORIZON_TIME_S:
                break
            slice_s *= 4
    proofs = prover.proofs()
    undecided = [t for t in undecided if t not in proofs]
    # What is left of the budget goes to the step's plan: T₁ searched again from the witness
    # where the first plan costs more, else the first plan's horizon from it, not yet proven.
    at_witness = None
    left = deadline - time.perf_counter()
    if first is not None and left >= MIN_HORIZON_TIME_S:
        start = found if first.cost > found.cost else first
        if start is found or first.status is not Status.OPTIMAL:
            _stop_if_asked(options)
            again = solve(start.horizon, dataclasses.replace(options, time_limit_s=left), start)
            if again.status.has_solution and start is found:  # the witness or cheaper
                at_witness = again
            elif again.status.has_solution:
                first = again
    if first is not None and first.cost <= found.cost:
        best = first  # T₁'s search, from the witness, is one of these
    elif at_witness is not None and at_witness.status.has_solution:
        best = at_witness  # the witness or cheaper, with the search's bound
    else:
        best = unproven(found)
    passed_over = (first.horizon, first.cost) if first is not None and \
        first.horizon < best.horizon else None
    shorter = tuple(t for t in undecided if t < best.horizon)
    return dataclasses.replace(best, witness_cost=found.cost, witness_horizon=found.horizon,
                               proofs=_shorter(proofs, best.horizon), undecided=shorter,
                               passed_over=passed_over)


def first_plan(problem: StepProblem, options: SolveOptions | None = None,
               on_try: Callable[[StepResult], None] | None = None,
               known: StepResult | None = None) -> StepResult:
    """Lines 4–6 of Algorithm 1 as the paper: from predictT, raise T until a plan is found (an
    infeasible or timed-out horizon counts as "not yet"; the result's ``minimal`` says whether
    every one was proven infeasible: by the search, or by the second prover
    (:func:`second_prover`), which works on the horizons the search left undecided beside its
    next ones). ``known``: a plan of the step found before, the search's first incumbent at its
    horizon (:func:`solve_horizon`), so that a search that gets there betters it or bounds
    it. A stop (``options.interrupt``) ends it: with the plan a horizon's search had
    found by then (its optimum unproven: the status says so), else with :class:`Interrupted`.

    With the skeleton search and a specification whose feasibility is monotone in T
    (:meth:`~dualarm_mpc.model.spec.Specification.monotone_in_horizon`), once the step went
    ``CHECK_CAP_AFTER_S`` without a plan the largest one is checked by the search's relaxations
    alone (:func:`~dualarm_mpc.search.skeleton.horizon_ruled_out`, a few seconds at most): if they
    rule it out, no horizon has a plan, and the conflict is diagnosed at once instead of after every
    horizon."""
    t0 = time.perf_counter()
    scenario = problem.scenario
    cap = scenario.solver.max_horizon
    last = None
    check_cap = scenario.solver.search == "skeleton" and problem.spec.monotone_in_horizon()
    below: dict[Key, StepResult] = {}  # the relaxations with a plan, from horizon to horizon
    undecided: list[int] = []  # the horizons tried without a plan or a proof of none
    options = options or solve_options(scenario)
    first_slice = PROVER_FIRST_SLICE_SHARE * options.time_limit_s
    with second_prover(problem, options, first_slice, on_try) as prover:
        for T in range(predict_horizon(problem, options), cap + 1):
            _stop_if_asked(options)
            if check_cap and time.perf_counter() - t0 >= CHECK_CAP_AFTER_S and T < cap:
                check_cap = False  # once
                if horizon_ruled_out(problem, cap, CAP_CHECK_TIME_S, options):
                    raise PlanningError(diagnose(problem, None, options, True), proven=True)
            at = known if known is not None and known.horizon == T else None
            res = solve_horizon(problem, T, options, below=below, incumbent=at)
            if not res.status.has_solution:  # a stopped solve without a plan decides nothing;
                _stop_if_asked(options)  # with one, its plan holds, its optimum unproven
            if on_try:
                on_try(res)
            last = res
            if res.status.has_solution:
                break
            if res.status is not Status.INFEASIBLE:
                undecided.append(T)
                prover.ask(undecided)
            if res.status is Status.ERROR:
                break
    proofs = prover.proofs()
    undecided = [t for t in undecided if t not in proofs]
    if last is not None and last.status.has_solution:
        return dataclasses.replace(last, undecided=tuple(undecided),
                                   proofs=_shorter(proofs, last.horizon))
    raise PlanningError(diagnose(problem, last, options, not undecided), proven=not undecided)


@contextmanager
def second_prover(problem: StepProblem, options: SolveOptions, first_slice_s: float,
                  on_try: Callable[[StepResult], None] | None = None) -> Iterator:
    """The scenario's second prover (``solver.prover``) of the step's horizons, for the length
    of a ``with``: :class:`~dualarm_mpc.milp.cpsat.Prover` on the horizons' programs, each proof
    told to ``on_try`` as an infeasible horizon at the end; or, with ``none``, one that proves
    nothing. Never in a replan: ``mpc.py`` solves its horizons itself, in lockstep by counted work
    alone."""
    scenario, state, spec = problem.scenario, problem.state, problem.spec
    if scenario.solver.prover == "none":
        yield _NoProver()
        return
    from dualarm_mpc.milp.cpsat import Prover

    objects = list(spec.objects)
    prover = Prover(lambda T: HorizonProgram(scenario, state, objects, T).standard_form(spec),
                    options, first_slice_s=first_slice_s)
    try:
        yield prover
    finally:
        proofs = prover.close()
    for T, proof in sorted(proofs.items()):
        if on_try:
            on_try(StepResult.no_plan(Status.INFEASIBLE, T, np.inf, proof.wall_time_s,
                                      proof.binaries, proof.message))


def _shorter(proofs: dict, horizon: int) -> tuple[int, ...]:
    """The horizons proven below ``horizon``."""
    return tuple(sorted(T for T in proofs if T < horizon))


class _NoProver:
    """``solver.prover: none``: proves nothing."""

    def ask(self, horizons) -> None:
        pass

    @contextmanager
    def searching(self, horizon: int, options: SolveOptions) -> Iterator[SolveOptions]:
        yield options

    def proofs(self) -> dict:
        return {}


def within_cap(scenario: Scenario) -> str:
    """The horizon cap as the reasons name it: the field and its value."""
    return f"within solver.max_horizon = {scenario.solver.max_horizon}"


def diagnose(problem: StepProblem, last: StepResult | None, options: SolveOptions | None,
             proven: bool) -> str:
    """Why no plan exists within the horizon cap: which rules, dropped, make the task feasible
    (each decided at the cap: by the skeleton search's feasibility pass, or the monolithic MILP
    stopped at its first solution). ``proven``: every horizon up to the cap was proven to have
    no plan, which the reason says whether or not the rest is decided."""
    scenario, spec = problem.scenario, problem.spec
    T = scenario.solver.max_horizon
    objects = [scenario.task.objects[j].name for j in spec.objects]
    status = f" (last status: {last.status.value})" if last and not proven else ""
    proof = ", proven for every horizon" if proven else ""
    head = f"no plan delivering {spec.m_o} of {objects} {within_cap(scenario)}{proof}{status}"
    options = options or solve_options(scenario)
    quick = dataclasses.replace(options, time_limit_s=min(options.time_limit_s, 20.0),
                                mip_rel_gap=1.0)

    def feasible(rules) -> Status:
        fewer = problem.with_spec(dataclasses.replace(spec, rules=tuple(rules)))
        if scenario.solver.search == "skeleton":
            return horizon_has_plan(fewer, T, quick)
        return solve_step(fewer, T, quick).status

    alone = feasible([])
    if alone is Status.INFEASIBLE:
        clearance = scenario.task.object_clearance
        apart = "" if clearance is None else f", objects {clearance:g} m apart (C1)"
        return (f"{head}: the task alone is infeasible — the goals cannot be reached with "
                f"|v| <= {scenario.robot.max_speed} and |u| <= {scenario.robot.max_force}"
                f"{apart} from this state")
    if not alone.has_solution:
        return (f"{head}; whether the task alone or the rules cause it was not decided within "
                "the time limit (solver.time_limit_s)")
    culprits = [name for name, f in spec.rules if not feasible([(name, f)]).has_solution]
    if culprits:
        return f"{head}: the task conflicts with rule(s) {', '.join(culprits)}"
    names = ", ".join(n for n, _ in spec.rules)
    return f"{head}: the rules {names} together conflict with the task"


def embed_step(scenario: Scenario, state: State, objects: list[int],
               local: Trajectory) -> Trajectory:
    """The step's trajectory over all objects: those outside the step stay where they are."""
    K1 = len(local.hand_pos)
    n = scenario.n_objects
    op = np.repeat(state.object_pos[None], K1, axis=0)
    ov = np.zeros((K1, n, 2))
    g = np.zeros((K1, 2, n), int)
    op[:, objects] = local.object_pos
    ov[:, objects] = local.object_vel
    g[:, :, objects] = local.grasp
    return Trajectory(local.hand_pos, local.hand_vel, local.force, op, ov, g)


def transport(scenario: Scenario, options: SolveOptions | None = None,
              progress: Callable[[Segment], None] | None = None,
              on_try: Callable[[HorizonTried], None] | None = None,
              kept: KeptSteps | None = None, quick: bool = False) -> Plan:
    """Algorithm 1 (sequential transportation): plan m_o objects at a time until every object
    rests in its goal. ``progress`` hears of each step, ``on_try`` of each horizon tried;
    ``kept`` and ``quick`` go to each step (:func:`plan_step`).
    Raises :class:`PlanningError` with the reason when a step has no plan; when
    ``options.interrupt`` is set, returns the steps completed so far (``partial``)."""
    state = State.initial(scenario)
    rules = rule_formulas(scenario)
    trajectory = Trajectory.still(state)
    segments: list[Segment] = []
    delivered_step: list[int | None] = [None] * scenario.n_objects
    done = delivered_objects(scenario, state.object_pos, state.object_vel)
    for j in np.flatnonzero(done):
        delivered_step[j] = 0

    def finish(partial: bool) -> Plan:
        return _plan(scenario, trajectory, delivered_step, segments, partial)

    def tried(res: StepResult) -> None:  # within plan_step: of the step being planned
        on_try(HorizonTried(len(segments) + 1, problem, res))

    for _ in range(3 * scenario.n_objects):  # each step delivers >= 1 object unless stuck
        remaining = [j for j in range(scenario.n_objects) if not done[j]]
        if not remaining:
            break
        objects = select_objects(scenario, state, remaining)
        problem = StepProblem(scenario, state, specification(scenario, objects, rules=rules))
        cpu0 = time.process_time()
        try:
            res, total = plan_step(problem, options, on_try and tried, kept, quick)
        except Interrupted:
            return finish(partial=True)
        except PlanningError as err:
            raise PlanningError(str(err), finish(partial=True), err.proven) from None
        cpu = time.process_time() - cpu0
        step = embed_step(scenario, state, objects, res.trajectory)
        offset = trajectory.steps
        trajectory = trajectory.then(step)
        state = State.last(step)
        now = delivered_objects(scenario, state.object_pos, state.object_vel)
        newly = [j for j in objects if now[j] and not done[j]]
        _delivered_at(scenario, step, newly, offset, delivered_step)
        done = done | now
        seg = _segment(objects, newly, res, total, cpu)
        segments.append(seg)
        if progress:
            progress(seg)
    if not done.all():
        missing = [scenario.task.objects[j].name for j in np.flatnonzero(~done)]
        raise PlanningError(f"sequential transportation stalled: {missing} not delivered",
                            finish(partial=True))
    return finish(partial=False)


def one_step(problem: StepProblem, res: StepResult, total_s: float, cpu_s: float) -> Plan:
    """The plan of one step from the scenario's start (``res``, a plan of ``problem``, found in
    ``total_s`` wall and ``cpu_s`` CPU seconds): a whole task's plan (``--mo all``) made outside
    Algorithm 1's loop, not verified."""
    scenario, objects = problem.scenario, list(problem.spec.objects)
    step = embed_step(scenario, problem.state, objects, res.trajectory)
    now = delivered_objects(scenario, step.object_pos[-1], step.object_vel[-1])
    newly = [j for j in objects if now[j]]
    delivered_step: list[int | None] = [None] * scenario.n_objects
    _delivered_at(scenario, step, newly, 0, delivered_step)
    return _plan(scenario, Trajectory.still(problem.state).then(step), delivered_step,
                 [_segment(objects, newly, res, total_s, cpu_s)], partial=False)


def _plan(scenario: Scenario, trajectory: Trajectory, delivered_step: list[int | None],
          segments: list[Segment], partial: bool) -> Plan:
    return Plan(
        dt=scenario.robot.dt, rule=scenario.task.rule, delivery=scenario.task.delivery,
        goals={k: list(v) for k, v in scenario.task.goals.items()},
        objects=[{"name": o.name, "goal": o.goal, "grasp_half_size": o.grasp_half_size}
                 for o in scenario.task.objects],
        workspace=list(scenario.robot.workspace), trajectory=trajectory,
        delivered_step=delivered_step, segments=segments, search=scenario.solver.search,
        partial=partial,
    )


def _delivered_at(scenario: Scenario, step: Trajectory, newly: list[int], offset: int,
                  delivered_step: list[int | None]) -> None:
    """Each object of ``newly``'s first step in its true goal box (the planner aims
    goal_margin in), ``offset`` the step's start within the plan."""
    for j in newly:
        goal = scenario.task.goals[scenario.task.objects[j].goal]
        inside = np.flatnonzero(in_goal(step.object_pos[:, j], goal))
        delivered_step[j] = offset + int(inside[0] if inside.size else step.steps)


def _segment(objects: list[int], newly: list[int], res: StepResult, total: float,
             cpu: float) -> Segment:
    return Segment(objects=objects, delivered=newly, horizon=res.horizon,
                   status=res.status.value, solve_time_s=total, cost=res.cost,
                   cpu_time_s=cpu, binaries=res.binaries, gap=float(res.gap),
                   horizon_proven_minimal=res.minimal,
                   witness_cost=res.witness_cost, witness_horizon=res.witness_horizon,
                   horizons_proven_by_cpsat=list(res.proofs),
                   horizons_undecided=list(res.undecided),
                   shorter_plan=None if res.passed_over is None else list(res.passed_over),
                   bound=float(min(res.bound, res.cost)), search_stats=res.search_stats)
