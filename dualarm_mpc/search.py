"""Exact step search over the discrete skeleton: which objects, which hand (docs/search.md).

The monolithic MILP of one horizon has an LP relaxation whose bound is zero (a fractional η moves
an object while the hands' fractions cancel), so HiGHS proves optimality and infeasibility by
enumeration alone. This module splits the same MILP along its discrete skeleton and searches it
best-first with admissible bounds; with hand-overs allowed for every object (``handover:
always``) it returns the monolithic optimum of the same horizon; by default (``auto``) the
same at a horizon that has no plan without a relay, else the optimum over the plans that hand
over only the objects no single hand can deliver.

*Skeleton node* (D, h): the set D of m_o objects whose delivery satisfies φ_task (13), and for
each j ∈ D the hand h_j that may hold it (1, 2, or ``BOTH`` for a hand-over). The node's program
is the monolithic one with η_ij(k ≥ 1) = 0 outside the skeleton and φ_task replaced by "every
j ∈ D delivered": a restriction, so its optimum is never below the monolithic one. The nodes
cover every plan: a plan delivers some D, the hands it uses on D are within some h, and objects
outside D can be left untouched without changing cost or any rule — which :func:`spec.untouchable`
proves per rule instance by partial evaluation; objects where that proof fails, and objects held
now, stay free. Of the nodes with hand-overs only the widest per D is searched: it covers the
others.

*Bounds.* Costing one hand only (the other moves for free, so eq. 16 costs it nothing) and
leaving out the rule instances that mention the other hand's objects separates a node into one
program per hand: hand i delivers S_i = {j ∈ D : h_j = i} alone, and the sum of their optima
bounds the node from below. A hand's optimum only grows with S_i (an object can
always be left untouched), so before its program is solved c_i(S) ≥ max over solved subsets.
An object j handed over (h_j = BOTH) is bounded by c(j), both hands delivering j alone. Before
any of these is solved, the route bound (``route.py``) may show that hand i cannot deliver S_i
within the horizon at all.

*Search.* A feasibility pass (first solutions only) decides whether the horizon has a plan and
gives the first incumbent. Then pop the node of least bound; solve what its bound still lacks;
when both hands' programs are solved, put their solutions together and check the joint plan by
re-simulation and direct LTL evaluation (``evaluate.py``, which shares no code with the
encoder): if it passes, the node's optimum is the sum; otherwise the best plan with the same
grasps, and failing that the joint node program, is solved. Stop when the incumbent is no worse
than every open bound.
"""

from __future__ import annotations

import functools
import heapq
import itertools
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np

from dualarm_mpc.evaluate import evaluate
from dualarm_mpc.horizon import HorizonProgram, StepResult, solve_options
from dualarm_mpc.ltl import Atom
from dualarm_mpc.mld import (
    N_HANDS,
    Model,
    Rect,
    State,
    crowding,
    in_goal,
    replay,
    standing,
    violations,
)
from dualarm_mpc.plan import Trajectory
from dualarm_mpc.route import Order, orders, route_steps
from dualarm_mpc.scenario import Scenario
from dualarm_mpc.solver import SolveOptions, Status
from dualarm_mpc.spec import Specification, restricted, untouchable

BOTH = 2  # h_j: either hand may hold object j (a hand-over)
BATCH = 2  # nodes evaluated at once in the best-first loop
# Relaxations solved at once there: more than the workers, so that one long program does not
# leave the other worker idle (measured: bench/search-experiments.md, "Settings of the search").
FETCH = 4
# The feasibility pass gives each program at first this share of the horizon's time limit, then
# four times as much in each later round, until one has a plan or the last round has all the
# time left: one program that runs long (a rule-2 pair at a horizon past its first plan) then
# no longer leaves the horizon undecided while other nodes would have a plan.
FIRST_SLICE = 1 / 16


# --- the search --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Node:
    targets: tuple[int, ...]  # D, the objects it delivers (scenario indices)
    hands: tuple[int, ...]  # h_j for j in D: 0 (arm 1), 1 (arm 2) or BOTH
    free: frozenset[int] = frozenset()  # outside D and not provably untouchable

    def share(self, i: int) -> tuple[int, ...]:
        """S_i: the objects of D that hand i alone delivers."""
        return tuple(j for j, h in zip(self.targets, self.hands, strict=True) if h == i)

    @property
    def handed_over(self) -> tuple[int, ...]:
        return self.share(BOTH)


@dataclass(frozen=True)
class HandKey:
    """The relaxation c_i(S): hand ``hand`` delivers ``share`` alone."""

    hand: int
    share: tuple[int, ...]


@dataclass(frozen=True)
class AloneKey:
    """The relaxation c(j): both hands deliver ``object`` alone."""

    object: int


Key = HandKey | AloneKey  # a relaxation's name


@dataclass
class SearchStats:
    """What the search did."""

    relaxations: int = 0  # one-hand and one-object programs solved
    cpu_time_s: float = 0.0  # of run(), every worker thread included
    timed_out: bool = False  # out of time or interrupted: the result is undecided


@dataclass
class StepSearch:
    """The exact search of one horizon of one sequential step."""

    scenario: Scenario
    state: State
    spec: Specification
    horizon: int
    options: SolveOptions
    handover: str = "auto"  # "auto", "always" or "never": see nodes()
    pool: ThreadPoolExecutor | None = None  # workers for independent relaxations
    stats: SearchStats = field(default_factory=SearchStats)
    # The relaxations with a plan at the horizon below (a step tries its horizons one by one):
    # each plan, idled one more step, stands for this horizon's feasibility probe.
    below: dict[Key, StepResult] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._relax: dict[Key, StepResult] = {}
        self._exact: set[Key] = set()  # keys of the relaxations solved to optimality
        self._witness: StepResult | None = None  # a plan the feasibility pass found
        self._slice = np.inf  # the time a program may take (the feasibility pass's rounds)
        self._composed: dict[Node, StepResult | None] = {}  # compose(node), exact
        # ``auto``: relays are searched once the nodes without them have no plan (see
        # handed_over_objects); the nodes the feasibility pass proved infeasible meanwhile.
        self._relays = False
        self._ruled: set[Node] = set()
        self._deadline = time.perf_counter() + self.options.time_limit_s
        self._program = HorizonProgram(self.scenario, self.state, list(self.spec.objects),
                                       self.horizon)
        self._model = self._program.model
        self._local = {j: n for n, j in enumerate(self.spec.objects)}
        local_grasp = self.state.grasp[:, list(self.spec.objects)]
        self._held = [j for n, j in enumerate(self.spec.objects) if local_grasp[:, n].any()]
        self._no_throw = frozenset(self._local[j] for j in self.spec.released_only_in_goal())

    # -- the subprograms ----------------------------------------------------------------------

    def _stopped(self) -> bool:
        """Out of time or work (``options.work``: read here only, where no worker runs, so
        the search stops at the same place on any machine), or asked to stop
        (``options.interrupt``)."""
        stop, work = self.options.interrupt, self.options.work
        return (time.perf_counter() > self._deadline or (stop is not None and stop.is_set())
                or (work is not None and work.spent()))

    def _solve(self, spec: Specification, allowed: np.ndarray, hands=(0, 1), grasp=None,
               start: StepResult | None = None, floor=None, orders=(),
               exact: bool = True, cutoff: float = np.inf, relaxed: bool = False,
               apart: frozenset = frozenset()) -> StepResult:
        """One subprogram, MIP-started from ``start``'s plan if given; ``exact`` false stops at
        its first solution (a feasibility probe). With a ``cutoff``, "infeasible" means no plan
        cheaper than it (``SolveOptions.cutoff``). ``relaxed``: a relaxation, whose objects
        held still may move in the nodes it bounds (``HorizonProgram.standard_form``).
        ``apart``, and ``start``'s: pairs whose (C1)–(C2) rows it likely needs."""
        remaining = max(min(self._deadline - time.perf_counter(), self._slice), 1e-3)
        options = replace(self.options, time_limit_s=remaining, small_trees=True, cutoff=cutoff)
        if not exact:
            options = replace(options, mip_rel_gap=1.0)
        res = self._program.solve(spec, options, _start(start), allowed=allowed, hands=hands,
                                  grasp=grasp, floor=floor, orders=orders, relaxed=relaxed,
                                  apart=apart if start is None else apart | start.apart)
        if self.options.work is not None:
            self.options.work.spend()
        if res.status is Status.INFEASIBLE and np.isfinite(cutoff):
            return replace(res, bound=cutoff)  # nothing cheaper than the cutoff: its bound
        return res

    def _by_order(self, spec: Specification, allowed: np.ndarray, shares, hands=(0, 1),
                  start: StepResult | None = None, floor=None, exact: bool = True,
                  cutoff: float = np.inf, spread: bool = False, relaxed: bool = False
                  ) -> StepResult:
        """A program split by the order in which each hand delivers its share (``shares``,
        one per hand; see :meth:`_orders`): its optimum is the best of the parts', each part
        solved against the best plan of those before (a cutoff), and a probe stops at the
        first part with a plan. ``start`` starts the part its plan follows. ``spread``: the
        parts of an exact solve run on every worker at once, each against ``cutoff`` alone
        (for a program solved while the other worker would idle)."""
        split = [o for o in (self._orders(i, share) for i, share in shares) if o is not None]
        if not split:
            return self._solve(spec, allowed, hands, start=start, floor=floor, exact=exact,
                               cutoff=cutoff, relaxed=relaxed)
        parts = list(itertools.product(*split))  # the shortest routes first

        def solve(part, exact=exact, cutoff=cutoff):
            return self._solve(spec, allowed, hands, floor=floor, orders=part, exact=exact,
                               start=start if all(_follows(start, o) for o in part) else None,
                               cutoff=cutoff, relaxed=relaxed,
                               apart=frozenset() if start is None else start.apart)

        if spread and exact:
            return _best(self._map(solve, parts))
        results = []
        for part in parts:
            best = min([cutoff] + [r.cost for r in results if r.status.has_solution])
            res = solve(part, cutoff=best if exact else np.inf)
            if not exact and res.status.has_solution:
                return res
            results.append(res)
        return _best(results)

    def _orders(self, i: int, share: tuple[int, ...]) -> list[Order] | None:
        """The orders in which hand i can deliver ``share`` within the horizon
        (``route.orders``), where no-throw (18) holds for all of its objects, at rest and not
        held: every plan then delivers them one after another, and the program of each order
        is much tighter than the whole (no object is grabbed, or in its goal, before its
        order's route allows; for one object, that alone). None where the split does not
        apply."""
        local = tuple(self._local[j] for j in share)
        if not share or not set(local) <= self._no_throw or not self._route(i, share):
            return None
        return orders(self._model, self._program.local_state, i, local, self._no_throw,
                      self.horizon)

    def _mask(self, pairs: Iterable[tuple[int, int]]) -> np.ndarray:
        allowed = np.zeros((N_HANDS, len(self.spec.objects)), bool)
        for i, j in pairs:
            allowed[i, self._local[j]] = True
        return allowed

    def _compute(self, key: Key, exact: bool, cutoff: float = np.inf) -> StepResult:
        # An object held now may stay held by either hand: untouching it is not free (it would
        # slide off), so every relaxation leaves it as the node programs may.
        held = [(i, j) for j in self._held for i in range(N_HANDS)]
        if not exact and key in self.below:
            idled = self._idled(self.below[key], key)
            if idled is not None:
                return idled
        if isinstance(key, AloneKey):
            j = key.object
            return self._solve(restricted(self.spec, (j,), (j,)),
                               self._mask([(i, j) for i in range(N_HANDS)] + held), exact=exact,
                               cutoff=cutoff, relaxed=True)
        i, share = key.hand, key.share
        if self._share_ruled_out(i, share):
            return _INFEASIBLE
        floor = np.zeros(N_HANDS)
        floor[i] = self._hand_bound(i, share)
        if not share and self._idle is not None:
            return self._idle
        probe = self._relax.get(key)  # its first solution starts the exact solve
        if probe is None and key in self.below:  # or the plan of the horizon below
            probe = self._idled(self.below[key], key)
        return self._by_order(restricted(self.spec, share, share),
                              self._mask([(i, j) for j in share] + held), [(i, share)],
                              hands=(i,), floor=floor, start=probe, exact=exact,
                              cutoff=cutoff, relaxed=True)

    def _share_ruled_out(self, i: int, share: tuple[int, ...]) -> bool:
        """Whether c_i(share) is infeasible without a solve: a subset is (the cheaper test), or
        the route exceeds the horizon."""
        return np.isinf(self._hand_bound(i, share)) or self._route(i, share) > self.horizon

    def _route(self, i: int, share: tuple[int, ...]) -> int:
        """The route bound (``route.py``), counted up to the horizon: more steps than the
        horizon and hand i cannot deliver ``share`` in it, whatever the rest of the plan does."""
        return route_steps(self._model, self._program.local_state, i,
                           tuple(self._local[j] for j in share), self._no_throw, self.horizon)

    def _idled(self, plan: StepResult, key: Key) -> StepResult | None:
        """``plan`` of the horizon below with one more step of rest, if it is a plan of this
        horizon's relaxation ``key`` (re-simulated and checked: true whenever the relaxation's
        specification survives idling, as the paper's rules do)."""
        traj = plan.trajectory
        if traj is None or len(traj.force) != self.horizon - 1:
            return None
        traj = replay(self._model, self._program.local_state,
                      np.concatenate([traj.force, np.zeros((1, N_HANDS, 2))]),
                      np.concatenate([traj.grasp, traj.grasp[-1:]]))
        share = (key.object,) if isinstance(key, AloneKey) else key.share
        if not self._feasible(traj, restricted(self.spec, share, share)):
            return None
        return StepResult.replayed(Status.FEASIBLE, self.horizon, traj, plan.cost, gap=np.inf)

    @functools.cached_property
    def _idle(self) -> StepResult | None:
        """The plan of no force and no grasp, optimal at cost zero for a hand with nothing to
        deliver if it satisfies the model and what is left of the rules (where nothing is held
        or moving): that hand's relaxation needs no solve."""
        if self._held or np.abs(self.state.hand_vel).max(initial=0) > 0:
            return None
        n = len(self.spec.objects)
        traj = replay(self._model, self._program.local_state, np.zeros((self.horizon, N_HANDS, 2)),
                      np.zeros((self.horizon + 1, N_HANDS, n), int))
        if not self._feasible(traj, restricted(self.spec, (), ())):
            return None
        return StepResult.replayed(Status.OPTIMAL, self.horizon, traj, 0.0)

    def _wanted(self, key: Key, exact: bool) -> bool:
        """Not known yet: a probe's answer stands for an exact one only when "infeasible"."""
        res = self._relax.get(key)
        return res is None or (exact and key not in self._exact and res.status.has_solution)

    def fetch(self, requests: Iterable[tuple[Key, bool]], cutoff: float = np.inf) -> None:
        """Solve the relaxations asked for and not known yet, on every worker at once. With a
        ``cutoff`` (the incumbent), a relaxation that cannot go below it is closed with the
        cutoff as its bound: every node with it is then no better than the incumbent."""
        # The larger share of a balanced node (one object when m_o ≤ 2, a pair when m_o = 3)
        # is solved to optimality even when only probed: that costs little more than its first
        # solution, and at a horizon with a plan the nodes' bounds need it anyway. Other shares
        # stay probes: with m_o = 3 the singles are mostly asked at horizons the pairs rule
        # out, where an exact solve is wasted (bench/search-experiments.md, "Settings of the
        # search").
        requests = [(k, e or self._larger(k)) for k, e in requests]
        todo = list(dict.fromkeys((k, e) for k, e in requests if self._wanted(k, e)))
        results = self._map(lambda ke: self._compute(*ke, cutoff=cutoff), todo)
        for (key, exact), res in zip(todo, results, strict=True):
            self._relax[key] = res
            self.stats.relaxations += 1
            if exact:
                self._exact.add(key)

    def _larger(self, key: Key) -> bool:
        """Whether ``key`` is the larger share of a balanced node (see :meth:`fetch`)."""
        return isinstance(key, HandKey) and len(key.share) == (self.spec.m_o + 1) // 2

    def _map(self, f, items: list) -> list:
        """``f`` over ``items``, on every worker at once."""
        if len(items) > 1 and self.pool is not None:
            return list(self.pool.map(f, items))
        return [f(item) for item in items]

    def relaxations_with_plans(self) -> dict[Key, StepResult]:
        """The relaxations solved so far that have a plan (for :attr:`below` of the next
        horizon)."""
        return {k: r for k, r in self._relax.items() if r.status.has_solution}

    def relaxation(self, key: Key, exact: bool = True) -> StepResult:
        self.fetch([(key, exact)])
        return self._relax[key]

    def hand(self, i: int, share: tuple[int, ...], exact: bool = True) -> StepResult:
        """c_i(S): hand i delivers ``share`` alone; the other hand holds nothing, costs nothing."""
        return self.relaxation(HandKey(i, share), exact)

    def alone(self, j: int, exact: bool = True) -> StepResult:
        """c(j): both hands deliver object j, every other object untouched."""
        return self.relaxation(AloneKey(j), exact)

    def _node_spec(self, node: Node) -> Specification:
        return replace(self.spec, targets=node.targets, m_o=len(node.targets),
                       task_form="counting")

    def joint(self, node: Node, start: StepResult | None = None, exact: bool = True,
              cutoff: float = np.inf, spread: bool = False) -> StepResult:
        """The node's own program: the monolithic one restricted to the skeleton; with a
        ``cutoff``, "infeasible" means no plan cheaper than it."""
        pairs = [(i, j) for j, h in zip(node.targets, node.hands, strict=True)
                 for i in range(N_HANDS) if h in (i, BOTH)]
        pairs += [(i, j) for j in node.free for i in range(N_HANDS)]
        floor = np.array([self._hand_bound(i, node.share(i)) for i in range(N_HANDS)])
        return self._by_order(self._node_spec(node), self._mask(pairs),
                              [(i, node.share(i)) for i in range(N_HANDS)], start=start,
                              floor=floor, exact=exact, cutoff=cutoff, spread=spread)

    # -- bounds -------------------------------------------------------------------------------

    def _hand_bound(self, i: int, share: tuple[int, ...]) -> float:
        """A lower bound on c_i(share): its own if solved, else the best of its solved subsets."""
        best = 0.0
        for key, res in list(self._relax.items()):
            if isinstance(key, HandKey) and key.hand == i and set(key.share) <= set(share) \
                    and self._proven(key, res):
                best = max(best, _bound(res))
        return best

    def _proven(self, key, res: StepResult) -> bool:
        return key in self._exact or res.status is Status.INFEASIBLE

    def bound(self, node: Node) -> float:
        split = sum(self._hand_bound(i, node.share(i)) for i in range(N_HANDS))
        alone = [_bound(self._relax[AloneKey(j)]) for j in node.targets
                 if self._proven(AloneKey(j), self._relax.get(AloneKey(j), _UNKNOWN))]
        return max([split] + alone)

    def missing(self, node: Node) -> list[Key]:
        """The relaxations the node's bound still lacks."""
        keys = [AloneKey(j) for j in node.handed_over]
        keys += [HandKey(i, node.share(i)) for i in range(N_HANDS)]
        return [k for k in keys if not self._proven(k, self._relax.get(k, _UNKNOWN))]

    # -- putting the hands together -----------------------------------------------------------

    def compose(self, node: Node, exact: bool = True) -> StepResult | None:
        """The joint plan made of each hand's own solution, if the model and the whole
        specification (task, every rule, eq. 16) hold on its re-simulated trace; else the best
        joint plan with the same grasps (a small MILP over θ alone), or None."""
        if exact and node in self._composed:
            return self._composed[node]
        parts = [self.hand(i, node.share(i), exact) for i in range(N_HANDS)]
        force = np.stack([parts[i].trajectory.force[:, i] for i in range(N_HANDS)], axis=1)
        grasp = np.stack([parts[i].trajectory.grasp[:, i] for i in range(N_HANDS)], axis=1)
        traj = replay(self._model, self._program.local_state, force, grasp)
        apart = parts[0].apart | parts[1].apart
        if self._feasible(traj, self.spec):
            status = (Status.OPTIMAL if all(p.status is Status.OPTIMAL for p in parts)
                      else Status.FEASIBLE)
            plan = StepResult.replayed(status, self.horizon, traj, float(np.abs(force).sum()),
                                        apart=apart)
        else:
            plan = self._solve(self._node_spec(node), self._mask([]), grasp=grasp, exact=exact,
                               apart=apart)
            plan = plan if plan.status.has_solution else None
        if exact:
            self._composed[node] = plan
        return plan

    def _composable(self, node: Node, below: float) -> bool:
        """Whether the node's composed plan is cheap to get and may improve on ``below``: its
        hands' relaxations are solved and its bound is under it."""
        return not (node.handed_over or node.free or node in self._composed
                    or self.missing(node)) and self.bound(node) < below

    def improve(self, nodes: Iterable[Node], best: StepResult | None, limit: float = np.inf
                ) -> StepResult | None:
        """``best``, or the cheapest composed plan of ``nodes`` if better and below ``limit``:
        a few hundredths of a second each, where a node's joint program takes seconds and runs
        faster against a lower incumbent (its cutoff)."""
        todo = [n for n in nodes
                if self._composable(n, limit * (1 - self.options.mip_rel_gap))]
        for plan in self._map(self.compose, todo):
            if plan is not None and plan.cost < min(limit, self._limit(best)):
                best = plan
        return best

    def _limit(self, best: StepResult | None) -> float:
        """What a plan must cost less than to matter: the best so far."""
        return np.inf if best is None else best.cost

    def _feasible(self, traj, spec: Specification) -> bool:
        return satisfies(self.scenario, self.state, spec, self._model, traj)

    # -- best-first ---------------------------------------------------------------------------

    def handed_over_objects(self) -> set[int]:
        """The objects with hand-over labels: every one with ``always``; none with ``never``;
        with ``auto`` those that neither hand can deliver alone but both together can, and,
        once a round of the feasibility pass found no plan without a relay (:meth:`feasible`),
        every object a hand may put down outside its goal for the other to pick up."""
        if self.handover != "auto":
            return set(self.spec.objects) if self.handover == "always" else set()
        return self._needed() | (self._relayable() if self._relays else set())

    def _relayable(self) -> set[int]:
        """The objects a relay can carry: those a hand may release outside their goal (not
        under no-throw), to be picked up there by the other hand."""
        return {j for j in self.spec.objects if self._local[j] not in self._no_throw}

    def _needed(self) -> set[int]:
        """The objects neither hand can deliver alone but both together can."""
        alone = list(self.spec.objects)
        for i in range(N_HANDS):  # an object one hand delivers needs no second probe
            self.fetch((HandKey(i, (j,)), False) for j in alone)
            alone = [j for j in alone
                     if self._relax[HandKey(i, (j,))].status is Status.INFEASIBLE]
        # Under no-throw (18) the first hand to hold j holds it until it is in its goal, so
        # its route bounds c(j)'s horizon too: beyond it for both hands, c(j) has no plan (the
        # route is 0, no bound, for an object held or moving now).
        alone = [j for j in alone if self._local[j] not in self._no_throw
                 or min(self._route(i, (j,)) for i in range(N_HANDS)) <= self.horizon]
        self.fetch((AloneKey(j), False) for j in alone)
        return {j for j in alone if self._relax[AloneKey(j)].status is not Status.INFEASIBLE}

    def nodes(self, handed_over: bool = True) -> list[Node]:
        """The skeletons (D, h) the search covers the plans with: every one with one hand per
        object, and unless not ``handed_over``, for each D the widest with hand-overs: every
        object of D that may be handed over (:meth:`handed_over_objects`) labelled BOTH, the
        others one hand each. A widest node's plans include those of every node that labels
        some of these objects with one hand only, so those are left out: one probe or one
        solve decides them all, where each of them would need its own. Without hand-over
        labels for every object, the search is exact over the plans in which each object is
        held by one hand at most; with them (``always``), against the monolithic MILP."""
        single = [Node(targets, hands, free) for targets, free in self._target_sets
                  for hands in itertools.product((0, 1), repeat=len(targets))]
        return single + self._widest() if handed_over else single

    @functools.cached_property
    def _target_sets(self) -> list[tuple[tuple[int, ...], frozenset[int]]]:
        """Every D, with its free objects (outside D and not provably untouchable)."""
        deliveries = []
        for targets in itertools.combinations(self.spec.objects, self.spec.m_o):
            quiet = untouchable(self.spec, self.state, targets)
            deliveries.append((targets, frozenset(
                j for j in self.spec.objects if j not in targets and j not in quiet)))
        return deliveries

    def _widest(self) -> list[Node]:
        """The widest nodes with hand-overs of each D (see :meth:`nodes`): one, unless some
        object of D may not be handed over."""
        both = self.handed_over_objects()
        return [Node(targets, hands, free) for targets, free in self._target_sets
                if both.intersection(targets)
                for hands in itertools.product(*[(BOTH,) if j in both else (0, 1)
                                                 for j in targets])]

    def _probe_order(self):
        """The nodes as :meth:`ruled_out` visits them: one hand per object first, then
        hand-overs (which need every single-hand relaxation to know which objects get them,
        so they are listed only if the first are all ruled out)."""
        yield from self.nodes(handed_over=False)
        yield from self._widest()

    def feasible(self) -> bool:
        """Whether the horizon admits a plan, decided with feasibility probes (first solutions,
        no optimality): a node is feasible when its relaxations are and its hands' plans fit
        together or its joint program has a solution. Infeasible relaxations found here serve
        the optimization too, and a plan found is its first incumbent.

        In rounds: each program may take ``FIRST_SLICE`` of the time limit, four times as much
        in the next round, which solves again only what ran out of time; the last round has
        all the time left. A node left undecided does not stop a round, so a node with a plan
        later in the order is still found; the horizon is infeasible only when every node is
        proven so, as without rounds.

        With ``auto`` hand-overs, a round that finds no plan among the nodes with one hand per
        object (none has one, or one ran out of its slice) turns to relays
        (:meth:`handed_over_objects`): from then on the widest relay nodes, which cover every
        plan, alone decide the horizon. A relay can make a horizon feasible that is not
        without one, and the step's horizon is that of Algorithm 1 only if "infeasible" covers
        every plan; nor are relays left for the proof that no other node has a plan, the slow
        part where they matter (bench/search-experiments.md, "Settings of the search")."""
        self._slice = FIRST_SLICE * self.options.time_limit_s
        try:
            while True:
                last = self._slice >= self._deadline - time.perf_counter()
                if self._feasible_round():
                    self.stats.timed_out = False  # a plan decides the horizon
                    return True
                if not self.stats.timed_out or last or self._stopped():
                    # Undecided: True, so that run() reports the time limit, not infeasibility.
                    return self.stats.timed_out
                self._forget_timed_out()
                self.stats.timed_out = False
                self._slice *= 4
        finally:
            self._slice = np.inf
            self._forget_timed_out()  # cut short by a slice: the optimization solves them again

    def _forget_timed_out(self) -> None:
        out = {k for k, r in self._relax.items() if r.status is Status.TIME_LIMIT}
        for key in out:
            del self._relax[key]
        self._exact -= out

    def _feasible_round(self) -> bool:
        """One round of :meth:`feasible`: True when it found a plan (the witness); else
        ``stats.timed_out`` says whether a node was left undecided."""
        if not self._relays:
            may_relay = self.handover == "auto" and bool(self._relayable() - self._needed())
            if self._probe(stop_undecided=may_relay):
                return True
            if may_relay and not self._stopped():
                self._relays = True
                self.stats.timed_out = False  # what the nodes left open, the widest decide
        return self._probe_widest()

    def _probe_widest(self) -> bool:
        """Probe the widest nodes with relays, which cover every plan and so alone decide the
        horizon, on every worker at once (a joint program each: one would leave the other
        worker idle): True when one has a plan (the witness)."""
        wide = [n for n in self._widest() if n not in self._ruled]
        relaxed = [self._relaxations_feasible(n) for n in wide]
        self.stats.timed_out |= None in relaxed
        self._ruled.update(n for n, r in zip(wide, relaxed, strict=True) if r is False)
        wide = [n for n, r in zip(wide, relaxed, strict=True) if r]
        for at in range(0, len(wide), BATCH):
            if self._stopped():
                self.stats.timed_out = True
                return False
            batch = wide[at:at + BATCH]
            probes = self._map(lambda n: self.joint(n, exact=False), batch)
            for node, probe in zip(batch, probes, strict=True):
                if self._settle(node, probe):
                    return True
        return False

    def _settle(self, node: Node, probe: StepResult) -> bool | None:
        """What the feasibility probe of ``node`` decided: a plan (the witness, True), none
        (the node is ruled out, False), or nothing in its time (None)."""
        if probe.status.has_solution:
            self._witness = probe
            return True
        if probe.status is Status.INFEASIBLE:
            self._ruled.add(node)
            return False
        self.stats.timed_out = True
        return None

    def _probe(self, stop_undecided: bool = False) -> bool:
        """Probe the nodes with one hand per object in turn until one has a plan (the witness,
        True), or with ``stop_undecided`` one is left undecided; the relaxations of the nodes
        after each are fetched beside its own."""
        single_hand = self.nodes(handed_over=False)
        for n, node in enumerate(single_hand):
            if self._stopped():
                self.stats.timed_out = True
                break
            if node in self._ruled:
                continue
            if n == 1:  # past the first guess, most singles will be needed: all at once
                self.fetch((HandKey(i, (j,)), False)
                           for j in self.spec.objects for i in range(N_HANDS))
            # and so will the larger shares of the nodes after it: a few at once
            relaxed = self._relaxations_feasible(
                node, self._ahead(single_hand[n + 1:]) if n else ())
            if relaxed is None:  # a relaxation ran out of time: the node is undecided
                self.stats.timed_out = True
                if stop_undecided:
                    break
                continue
            if not relaxed:
                self._ruled.add(node)
                continue
            witness = None if node.free else self.compose(node, exact=False)
            if witness is None:
                witness = self.joint(node, exact=False)
            settled = self._settle(node, witness)
            if settled:
                return True
            if settled is None and stop_undecided:
                break
        return False

    def _relaxations_feasible(self, node: Node, ahead: Iterable[Key] = ()) -> bool | None:
        """True when every relaxation of the node has a solution, False when one is proven
        infeasible, None when one ran out of time (undecided). The ``ahead`` relaxations are
        probed beside the node's, on the workers its own leave idle."""
        keys = [AloneKey(j) for j in node.handed_over]
        keys += [HandKey(i, node.share(i)) for i in range(N_HANDS)]
        self.fetch((k, False) for k in keys + list(ahead))
        statuses = [self._relax[k].status for k in keys]
        if Status.INFEASIBLE in statuses:
            return False
        return True if all(st.has_solution for st in statuses) else None

    def _ahead(self, nodes: Iterable[Node]) -> list[Key]:
        """The larger shares (solved exactly, see :meth:`fetch`) that the probes of ``nodes``
        will ask for next, up to :data:`FETCH`: unknown, and not ruled out without a solve (by
        an infeasible subset or the route). They would be solved one after another, on one
        worker; at a horizon with a plan the best-first loop wants their bounds anyway. (Not
        all shares ahead: those probe pairs a plan never needs.)"""
        keys: list[Key] = []
        for node in nodes:
            for i in range(N_HANDS):
                key = HandKey(i, node.share(i))
                if key not in keys and self._larger(key) and self._wanted(key, False) \
                        and not self._share_ruled_out(i, node.share(i)):
                    keys.append(key)
            if len(keys) >= FETCH:
                break
        return keys[:FETCH]

    def ruled_out(self) -> bool:
        """Whether the relaxations alone prove that the horizon has no plan: every node has an
        infeasible one, relays included. Stops at the first node that they cannot rule out (a
        cheap check: no joint program is solved)."""
        self._relays = True
        for node in self._probe_order():
            if self._relaxations_feasible(node) is not False:
                return False
        return True

    def evaluate(self, node: Node, incumbent: float = np.inf, spread: bool = False
                 ) -> StepResult:
        """The node's optimum if it is below ``incumbent`` ("infeasible" if none is): composed
        from both hands' solutions when they fit together (directly or with their grasps
        kept), else the joint node program, solved against the better of the two (its order
        parts on every worker at once with ``spread``)."""
        if node.handed_over or node.free:
            return self.joint(node, cutoff=incumbent, spread=spread)
        lb = self.bound(node)
        composed = self.compose(node)
        if composed is not None and composed.cost <= lb * (1 + self.options.mip_rel_gap) + 1e-9:
            return composed
        if composed is None:
            return self.joint(node, cutoff=incumbent, spread=spread)
        res = self.joint(node, start=composed, cutoff=min(incumbent, composed.cost),
                         spread=spread)
        if res.cost <= composed.cost:
            return res
        if res.status in (Status.OPTIMAL, Status.INFEASIBLE):
            return composed  # nothing cheaper: the composed plan is the node's optimum
        # The joint program ran out before it proved that: the node is still open.
        return replace(composed, status=Status.FEASIBLE, bound=_bound(res))

    def run(self) -> StepResult:
        """The optimum of the horizon (as the monolithic MILP), or why there is none."""
        t0, cpu0 = time.perf_counter(), time.process_time()
        gap = self.options.mip_rel_gap
        counter = itertools.count()
        heap = [(0.0, next(counter), n) for n in self.nodes()]
        heapq.heapify(heap)
        best: StepResult | None = self._witness
        undecided = np.inf  # the least bound of a node the solver could not close
        while heap:
            key, _, node = heapq.heappop(heap)
            lb = self.bound(node)
            if lb > key:  # bounds only grow: a stale key goes back in its place
                heapq.heappush(heap, (lb, next(counter), node))
                continue
            if np.isinf(lb):
                continue  # a relaxation is infeasible: so is the node
            limit = self._limit(best)
            if lb >= limit * (1 - gap) - 1e-9:
                heapq.heappush(heap, (lb, next(counter), node))
                break
            if self._stopped():
                heapq.heappush(heap, (lb, next(counter), node))
                self.stats.timed_out = True
                break
            need = self.missing(node)
            if need:
                # The next nodes' needs too: they are likely to come next. A fixed batch (not
                # one per worker) keeps the search, and the plan it picks among equal optima,
                # the same whatever the number of workers.
                for _, _, other in heapq.nsmallest(FETCH, heap):
                    need += self.missing(other)
                self.fetch(((k, True) for k in need[:FETCH]), cutoff=limit)
                heapq.heappush(heap, (self.bound(node), next(counter), node))
                continue
            # Before a joint program, the cheap plans of every node with complete bounds: a
            # better incumbent cuts the joint programs short, or this one off.
            improved = self.improve([node] + [n for _, _, n in sorted(heap)], best, limit)
            if improved is not best:
                best = improved
                heapq.heappush(heap, (lb, next(counter), node))
                continue
            # The next nodes whose bounds are complete and below the incumbent are evaluated
            # beside it, against the same incumbent: usually they would be next anyway.
            batch = [(lb, node)]
            while heap and len(batch) < BATCH:
                _, _, other = heap[0]
                lb_other = self.bound(other)
                if self.missing(other) or np.isinf(lb_other) or \
                        lb_other >= limit * (1 - gap) - 1e-9:
                    break
                heapq.heappop(heap)
                batch.append((lb_other, other))
            lone = len(batch) == 1  # then it spreads its order parts over the workers instead
            results = self._map(lambda n, cut=limit, spread=lone: self.evaluate(
                n, cut, spread), [n for _, n in batch])
            for (lb_node, _), res in zip(batch, results, strict=True):
                if res.status.has_solution and res.cost < self._limit(best):
                    best = res
                if res.status in (Status.FEASIBLE, Status.TIME_LIMIT):
                    undecided = min(undecided, max(lb_node, _bound(res)))
        open_bound = min([undecided] + [self.bound(n) for _, _, n in heap])
        self.stats.cpu_time_s = time.process_time() - cpu0
        wall = time.perf_counter() - t0
        return self.result(best, open_bound, wall)

    def result(self, best: StepResult | None, open_bound: float, wall: float) -> StepResult:
        """The horizon's result: ``best`` with the status and gap its ``open_bound`` allows, or
        no plan (infeasible when the bound is infinite, else undecided)."""
        binaries = 3 * (self.horizon + 1) * len(self.spec.objects)
        if best is None:
            status = Status.INFEASIBLE if open_bound == np.inf else Status.TIME_LIMIT
            return StepResult.no_plan(status, self.horizon, open_bound, wall, binaries)
        lower = min(open_bound, best.cost)
        gap = max(0.0, (best.cost - lower) / max(abs(best.cost), 1e-12))
        status = Status.OPTIMAL if gap <= self.options.mip_rel_gap + 1e-9 else Status.FEASIBLE
        return replace(best, status=status, solve_time_s=wall, build_time_s=0.0, gap=gap,
                       binaries=binaries, bound=lower)


def satisfies(scenario: Scenario, state: State, spec: Specification, model: Model,
              traj: Trajectory) -> bool:
    """Whether ``traj`` (over ``spec``'s objects, from ``state``) keeps the model's
    constraints (the objects' spacing, (C1)–(C3), included), ends at rest and satisfies ``spec``
    (evaluated on its trace by ``evaluate.py``, which shares no code with the encoder)."""
    if violations(model, traj) or np.abs(traj.object_vel[-1]).max(initial=0) > 1e-9:
        return False
    if crowding(model, traj, *standing(state, list(spec.objects), model.dt)):
        return False
    local = {j: n for n, j in enumerate(spec.objects)}
    goals = [Rect.of(scenario.task.goals[o.goal]) for o in scenario.task.objects]

    def value(atom: Atom, k: int) -> bool:
        n = local.get(atom.index[-1] - 1)
        if atom.name == "eta":
            return False if n is None else bool(traj.grasp[k, atom.index[0] - 1, n])
        if n is None:
            return bool(in_goal(state.object_pos[atom.index[0] - 1], goals[atom.index[0] - 1]))
        return bool(in_goal(traj.object_pos[k, n], model.goals[n]))

    return evaluate(spec.formula(), value, len(traj.force))


_UNKNOWN = StepResult.no_plan(Status.ERROR, 0)
_INFEASIBLE = replace(_UNKNOWN, status=Status.INFEASIBLE, bound=np.inf)


def _start(plan: StepResult | None):
    """A MIP start from ``plan``: its solver values, or else (a plan re-simulated, not solved)
    its forces and grasps, which the solver completes."""
    if plan is None or plan.trajectory is None:
        return None
    if plan.solution is not None:
        return lambda x, v=plan.solution: v
    traj = plan.trajectory
    return lambda x: (np.concatenate([x.force.ravel(), x.eta.ravel()]),
                      np.concatenate([traj.force.ravel(), traj.grasp.ravel()]).astype(float))


def _follows(plan: StepResult | None, order: Order) -> bool:
    """Whether ``plan``'s hand first grabs the objects of ``order`` in its order."""
    if plan is None or plan.trajectory is None:
        return False
    grasp = plan.trajectory.grasp[1:, order.hand]
    first = [int(np.argmax(grasp[:, n])) if grasp[:, n].any() else len(grasp)
             for n in order.objects]
    return first == sorted(first)


def _best(results: list[StepResult]) -> StepResult:
    """The best of a program's parts (which together cover its plans): its solution, and the
    least of their bounds; optimal when every part is closed."""
    bound = min((_bound(r) for r in results), default=np.inf)
    found = [r for r in results if r.status.has_solution]
    if not found:
        undecided = [r for r in results if r.status is not Status.INFEASIBLE]
        return replace(undecided[0] if undecided else _INFEASIBLE, bound=bound)
    best = min(found, key=lambda r: r.cost)
    closed = all(r.status in (Status.OPTIMAL, Status.INFEASIBLE) for r in results)
    return replace(best, status=Status.OPTIMAL if closed else Status.FEASIBLE,
                   bound=min(bound, best.cost))


def _bound(res: StepResult) -> float:
    """A proven lower bound of a subprogram: +inf when it is infeasible, its cutoff when it
    has nothing cheaper."""
    if res.status is Status.INFEASIBLE:
        return res.bound
    if res.status is Status.OPTIMAL:
        return max(min(res.bound, res.cost), 0.0) if np.isfinite(res.bound) else res.cost
    return max(res.bound, 0.0) if np.isfinite(res.bound) else 0.0


@contextmanager
def _searching(scenario: Scenario, state: State, spec: Specification, horizon: int,
               options: SolveOptions | None, below: dict[Key, StepResult] | None = None):
    """A :class:`StepSearch` with the scenario's workers, for the length of a ``with``."""
    options = options or solve_options(scenario)
    with ThreadPoolExecutor(scenario.solver.workers) as pool:
        yield StepSearch(scenario, state, spec, horizon, options, scenario.solver.handover, pool,
                         below={} if below is None else below)


def horizon_ruled_out(scenario: Scenario, state: State, spec: Specification, horizon: int,
                      time_limit_s: float, options: SolveOptions | None = None) -> bool:
    """Whether the one-hand and one-object relaxations prove that ``horizon`` has no plan
    (within ``time_limit_s``; False when they cannot tell, or ``options.interrupt`` stops
    them)."""
    options = replace(options or solve_options(scenario), time_limit_s=time_limit_s)
    with _searching(scenario, state, spec, horizon, options) as search:
        return search.ruled_out()


def horizon_has_plan(scenario: Scenario, state: State, spec: Specification, horizon: int,
                     options: SolveOptions | None = None) -> Status:
    """Whether ``horizon`` admits a plan (the feasibility pass alone): ``FEASIBLE``,
    ``INFEASIBLE``, or ``TIME_LIMIT`` when the time limit left it undecided."""
    with _searching(scenario, state, spec, horizon, options) as search:
        found = search.feasible()
    if search.stats.timed_out:
        return Status.TIME_LIMIT
    return Status.FEASIBLE if found else Status.INFEASIBLE


def search_step(scenario: Scenario, state: State, spec: Specification, horizon: int,
                options: SolveOptions | None = None,
                below: dict[Key, StepResult] | None = None) -> StepResult:
    """The skeleton search of one horizon; the same optimum as :func:`horizon.solve_step`.
    ``below``: the relaxations with a plan at ``horizon − 1`` (:attr:`StepSearch.below`),
    replaced by this horizon's, for the next horizon of the same step."""
    t0 = time.perf_counter()
    with _searching(scenario, state, spec, horizon, options, below) as search:
        if search.feasible():
            res = search.run()
        else:
            res = search.result(None, np.inf, time.perf_counter() - t0)
    if below is not None:
        below.clear()
        below.update(search.relaxations_with_plans())
    return replace(res, solve_time_s=time.perf_counter() - t0)
