"""Exact step search over the discrete skeleton: which objects, which hand (docs/search.md).

The monolithic MILP of one horizon has an LP relaxation whose bound is zero (a fractional η moves
an object while the hands' fractions cancel), so HiGHS proves optimality and infeasibility by
enumeration alone. This module splits the same MILP along its discrete skeleton and searches it
best-first with admissible bounds; with hand-overs allowed for every object (``handover:
always``) it returns the monolithic optimum of the same horizon; by default (``auto``) the
same at a horizon that has no plan without a relay, else the optimum over the plans that hand
over only the objects no single hand can deliver.

*Skeleton node* (D, h) (``subprograms.Node``): the set D of m_o objects whose delivery satisfies
φ_task (13), and for each j ∈ D the hand h_j that may hold it (1, 2, or ``BOTH`` for a
hand-over). The node's program is the monolithic one with η_ij(k ≥ 1) = 0 outside the skeleton
and φ_task replaced by "every j ∈ D delivered": a restriction, so its optimum is never below the
monolithic one. The nodes cover every plan (:class:`Skeleton`): a plan delivers some D, the
hands it uses on D are within some h, and objects outside D can be left untouched without
changing cost or any rule — which :func:`~dualarm_mpc.model.spec.untouchable` proves per rule
instance by partial evaluation; objects where that proof fails, and objects held now, stay free. Of
the nodes with hand-overs only the widest per D is searched: it covers the others.

*Bounds* (``relaxations.py``): the one-hand relaxations c_i(S_i) of a node's shares, summed,
and c(j) of an object handed over, bound the node from below.

*Search.* A feasibility pass (:class:`FeasibilityPass`, first solutions only) decides whether
the horizon has a plan and gives the first incumbent. Then the best-first optimiser
(:class:`BestFirst`) pops the node of least bound; solves what its bound still lacks; when both
hands' programs are solved, puts their solutions together and checks the joint plan by
re-simulation and direct LTL evaluation (``evaluate.py``, which shares no code with the
encoder): if it passes, the node's optimum is the sum; otherwise the best plan with the same
grasps, and failing that the joint node program, is solved. It stops when the incumbent is no
worse than every open bound.

Why one module of this length: the skeleton, the feasibility pass and the best-first optimiser
are one search's phases over the same nodes and the same relaxation store, each its own class of
under 170 lines, kept side by side so that the search reads in the order it runs.
"""

from __future__ import annotations

import functools
import heapq
import itertools
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from dualarm_mpc.milp.horizon import StepResult, solve_options
from dualarm_mpc.milp.solver import SolveOptions, Status
from dualarm_mpc.model.mld import N_HANDS
from dualarm_mpc.model.spec import StepProblem, untouchable
from dualarm_mpc.search.relaxations import (
    FETCH,
    AloneKey,
    HandKey,
    Key,
    RelaxationSolver,
    RelaxationStore,
    solve_relaxation,
)
from dualarm_mpc.search.subprograms import BOTH, WAVE, Node, StepPrograms, lower_bound

BATCH = 2  # nodes evaluated at once in the best-first loop
# The feasibility pass gives each program at first this share of the horizon's time limit, then
# four times as much in each later round, until one has a plan or the last round has all the
# time left: one program that runs long (a rule-2 pair at a horizon past its first plan) then
# no longer leaves the horizon undecided while other nodes would have a plan.
FIRST_SLICE = 1 / 16
# Up to this m_o a node's smaller share is a single object often enough that the pass probes
# every single at once; past it (a whole task) a single is a share only beside a share of
# m_o − 1, which the route mostly rules out, and its probe, seconds at a long horizon, is waste.
SINGLES_M_O = 3


class Skeleton:
    """The skeleton nodes (D, h) of one horizon that cover its plans (docs/search.md, "Skeleton
    nodes", "Hand-overs"): every one with one hand per object, and for each D the widest with
    hand-overs. ``handover`` (``solver.handover``) says which objects get the label BOTH."""

    def __init__(self, programs: StepPrograms, store: RelaxationStore, handover: str) -> None:
        self.programs, self.store, self.handover = programs, store, handover

    @functools.cached_property
    def _target_sets(self) -> list[tuple[tuple[int, ...], frozenset[int]]]:
        """Every D, with its free objects (outside D and not provably untouchable)."""
        spec, deliveries = self.programs.spec, []
        for targets in itertools.combinations(spec.objects, spec.m_o):
            quiet = untouchable(spec, self.programs.state, targets)
            deliveries.append((targets, frozenset(
                j for j in spec.objects if j not in targets and j not in quiet)))
        return deliveries

    def single_hand(self) -> list[Node]:
        """Every node with one hand per object, the first one giving every object to arm 1."""
        return [Node(targets, hands, free) for targets, free in self._target_sets
                for hands in itertools.product((0, 1), repeat=len(targets))]

    def nodes(self, relays: bool) -> list[Node]:
        """The nodes the search covers the plans with: those with one hand per object, and for
        each D the widest with hand-overs (:meth:`widest`). A widest node's plans include those
        of every node that labels some of its BOTH objects with one hand only, so those are
        left out: one probe or one solve decides them all, where each of them would need its
        own. Without hand-over labels for every object, the search is exact over the plans in
        which each object is held by one hand at most; with them (``always``), against the
        monolithic MILP. ``relays``: relay nodes too (:meth:`handed_over_objects`)."""
        return self.single_hand() + self.widest(relays)

    def widest(self, relays: bool, slice_s: float = np.inf) -> list[Node]:
        """The widest nodes with hand-overs of each D: every object of D that may be handed
        over (:meth:`handed_over_objects`) labelled BOTH, the others one hand each; one per D,
        unless some object of D may not be handed over."""
        both = self.handed_over_objects(relays, slice_s)
        return [Node(targets, hands, free) for targets, free in self._target_sets
                if both.intersection(targets)
                for hands in itertools.product(*[(BOTH,) if j in both else (0, 1)
                                                 for j in targets])]

    def handed_over_objects(self, relays: bool, slice_s: float = np.inf) -> set[int]:
        """The objects with hand-over labels: every one with ``always``; none with ``never``;
        with ``auto`` those that neither hand can deliver alone but both together can, and with
        ``relays`` (once the feasibility pass found no plan without them) every object a hand
        may put down outside its goal for the other to pick up."""
        if self.handover != "auto":
            return set(self.programs.spec.objects) if self.handover == "always" else set()
        return self.needed(slice_s) | (self.relayable() if relays else set())

    def relayable(self) -> set[int]:
        """The objects a relay can carry: those a hand may release outside their goal (not
        under no-throw), to be picked up there by the other hand."""
        p = self.programs
        return {j for j in p.spec.objects if p.local[j] not in p.no_throw}

    def needed(self, slice_s: float = np.inf) -> set[int]:
        """The objects neither hand can deliver alone but both together can (decided by
        probes, each within ``slice_s``). A hand that has a plan for a share delivers each of
        its objects alone (c_i(S) only grows with S): those objects need no probe, and after
        a plan of a whole task, none does."""
        p, store = self.programs, self.store
        alone = [j for j in p.spec.objects if not store.delivered_alone(j)]
        for i in range(N_HANDS):  # an object one hand delivers needs no second probe
            store.fetch(((HandKey(i, (j,)), False) for j in alone), slice_s=slice_s)
            alone = [j for j in alone if store.status(HandKey(i, (j,))) is Status.INFEASIBLE]
        # Under no-throw (18) the first hand to hold j holds it until it is in its goal, so
        # its route bounds c(j)'s horizon too: beyond it for both hands, c(j) has no plan (the
        # route is 0, no bound, for an object held or moving now).
        alone = [j for j in alone if p.local[j] not in p.no_throw
                 or min(p.route(i, (j,)) for i in range(N_HANDS)) <= p.horizon]
        store.fetch(((AloneKey(j), False) for j in alone), slice_s=slice_s)
        return {j for j in alone if store.status(AloneKey(j)) is not Status.INFEASIBLE}


def compose(programs: StepPrograms, store: RelaxationStore, node: Node, exact: bool = True,
            slice_s: float = np.inf) -> StepResult | None:
    """The joint plan made of each hand's own solution (its relaxation, solved to optimality or
    a probe), if the model and the whole specification (task, every rule, eq. 16) hold on its
    re-simulated trace; else the best joint plan with the same grasps (a small MILP over θ
    alone), or None."""
    parts = [store.hand(i, node.share(i), exact, slice_s) for i in range(N_HANDS)]
    force = np.stack([parts[i].trajectory.force[:, i] for i in range(N_HANDS)], axis=1)
    grasp = np.stack([parts[i].trajectory.grasp[:, i] for i in range(N_HANDS)], axis=1)
    traj = programs.replay(force, grasp)
    apart = parts[0].apart | parts[1].apart
    if programs.satisfies(traj, programs.spec):
        status = (Status.OPTIMAL if all(p.status is Status.OPTIMAL for p in parts)
                  else Status.FEASIBLE)
        return StepResult.replayed(status, programs.horizon, traj, float(np.abs(force).sum()),
                                   apart=apart)
    plan = programs.solve(programs.node_spec(node), programs.mask([]), grasp=grasp, exact=exact,
                          apart=apart, slice_s=slice_s)
    return plan if plan.status.has_solution else None


def joint(programs: StepPrograms, store: RelaxationStore, node: Node, **kw) -> StepResult:
    """The node's own program (:meth:`~dualarm_mpc.search.subprograms.StepPrograms.joint`), each
    hand's cost floored at the bound the store proves for its share."""
    return programs.joint(node, store.floor(node), **kw)


# --- the feasibility pass ----------------------------------------------------------------------


@dataclass(frozen=True)
class Feasibility:
    """What the feasibility pass decided: ``status`` FEASIBLE (``witness`` is a plan, the first
    incumbent), INFEASIBLE (every node proven to have none) or TIME_LIMIT (undecided);
    ``relays``: whether the relay nodes are among the horizon's nodes
    (:meth:`Skeleton.handed_over_objects`)."""

    status: Status
    witness: StepResult | None = None
    relays: bool = False


class FeasibilityPass:
    """Whether the horizon admits a plan, decided with feasibility probes (first solutions, no
    optimality): a node is feasible when its relaxations are and its hands' plans fit together
    or its joint program has a solution (docs/search.md, "The search", 1). Infeasible
    relaxations found here stay in the store for the optimisation."""

    def __init__(self, programs: StepPrograms, store: RelaxationStore, skeleton: Skeleton
                 ) -> None:
        self.programs, self.store, self.skeleton = programs, store, skeleton
        self._ruled: set[Node] = set()  # the nodes proven infeasible so far

    def decide(self) -> Feasibility:
        """In rounds: each program may take ``FIRST_SLICE`` of the time limit, four times as
        much in the next round, which solves again only what ran out of time; the last round
        has all the time left. A node left undecided does not stop a round, so a node with a
        plan later in the order is still found; the horizon is infeasible only when every node
        is proven so, as without rounds.

        With ``auto`` hand-overs, a round that finds no plan among the nodes with one hand per
        object (none has one, or one ran out of its slice) turns to relays: from then on the
        widest relay nodes, which cover every plan, alone decide the horizon. A relay can make
        a horizon feasible that is not without one, and the step's horizon is that of Algorithm
        1 only if "infeasible" covers every plan; nor are relays left for the proof that no
        other node has a plan, the slow part where they matter (bench/search-experiments.md,
        "Settings of the search")."""
        slice_s, relays = FIRST_SLICE * self.programs.options.time_limit_s, False
        try:
            while True:
                last = slice_s >= self.programs.deadline - time.perf_counter()
                found = self._round(slice_s, relays)
                if found.status is not Status.TIME_LIMIT or last or self.programs.stopped():
                    return found
                self.store.forget_timed_out()
                slice_s, relays = 4 * slice_s, found.relays
        finally:
            self.store.forget_timed_out()  # cut short by a slice: the optimisation solves them

    def _round(self, slice_s: float, relays: bool) -> Feasibility:
        """One round of :meth:`decide`, each program within ``slice_s``."""
        undecided = False
        if not relays:
            relayable = self.skeleton.relayable()  # none under rule 1: no probe for needed
            may_relay = self.skeleton.handover == "auto" and bool(relayable) and bool(
                relayable - self.skeleton.needed(slice_s))
            single = self._probe(slice_s, stop_undecided=may_relay)
            if single.status is Status.FEASIBLE:
                return single
            undecided = single.status is Status.TIME_LIMIT
            if may_relay and not self.programs.stopped():
                relays, undecided = True, False  # what the nodes left open, the widest decide
        wide = self._probe_widest(slice_s, relays)
        if wide.status is Status.FEASIBLE or not undecided:
            return wide
        return replace(wide, status=Status.TIME_LIMIT)

    def _probe(self, slice_s: float, stop_undecided: bool) -> Feasibility:
        """Probe the nodes with one hand per object in turn until one has a plan, or with
        ``stop_undecided`` one is left undecided; the relaxations of the nodes after each are
        fetched beside its own."""
        single_hand, undecided = self.skeleton.single_hand(), False
        for n, node in enumerate(single_hand):
            if self.programs.stopped():
                undecided = True
                break
            if node in self._ruled:
                continue
            if n == 1 and self.programs.spec.m_o <= SINGLES_M_O:
                # past the first guess, most singles will be needed: all at once
                self.store.fetch(((HandKey(i, (j,)), False) for j in self.programs.spec.objects
                                  for i in range(N_HANDS)), slice_s=slice_s)
            # and so will the larger shares of the nodes after it: a few at once
            found = self._probe_node(node, self._ahead(single_hand[n + 1:]) if n else (),
                                     slice_s)
            if found.status is Status.FEASIBLE:
                return found
            if found.status is Status.TIME_LIMIT:
                undecided = True
                if stop_undecided:
                    break
        return Feasibility(Status.TIME_LIMIT if undecided else Status.INFEASIBLE)

    def _probe_node(self, node: Node, ahead: list[Key], slice_s: float) -> Feasibility:
        """A node with one hand per object: its relaxations (with the ``ahead`` ones beside
        them), then its hands' plans put together, else its joint program."""
        relaxed = self.relaxations_feasible(node, ahead, slice_s)
        if relaxed is None:
            return Feasibility(Status.TIME_LIMIT)
        if not relaxed:
            self._ruled.add(node)
            self.programs.stats.pruned.add(node)
            return Feasibility(Status.INFEASIBLE)
        self.programs.stats.expanded.add(node)
        probe = None if node.free else compose(self.programs, self.store, node, exact=False,
                                               slice_s=slice_s)
        if probe is None:
            probe = joint(self.programs, self.store, node, exact=False, slice_s=slice_s)
        return self._settle(node, probe)

    def _probe_widest(self, slice_s: float, relays: bool) -> Feasibility:
        """Probe the widest nodes (with ``relays``, those cover every plan and so alone decide
        the horizon), on every worker at once (a joint program each: one would leave the other
        worker idle)."""
        wide = [n for n in self.skeleton.widest(relays, slice_s) if n not in self._ruled]
        relaxed = [self.relaxations_feasible(n, slice_s=slice_s) for n in wide]
        undecided = None in relaxed
        ruled = [n for n, r in zip(wide, relaxed, strict=True) if r is False]
        self._ruled.update(ruled)
        self.programs.stats.pruned.update(ruled)
        wide = [n for n, r in zip(wide, relaxed, strict=True) if r]
        for at in range(0, len(wide), BATCH):
            if self.programs.stopped():
                return Feasibility(Status.TIME_LIMIT, relays=relays)
            batch = wide[at:at + BATCH]
            self.programs.stats.expanded.update(batch)
            probes = self.programs.map(lambda n: joint(
                self.programs, self.store, n, exact=False, slice_s=slice_s), batch)
            for node, probe in zip(batch, probes, strict=True):
                settled = self._settle(node, probe)
                if settled.status is Status.FEASIBLE:
                    return replace(settled, relays=relays)
                undecided |= settled.status is Status.TIME_LIMIT
        return Feasibility(Status.TIME_LIMIT if undecided else Status.INFEASIBLE, relays=relays)

    def _settle(self, node: Node, probe: StepResult) -> Feasibility:
        """What the probe of ``node`` decided: a plan (the witness), none (the node is ruled
        out), or nothing in its time."""
        if probe.status.has_solution:
            return Feasibility(Status.FEASIBLE, probe)
        if probe.status is Status.INFEASIBLE:
            self._ruled.add(node)
            return Feasibility(Status.INFEASIBLE)
        return Feasibility(Status.TIME_LIMIT)

    def relaxations_feasible(self, node: Node, ahead: Iterable[Key] = (),
                             slice_s: float = np.inf) -> bool | None:
        """True when every relaxation of the node has a solution, False when one is proven
        infeasible, None when one ran out of time (undecided). The ``ahead`` relaxations are
        probed beside the node's, on the workers its own leave idle."""
        if self.store.ruled_out(node):
            return False
        keys = self.store.keys(node)
        self.store.fetch(((k, False) for k in keys + list(ahead)), slice_s=slice_s)
        statuses = [self.store.status(k) for k in keys]
        if Status.INFEASIBLE in statuses:
            return False
        return True if all(st.has_solution for st in statuses) else None

    def _ahead(self, nodes: Iterable[Node]) -> list[Key]:
        """The larger shares (solved exactly, see :meth:`RelaxationStore.fetch`) that the
        probes of ``nodes`` will ask for next, up to ``FETCH``: unknown, and not ruled out
        without a solve (by an infeasible subset or the route). They would be solved one after
        another, on one worker; at a horizon with a plan the best-first loop wants their bounds
        anyway. (Not all shares ahead: those probe pairs a plan never needs.)"""
        keys: list[Key] = []
        for node in nodes:
            for i in range(N_HANDS):
                key = HandKey(i, node.share(i))
                if key not in keys and self.store.larger(key) \
                        and self.store.wanted(key, False) \
                        and not self.store.share_ruled_out(i, node.share(i)):
                    keys.append(key)
            if len(keys) >= FETCH:
                break
        return keys[:FETCH]

    def ruled_out(self) -> bool:
        """Whether the relaxations alone prove that the horizon has no plan: every node has an
        infeasible one, relays included. Stops at the first node that they cannot rule out (a
        cheap check: no joint program is solved; the relay nodes are listed, which needs every
        single-hand relaxation, only if the others are all ruled out)."""
        if any(self.relaxations_feasible(n) is not False for n in self.skeleton.single_hand()):
            return False
        return all(self.relaxations_feasible(n) is False
                   for n in self.skeleton.widest(relays=True))


# --- the best-first optimiser ------------------------------------------------------------------


class BestFirst:
    """The optimum of the horizon (as the monolithic MILP) from the feasibility pass's verdict:
    best-first over the nodes by their bounds (docs/search.md, "The search", 2–3)."""

    def __init__(self, programs: StepPrograms, store: RelaxationStore, skeleton: Skeleton
                 ) -> None:
        self.programs, self.store, self.skeleton = programs, store, skeleton
        self._composed: dict[Node, StepResult | None] = {}  # compose(node), exact

    def run(self, found: Feasibility, incumbent: StepResult | None = None) -> StepResult:
        """From the pass's witness or ``incumbent``, a plan of the horizon known already,
        whichever is cheaper (the first incumbent, if any), over the nodes the pass's ``relays``
        say: the best plan and the least open bound, as :func:`step_result` reports them."""
        t0 = time.perf_counter()
        heap = _Heap(self.skeleton.nodes(found.relays))
        best = min((p for p in (found.witness, incumbent) if p is not None),
                   key=lambda p: p.cost, default=None)
        undecided = np.inf  # the least bound of a node the solver could not close
        stats = self.programs.stats
        while heap:
            node, key = heap.pop()
            lb = self.store.bound(node)
            if lb > key:  # bounds only grow: a stale key goes back in its place
                heap.push(node, lb)
                continue
            if np.isinf(lb):
                stats.pruned.add(node)
                continue  # a relaxation is infeasible: so is the node
            limit = _cost(best)
            if self.programs.reaches(lb, limit) or self.programs.stopped():
                heap.push(node, lb)
                if self.programs.reaches(lb, limit):  # every open node is bounded above it
                    stats.pruned.update(heap.in_order())
                break
            if self.store.ruled_out(node):
                stats.pruned.add(node)
                continue
            need = self.store.missing(node)
            if need:
                # The node's larger shares first: where the horizon is short for them (most
                # nodes of a whole task), one is infeasible and the smaller ones' exact solves,
                # the slow ones at long horizons, are never needed. Then the next nodes' needs:
                # they are likely to come next. A fixed batch (not one per worker) keeps the
                # search, and the plan it picks among equal optima, the same whatever the
                # number of workers.
                need = _largest(need)
                for other in heap.smallest(FETCH):
                    need += _largest(self.store.missing(other))
                needs = self._needs(need[:FETCH], [node] + heap.in_order(), limit)
                self.store.fetch(((k, True) for k in needs), cutoff=needs)
                heap.push(node, self.store.bound(node))
                continue
            # Before a joint program, the cheap plans of every node with complete bounds: a
            # better incumbent cuts the joint programs short, or this one off.
            improved = self.improve([node] + heap.in_order(), best, limit)
            if improved is not best:
                best = improved
                heap.push(node, lb)
                continue
            # A node split into more order parts than a wave spreads them over the workers, so
            # that the later waves are cut off by the first; others are evaluated beside the
            # next ready node, if any (each part after part), or spread too. A node of two
            # parts gains more beside another: its second part is cut off by its first.
            split = self.programs.parts(node) > WAVE
            batch = [(lb, node)] + ([] if split else self._beside(heap, limit))
            lone = len(batch) == 1
            results = self.programs.map(lambda n, cut=limit, spread=lone: self.evaluate(
                n, cut, spread), [n for _, n in batch])
            for (lb_node, _), res in zip(batch, results, strict=True):
                if res.status.has_solution and res.cost < _cost(best):
                    best = res
                if res.status in (Status.FEASIBLE, Status.TIME_LIMIT):
                    undecided = min(undecided, max(lb_node, lower_bound(res)))
        open_bound = min([undecided] + [self.store.bound(n) for n in heap.in_order()])
        return step_result(self.programs, best, open_bound, time.perf_counter() - t0)

    def _needs(self, keys: list[Key], nodes: list[Node], limit: float) -> dict[Key, float]:
        """For each relaxation c_i(S) of ``keys``, what it may cost before every open node
        with it reaches ``limit``, the incumbent: ``limit`` less the least bound of the other
        hand's share among ``nodes``. Solved against that, not the incumbent, it proves only
        what the nodes need, sooner (in a whole task each share has one node, its complement's).
        A relaxation whose nodes are all bounded at ``limit`` already is left out (the popped
        node's never is: it is below ``limit``); c(j) keeps the incumbent."""
        needs = {}
        for key in keys:
            if isinstance(key, HandKey):
                other = [self.store.hand_bound(1 - key.hand, n.share(1 - key.hand))
                         for n in nodes if n.share(key.hand) == key.share]
                need = limit - min(other, default=0.0)
                if need > self.store.hand_bound(key.hand, key.share):
                    needs[key] = need
            else:
                needs[key] = limit
        return needs

    def _beside(self, heap: _Heap, limit: float) -> list[tuple[float, Node]]:
        """The next nodes whose bounds are complete and below the incumbent, taken off the heap
        to be evaluated beside the one popped, against the same incumbent: usually they would
        be next anyway."""
        beside: list[tuple[float, Node]] = []
        while heap and len(beside) < BATCH - 1:
            other = heap.first()
            lb_other = self.store.bound(other)
            if self.store.missing(other) or np.isinf(lb_other) or \
                    self.programs.reaches(lb_other, limit):
                break
            heap.pop()
            beside.append((lb_other, other))
        return beside

    def evaluate(self, node: Node, incumbent: float = np.inf, spread: bool = False
                 ) -> StepResult:
        """The node's optimum if it is below ``incumbent`` ("infeasible" if none is): composed
        from both hands' solutions when they fit together (directly or with their grasps
        kept), else the joint node program, solved against the better of the two (its order
        parts on every worker at once with ``spread``)."""
        self.programs.stats.expanded.add(node)
        if node.handed_over or node.free:
            return joint(self.programs, self.store, node, cutoff=incumbent, spread=spread)
        lb = self.store.bound(node)
        composed = self.compose(node)
        gap = self.programs.options.mip_rel_gap
        if composed is not None and composed.cost <= lb * (1 + gap) + 1e-9:
            return composed
        if composed is None:
            return joint(self.programs, self.store, node, cutoff=incumbent, spread=spread)
        res = joint(self.programs, self.store, node, start=composed,
                    cutoff=min(incumbent, composed.cost), spread=spread)
        if res.cost <= composed.cost:
            return res
        if res.status in (Status.OPTIMAL, Status.INFEASIBLE):
            return composed  # nothing cheaper: the composed plan is the node's optimum
        # The joint program ran out before it proved that: the node is still open.
        return replace(composed, status=Status.FEASIBLE, bound=lower_bound(res))

    def compose(self, node: Node) -> StepResult | None:
        """:func:`compose` from the hands' optimal relaxations, kept for the node."""
        if node not in self._composed:
            self.programs.stats.expanded.add(node)
            self._composed[node] = compose(self.programs, self.store, node)
        return self._composed[node]

    def improve(self, nodes: Iterable[Node], best: StepResult | None, limit: float = np.inf
                ) -> StepResult | None:
        """``best``, or the cheapest composed plan of ``nodes`` if better and below ``limit``:
        a few hundredths of a second each, where a node's joint program takes seconds and runs
        faster against a lower incumbent (its cutoff)."""
        below = limit * (1 - self.programs.options.mip_rel_gap)
        todo = [n for n in nodes if not (n.handed_over or n.free or n in self._composed
                                         or self.store.missing(n))
                and self.store.bound(n) < below]
        for plan in self.programs.map(self.compose, todo):
            if plan is not None and plan.cost < min(limit, _cost(best)):
                best = plan
        return best


class _Heap:
    """The open nodes by key (their bound when pushed), ties in the order pushed."""

    def __init__(self, nodes: list[Node]) -> None:
        self._counter = itertools.count()
        self._items = [(0.0, next(self._counter), n) for n in nodes]
        heapq.heapify(self._items)

    def __bool__(self) -> bool:
        return bool(self._items)

    def push(self, node: Node, key: float) -> None:
        heapq.heappush(self._items, (key, next(self._counter), node))

    def pop(self) -> tuple[Node, float]:
        key, _, node = heapq.heappop(self._items)
        return node, key

    def first(self) -> Node:
        return self._items[0][2]

    def smallest(self, n: int) -> list[Node]:
        return [node for _, _, node in heapq.nsmallest(n, self._items)]

    def in_order(self) -> list[Node]:
        return [node for _, _, node in sorted(self._items)]


def _largest(keys: list[Key]) -> list[Key]:
    """Of a node's relaxations, those of its largest shares (every one handed over kept)."""
    size = max((len(k.share) for k in keys if isinstance(k, HandKey)), default=0)
    return [k for k in keys if not isinstance(k, HandKey) or len(k.share) == size]


def _cost(best: StepResult | None) -> float:
    """What a plan must cost less than to matter: the best so far."""
    return np.inf if best is None else best.cost


def step_result(programs: StepPrograms, best: StepResult | None, open_bound: float,
                wall: float) -> StepResult:
    """The horizon's result: ``best`` with the status and gap its ``open_bound`` allows, or no
    plan (infeasible when the bound is infinite, else undecided)."""
    binaries = 3 * (programs.horizon + 1) * len(programs.spec.objects)
    if best is None:
        status = Status.INFEASIBLE if open_bound == np.inf else Status.TIME_LIMIT
        return StepResult.no_plan(status, programs.horizon, open_bound, wall, binaries)
    lower = min(open_bound, best.cost)
    gap = max(0.0, (best.cost - lower) / max(abs(best.cost), 1e-12))
    status = (Status.OPTIMAL if gap <= programs.options.mip_rel_gap + 1e-9
              else Status.FEASIBLE)
    return replace(best, status=status, solve_time_s=wall, build_time_s=0.0, gap=gap,
                   binaries=binaries, bound=lower)


# --- one horizon -------------------------------------------------------------------------------


@dataclass(frozen=True)
class StepSearch:
    """The exact search of one horizon of one sequential step, its parts built once: the
    programs, the relaxation store, the skeleton. ``feasible`` then ``run``, or ``ruled_out``."""

    programs: StepPrograms
    store: RelaxationStore
    skeleton: Skeleton

    @classmethod
    def of(cls, programs: StepPrograms, handover: str = "auto",
           below: dict[Key, StepResult] | None = None,
           solver: RelaxationSolver = solve_relaxation) -> StepSearch:
        """The search of ``programs``' horizon: ``handover`` as ``solver.handover``; ``below``,
        the relaxations with a plan at the horizon below; ``solver`` solves each relaxation."""
        store = RelaxationStore(programs, {} if below is None else below, solver)
        return cls(programs, store, Skeleton(programs, store, handover))

    def feasible(self) -> Feasibility:
        """The feasibility pass (:class:`FeasibilityPass`)."""
        return FeasibilityPass(self.programs, self.store, self.skeleton).decide()

    def run(self, found: Feasibility, incumbent: StepResult | None = None) -> StepResult:
        """The best-first optimisation (:class:`BestFirst`) after the pass that gave ``found``,
        from ``incumbent`` where it is cheaper than the pass's plan."""
        return BestFirst(self.programs, self.store, self.skeleton).run(found, incumbent)

    def ruled_out(self) -> bool:
        """Whether the relaxations alone prove the horizon infeasible
        (:meth:`FeasibilityPass.ruled_out`)."""
        return FeasibilityPass(self.programs, self.store, self.skeleton).ruled_out()


@contextmanager
def _searching(problem: StepProblem, horizon: int, options: SolveOptions | None,
               below: dict[Key, StepResult] | None = None) -> Iterator[StepSearch]:
    """A :class:`StepSearch` with the scenario's workers, for the length of a ``with``."""
    solver = problem.scenario.solver
    options = options or solve_options(problem.scenario)
    with ThreadPoolExecutor(solver.workers) as pool:
        programs = StepPrograms(problem, horizon, options, pool)
        yield StepSearch.of(programs, solver.handover, below)


def horizon_ruled_out(problem: StepProblem, horizon: int, time_limit_s: float,
                      options: SolveOptions | None = None) -> bool:
    """Whether the one-hand and one-object relaxations prove that ``horizon`` has no plan
    (within ``time_limit_s``; False when they cannot tell, or ``options.interrupt`` stops
    them)."""
    options = replace(options or solve_options(problem.scenario), time_limit_s=time_limit_s)
    with _searching(problem, horizon, options) as search:
        return search.ruled_out()


def horizon_has_plan(problem: StepProblem, horizon: int, options: SolveOptions | None = None
                     ) -> Status:
    """Whether ``horizon`` admits a plan (the feasibility pass alone): ``FEASIBLE``,
    ``INFEASIBLE``, or ``TIME_LIMIT`` when the time limit left it undecided."""
    with _searching(problem, horizon, options) as search:
        return search.feasible().status


def search_step(problem: StepProblem, horizon: int, options: SolveOptions | None = None,
                below: dict[Key, StepResult] | None = None,
                incumbent: StepResult | None = None) -> StepResult:
    """The skeleton search of one horizon; the same optimum as
    :func:`~dualarm_mpc.milp.horizon.solve_step`. ``below``: the relaxations with a plan at
    ``horizon − 1`` (``RelaxationStore.below``), replaced by this horizon's, for the next horizon of
    the same step. ``incumbent``: a plan of the horizon known already (the step's no-throw witness),
    the optimisation's first incumbent and cutoff: only cheaper plans are searched for; where
    no object of it is held by both hands, the feasibility pass is not run."""
    t0 = time.perf_counter()
    with _searching(problem, horizon, options, below) as search:
        # A plan without a hand-over is one of a node with one hand per object: it decides the
        # horizon as the pass would, and the pass's time goes to the optimisation instead.
        found = Feasibility(Status.FEASIBLE) if _without_handover(incumbent) \
            else search.feasible()
        if found.status is Status.INFEASIBLE:
            res = step_result(search.programs, None, np.inf, time.perf_counter() - t0)
        else:  # a plan, or undecided: the optimisation reports the time limit then
            res = search.run(found, incumbent)
    if below is not None:
        below.clear()
        below.update(search.store.with_plans())
    return replace(res, solve_time_s=time.perf_counter() - t0,
                   search_stats=search.programs.stats.record())


def _without_handover(plan: StepResult | None) -> bool:
    """Whether ``plan`` is a plan in which no object is held by both hands."""
    if plan is None or plan.trajectory is None:
        return False
    return not plan.trajectory.grasp.any(axis=0).all(axis=0).any()
