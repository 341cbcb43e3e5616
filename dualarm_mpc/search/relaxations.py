"""The relaxations of one horizon and the bounds they give (docs/search.md, "Bounds").

*One hand*, c_i(S) (:class:`HandKey`): hand i delivers S alone, only its force costed, the rule
instances that mention other objects left out. A node's joint plan restricted to hand i is a plan
of it, so c_1(S_1) + c_2(S_2) bounds the node from below. c_i(S) only grows with S (an object
can always be left untouched), so before it is solved it is at least the best of its solved
subsets, and a subset proven infeasible, or the route bound (``route.py``), rules it out
without a solve. *One object*, c(j) (:class:`AloneKey`): both hands deliver j alone, a bound for
the nodes that hand j over.

:class:`RelaxationStore` solves each relaxation once — a feasibility probe (first solution),
then to optimality when a bound needs it — keeps it, and answers the bounds of a node from what
it holds. The solve itself is the store's ``solver`` (:func:`solve_relaxation`, the horizon's
MILP narrowed, by default), so a test can wrap the real one.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from dualarm_mpc.milp.horizon import StepResult
from dualarm_mpc.milp.solver import Status
from dualarm_mpc.model.mld import N_HANDS
from dualarm_mpc.model.spec import restricted
from dualarm_mpc.search.subprograms import INFEASIBLE, Node, StepPrograms, lower_bound

# Relaxations solved at once: more than the workers, so that one long program does not leave
# the other worker idle (measured: bench/search-experiments.md, "Settings of the search").
FETCH = 4


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


@dataclass(frozen=True)
class Request:
    """One solve of the relaxation ``key``, as the store asks its solver."""

    key: Key
    exact: bool  # to optimality; else its first solution (a feasibility probe)
    cutoff: float = np.inf  # "infeasible" then means nothing cheaper (SolveOptions.cutoff)
    slice_s: float = np.inf  # the time it may take (the feasibility pass's rounds)
    floor: float = 0.0  # the hand's cost is at least this (its solved subsets' best)
    start: StepResult | None = None  # a plan of it: its probe's, or the horizon below's


RelaxationSolver = Callable[[StepPrograms, Request], StepResult]


def solve_relaxation(programs: StepPrograms, request: Request) -> StepResult:
    """The relaxation's program, solved: the horizon's MILP with η zero outside its pairs and
    the specification restricted to its objects (``spec.restricted``); a hand's share split by
    its orders where no-throw (18) allows
    (:meth:`~dualarm_mpc.search.subprograms.StepPrograms.by_order`)."""
    key = request.key
    if isinstance(key, AloneKey):
        return programs.alone(key.object, exact=request.exact, cutoff=request.cutoff,
                              slice_s=request.slice_s)
    i, share = key.hand, key.share
    floor = np.zeros(N_HANDS)
    floor[i] = request.floor
    return programs.hand(i, share, floor=floor, start=request.start, exact=request.exact,
                         cutoff=request.cutoff, slice_s=request.slice_s)


_UNKNOWN = StepResult.no_plan(Status.ERROR, 0)


@dataclass
class RelaxationStore:
    """The relaxations of one horizon: solved by ``solver`` when first asked, kept, and the
    bounds of the skeleton nodes from them. ``below``: the relaxations with a plan at the
    horizon below (a step tries its horizons one by one); each plan, idled one more step,
    stands for this horizon's feasibility probe."""

    programs: StepPrograms
    below: dict[Key, StepResult] = field(default_factory=dict)
    solver: RelaxationSolver = solve_relaxation
    solved: int = field(default=0, init=False)  # relaxations computed, with a solve or not

    def __post_init__(self) -> None:
        self._results: dict[Key, StepResult] = {}
        self._exact: set[Key] = set()  # keys of the relaxations solved to optimality

    # -- solving and keeping ------------------------------------------------------------------

    def fetch(self, requests: Iterable[tuple[Key, bool]],
              cutoff: float | Mapping[Key, float] = np.inf, slice_s: float = np.inf) -> None:
        """Solve the relaxations asked for (key, exact) and not known yet, on every worker at
        once, each within ``slice_s``. With a ``cutoff`` (one for all, or one per key: what
        the nodes with it may still cost), a relaxation that cannot go below it is closed with
        the cutoff as its bound: every node with it is then no better than the incumbent."""
        # The larger share of a balanced node is solved to optimality even when only probed:
        # that costs little more than its first solution, and at a horizon with a plan the
        # nodes' bounds need it anyway. Other shares stay probes: with m_o = 3 the singles are
        # mostly asked at horizons the pairs rule out, where an exact solve is wasted
        # (bench/search-experiments.md, "Settings of the search").
        requests = [(k, e or self.larger(k)) for k, e in requests]
        todo = list(dict.fromkeys((k, e) for k, e in requests if self.wanted(k, e)))
        cuts = {k: cutoff.get(k, np.inf) if isinstance(cutoff, Mapping) else cutoff
                for k, _ in todo}
        results = self.programs.map(lambda ke: self._compute(*ke, cuts[ke[0]], slice_s), todo)
        for (key, exact), res in zip(todo, results, strict=True):
            self._results[key] = res
            self.solved += 1
            if exact:
                self._exact.add(key)

    def wanted(self, key: Key, exact: bool) -> bool:
        """Not known yet: a probe's answer stands for an exact one only when "infeasible"."""
        res = self._results.get(key)
        return res is None or (exact and key not in self._exact and res.status.has_solution)

    def larger(self, key: Key) -> bool:
        """Whether ``key`` is the larger share of a balanced node (one object when m_o ≤ 2, a
        pair when m_o = 3), solved exactly when first asked (see :meth:`fetch`). Not past
        m_o = 3: there a share's exact solve costs many times its probe (three objects of a
        whole task of six, 11 s against 2), and most horizons searched have no plan."""
        m_o = self.programs.spec.m_o
        return isinstance(key, HandKey) and m_o <= 3 and len(key.share) == (m_o + 1) // 2

    def _compute(self, key: Key, exact: bool, cutoff: float, slice_s: float) -> StepResult:
        """The relaxation, without a solve where what is known decides it (a plan of the
        horizon below, a subset or route that rules it out, a hand with nothing to do)."""
        if not exact and key in self.below:
            idled = self._idled(self.below[key], key)
            if idled is not None:
                return idled
        if isinstance(key, AloneKey):
            return self.solver(self.programs, Request(key, exact, cutoff, slice_s))
        i, share = key.hand, key.share
        if self.share_ruled_out(i, share):
            return INFEASIBLE
        floor = self.hand_bound(i, share)
        if not share and self._idle is not None:
            return self._idle
        probe = self._results.get(key)  # its first solution starts the exact solve
        if probe is None and key in self.below:  # or the plan of the horizon below
            probe = self._idled(self.below[key], key)
        return self.solver(self.programs, Request(key, exact, cutoff, slice_s, floor, probe))

    def _idled(self, plan: StepResult, key: Key) -> StepResult | None:
        """``plan`` of the horizon below with one more step of rest, if it is a plan of this
        horizon's relaxation ``key`` (re-simulated and checked: true whenever the relaxation's
        specification survives idling, as the paper's rules do)."""
        traj, horizon = plan.trajectory, self.programs.horizon
        if traj is None or len(traj.force) != horizon - 1:
            return None
        traj = self.programs.replay(np.concatenate([traj.force, np.zeros((1, N_HANDS, 2))]),
                                    np.concatenate([traj.grasp, traj.grasp[-1:]]))
        share = (key.object,) if isinstance(key, AloneKey) else key.share
        if not self.programs.satisfies(traj, restricted(self.programs.spec, share, share)):
            return None
        return StepResult.replayed(Status.FEASIBLE, horizon, traj, plan.cost, gap=np.inf)

    @functools.cached_property
    def _idle(self) -> StepResult | None:
        """The plan of no force and no grasp, optimal at cost zero for a hand with nothing to
        deliver if it satisfies the model and what is left of the rules (where nothing is held
        or moving): that hand's relaxation needs no solve."""
        p = self.programs
        if p.held or np.abs(p.state.hand_vel).max(initial=0) > 0:
            return None
        traj = p.replay(np.zeros((p.horizon, N_HANDS, 2)),
                        np.zeros((p.horizon + 1, N_HANDS, len(p.spec.objects)), int))
        if not p.satisfies(traj, restricted(p.spec, (), ())):
            return None
        return StepResult.replayed(Status.OPTIMAL, p.horizon, traj, 0.0)

    def forget_timed_out(self) -> None:
        """Drop the relaxations that ran out of time: asked again, they are solved again."""
        out = {k for k, r in self._results.items() if r.status is Status.TIME_LIMIT}
        for key in out:
            del self._results[key]
        self._exact -= out

    def status(self, key: Key) -> Status:
        """What is known of a relaxation already fetched."""
        return self._results[key].status

    def hand(self, i: int, share: tuple[int, ...], exact: bool = True,
             slice_s: float = np.inf) -> StepResult:
        """c_i(S): hand i delivers ``share`` alone; the other hand holds nothing, costs nothing."""
        key = HandKey(i, share)
        self.fetch([(key, exact)], slice_s=slice_s)
        return self._results[key]

    def delivered_alone(self, j: int) -> bool:
        """Whether a hand is known to deliver object j alone: a share holding j has a plan."""
        return any(isinstance(k, HandKey) and j in k.share for k in self.with_plans())

    def with_plans(self) -> dict[Key, StepResult]:
        """The relaxations solved so far that have a plan (``below`` of the next horizon)."""
        return {k: r for k, r in self._results.items() if r.status.has_solution}

    # -- bounds -------------------------------------------------------------------------------

    def share_ruled_out(self, i: int, share: tuple[int, ...]) -> bool:
        """Whether c_i(share) is infeasible without a solve: a subset is (the cheaper test), or
        the route exceeds the horizon."""
        return (np.isinf(self.hand_bound(i, share))
                or self.programs.route(i, share) > self.programs.horizon)

    def ruled_out(self, node: Node) -> bool:
        """Whether a share of ``node`` is ruled out without a solve (:meth:`share_ruled_out`):
        the node then has no plan, and its other relaxations need no solve (in a whole task
        most nodes give one hand more objects than its route allows)."""
        return any(self.share_ruled_out(i, node.share(i)) for i in range(N_HANDS))

    def hand_bound(self, i: int, share: tuple[int, ...]) -> float:
        """A lower bound on c_i(share): its own if solved, else the best of its solved subsets."""
        best = 0.0
        for key, res in list(self._results.items()):
            if isinstance(key, HandKey) and key.hand == i and set(key.share) <= set(share) \
                    and self._proven(key, res):
                best = max(best, lower_bound(res))
        return best

    def _proven(self, key: Key, res: StepResult) -> bool:
        return key in self._exact or res.status is Status.INFEASIBLE

    def floor(self, node: Node) -> np.ndarray:
        """Each hand's proven bound on its share of ``node``: the rows "hand i's Σ‖u_i‖₁ ≥
        it" lift the node program's LP bound from zero."""
        return np.array([self.hand_bound(i, node.share(i)) for i in range(N_HANDS)])

    def bound(self, node: Node) -> float:
        """The node's lower bound: c_1(S_1) + c_2(S_2), or c(j) of an object handed over."""
        split = sum(self.hand_bound(i, node.share(i)) for i in range(N_HANDS))
        alone = [lower_bound(self._results[AloneKey(j)]) for j in node.targets
                 if self._proven(AloneKey(j), self._results.get(AloneKey(j), _UNKNOWN))]
        return max([split] + alone)

    @staticmethod
    def keys(node: Node) -> list[Key]:
        """The relaxations that bound ``node``."""
        keys: list[Key] = [AloneKey(j) for j in node.handed_over]
        return keys + [HandKey(i, node.share(i)) for i in range(N_HANDS)]

    def missing(self, node: Node) -> list[Key]:
        """The relaxations the node's bound still lacks."""
        return [k for k in self.keys(node)
                if not self._proven(k, self._results.get(k, _UNKNOWN))]
