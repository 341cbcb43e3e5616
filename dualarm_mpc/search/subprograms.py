"""The narrowed programs of one horizon that the skeleton search solves (docs/search.md).

A *skeleton node* (D, h) fixes the m_o objects D whose delivery satisfies φ_task (13) and, for
each j ∈ D, the hand h_j that may hold it (arm 1, arm 2, or ``BOTH`` for a hand-over). Every
program of the search is the horizon's MILP (``horizon.HorizonProgram``: eqs. 1, 7–11, 14–16,
cost 17) narrowed: η_ij(k ≥ 1) = 0 outside the pairs it allows, a specification restricted to
some objects, one hand costed, the grasps of a plan fixed, or one order in which a hand delivers
its share ("Orders (no-throw)"). :class:`StepPrograms` builds and solves them under the search's
clock: the horizon's deadline, the feasibility pass's time slice where it gives one, and the
options' stop request and work budget. :func:`satisfies` is the check every plan put together
from parts passes: re-simulation and direct LTL evaluation (``evaluate.py``, which shares no code
with the encoder).

Why one module of this length: it is one class and the few functions its programs' results go
through; its parts (the splits by order, the order bounds, the routes, the clock) share one
horizon's state and locks, which a split would pass between modules.
"""

from __future__ import annotations

import itertools
import math
import threading
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from dualarm_mpc.logic.evaluate import evaluate
from dualarm_mpc.logic.ltl import Atom
from dualarm_mpc.milp.horizon import HorizonProgram, StepResult
from dualarm_mpc.milp.solver import SolveOptions, Status
from dualarm_mpc.model.mld import (
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
from dualarm_mpc.model.plan import Trajectory
from dualarm_mpc.model.route import Order, orders, route_steps
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.model.spec import Specification, StepProblem, restricted

BOTH = 2  # h_j: either hand may hold object j (a hand-over)
# A share is split into one program per order (m! of them) up to this many objects: 120 at five;
# a larger share is solved whole (ten would be 3.6 million programs, and as many routes)
SPLIT_MAX_OBJECTS = 5
# The parts of a spread program solved at once: fixed, not one per worker, so that which parts
# a better plan cuts off, and the plan picked among equal optima, do not depend on the workers.
WAVE = 2
# A joint program split by order over more objects than this (past Table II's m_o = 3: a whole
# task's nodes) is solved with HiGHS's own settings, not ``small_trees``: its tree runs to
# thousands of nodes, where full presolve, restarts and reliability branching pay
# (docs/search.md, "Solver settings").
LARGE_JOINT = 3


@dataclass(frozen=True)
class Node:
    """A skeleton node (D, h) (docs/search.md, "Skeleton nodes")."""

    targets: tuple[int, ...]  # D, the objects it delivers (scenario indices)
    hands: tuple[int, ...]  # h_j for j in D: 0 (arm 1), 1 (arm 2) or BOTH
    free: frozenset[int] = frozenset()  # outside D and not provably untouchable

    def share(self, i: int) -> tuple[int, ...]:
        """S_i: the objects of D that hand i alone delivers."""
        return tuple(j for j, h in zip(self.targets, self.hands, strict=True) if h == i)

    @property
    def handed_over(self) -> tuple[int, ...]:
        return self.share(BOTH)


@dataclass
class SearchStats:
    """What the search of one horizon did, so that its scaling can be read: the nodes
    ``expanded`` (a plan of their own sought: the hands' plans put together, or the node's
    program), those ``pruned`` by bounds alone (a relaxation without a plan, or a bound no
    better than the incumbent), and the programs solved with their wall time summed over the
    workers (the leaves of the search: relaxations and node programs)."""

    expanded: set[Node] = field(default_factory=set)
    pruned: set[Node] = field(default_factory=set)
    programs: int = 0
    program_time_s: float = 0.0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def solved(self, wall_s: float) -> None:
        with self._lock:
            self.programs += 1
            self.program_time_s += wall_s

    def record(self) -> dict:
        """The counts as the plan JSON's ``search_stats`` (docs/formats.md); a node pruned
        and later expanded counts as expanded."""
        return {"horizons": 1, "expansions": len(self.expanded),
                "prunes": len(self.pruned - self.expanded), "programs": self.programs,
                "leaf_time_s": round(self.program_time_s, 4)}

    class Sum:
        """The records of several searches (a step's horizons) added up."""

        def __init__(self) -> None:
            self.total: dict = {}

        def add(self, record: dict | None) -> None:
            for key, value in (record or {}).items():
                self.total[key] = self.total.get(key, 0) + value

        def record(self) -> dict | None:
            """The sum, or None where no search ran (the monolithic MILP)."""
            return {k: round(v, 4) for k, v in self.total.items()} or None


class StepPrograms:
    """The programs of one horizon of one sequential step, narrowed as the search asks and
    solved by ``options.backend`` under the search's clock. ``pool``: the workers that solve
    independent programs at once (HiGHS releases the GIL)."""

    def __init__(self, problem: StepProblem, horizon: int, options: SolveOptions,
                 pool: ThreadPoolExecutor | None = None) -> None:
        self.problem, self.horizon = problem, horizon
        self.options, self.pool = options, pool
        self.deadline = time.perf_counter() + options.time_limit_s
        spec = problem.spec
        self.program = HorizonProgram(problem.scenario, problem.state, list(spec.objects),
                                      horizon)
        self.model = self.program.model
        self.local = {j: n for n, j in enumerate(spec.objects)}
        local_grasp = problem.state.grasp[:, list(spec.objects)]
        self.held = [j for n, j in enumerate(spec.objects) if local_grasp[:, n].any()]
        self.no_throw = frozenset(self.local[j] for j in spec.released_only_in_goal())
        self.stats = SearchStats()
        # c_i(o): the least cost of hand i alone along order o (a part of its relaxation
        # c_i(S)), as proven so far, and the orders whose bound is their optimum
        self._order_bound: dict[tuple[int, tuple[int, ...]], float] = {}
        self._order_exact: set[tuple[int, tuple[int, ...]]] = set()
        self._order_lock = threading.Lock()
        self._orders: dict[tuple[int, tuple[int, ...]], list[Order] | None] = {}

    @property
    def scenario(self) -> Scenario:
        return self.problem.scenario

    @property
    def state(self) -> State:
        """The step's start, over all objects."""
        return self.problem.state

    @property
    def spec(self) -> Specification:
        return self.problem.spec

    def stopped(self) -> bool:
        """Out of time or work (``options.work``: read here only, where no worker runs, so
        the search stops at the same place on any machine), or asked to stop
        (``options.interrupt``)."""
        stop, work = self.options.interrupt, self.options.work
        return (time.perf_counter() > self.deadline or (stop is not None and stop.is_set())
                or (work is not None and work.spent()))

    def map(self, f, items: list) -> list:
        """``f`` over ``items``, on every worker at once."""
        if len(items) > 1 and self.pool is not None:
            return list(self.pool.map(f, items))
        return [f(item) for item in items]

    def solve(self, spec: Specification, allowed: np.ndarray, hands=(0, 1), grasp=None,
              start: StepResult | None = None, floor=None, orders=(), exact: bool = True,
              cutoff: float = np.inf, relaxed: bool = False, apart: frozenset = frozenset(),
              slice_s: float = np.inf) -> StepResult:
        """One program, MIP-started from ``start``'s plan if given; ``exact`` false stops at
        its first solution (a feasibility probe). With a ``cutoff``, "infeasible" means no plan
        cheaper than it (``SolveOptions.cutoff``). ``relaxed``: a relaxation, whose objects
        held still may move in the nodes it bounds (``HorizonProgram.standard_form``).
        ``apart``, and ``start``'s: pairs whose (C1)–(C2) rows it likely needs. It may take
        ``slice_s`` at most, and never past the horizon's deadline."""
        t0 = time.perf_counter()
        remaining = max(min(self.deadline - t0, slice_s), 1e-3)
        large = exact and not relaxed and len(hands) == N_HANDS and \
            sum(len(order.objects) for order in orders) > LARGE_JOINT
        options = replace(self.options, time_limit_s=remaining, small_trees=not large,
                          cutoff=cutoff)
        if not exact:
            options = replace(options, mip_rel_gap=1.0)
        res = self.program.solve(spec, options, _start(start), allowed=allowed, hands=hands,
                                 grasp=grasp, floor=floor, orders=orders, relaxed=relaxed,
                                 apart=apart if start is None else apart | start.apart)
        self.stats.solved(time.perf_counter() - t0)
        if self.options.work is not None:
            self.options.work.spend()
        if res.status is Status.INFEASIBLE and np.isfinite(cutoff):
            return replace(res, bound=cutoff)  # nothing cheaper than the cutoff: its bound
        return res

    def by_order(self, spec: Specification, allowed: np.ndarray, shares, hands=(0, 1),
                 start: StepResult | None = None, floor=None, exact: bool = True,
                 cutoff: float = np.inf, spread: bool = False, relaxed: bool = False,
                 slice_s: float = np.inf) -> StepResult:
        """A program split by the order in which each hand delivers its share (``shares``,
        one per hand; see :meth:`orders`): its optimum is the best of the parts', each part
        solved against the best plan of those before (a cutoff), and a probe stops at the
        first part with a plan. ``start`` starts the part its plan follows. ``spread``: the
        parts of an exact solve run on every worker at once, ``WAVE`` at a time, each wave
        against the best plan of those before (for a program solved while the other worker
        would idle).

        The parts of a one-hand relaxation prove c_i(o) of their orders. A part of a joint
        program (both hands costed) is bounded by them (``_part_floor``): the parts are
        solved least bound first, each with its hands' c_i(o) as floors, and a part whose
        bound reaches the cutoff is closed unsolved."""
        split = [o for o in (self.orders(i, share) for i, share in shares) if o is not None]
        if not split:
            return self.solve(spec, allowed, hands, start=start, floor=floor, exact=exact,
                              cutoff=cutoff, relaxed=relaxed, slice_s=slice_s)
        parts = list(itertools.product(*split))  # the shortest routes first
        one_hand = relaxed and len(hands) == 1
        joint = exact and not relaxed and len(hands) == N_HANDS
        if joint:
            parts.sort(key=lambda part: sum(self.order_bound(o) for o in part))

        def solve(part, exact=exact, cutoff=cutoff):
            part_floor = floor
            if joint:
                part_floor = self._part_floor(part, shares, floor, cutoff)
                if self.reaches(part_floor.sum(), cutoff):  # nothing cheaper, within the gap
                    return replace(INFEASIBLE, bound=min(part_floor.sum(), cutoff))
            res = self.solve(spec, allowed, hands, floor=part_floor, orders=part, exact=exact,
                             start=start if all(_follows(start, o) for o in part) else None,
                             cutoff=cutoff, relaxed=relaxed, slice_s=slice_s,
                             apart=frozenset() if start is None else start.apart)
            if one_hand:
                self._prove_order(part[0], res, cutoff, exact)
            return res

        results = []
        if spread and exact:
            while parts:
                best = min([cutoff] + [r.cost for r in results if r.status.has_solution])
                if joint:  # a wave of parts that need their joint solve, not one closed at once
                    parts, closed = self._open_parts(parts, shares, floor, best)
                    results += closed
                results += self.map(lambda part, best=best: solve(part, cutoff=best),
                                    parts[:WAVE])
                parts = parts[WAVE:]
            return best_part(results)
        for part in parts:
            best = min([cutoff] + [r.cost for r in results if r.status.has_solution])
            res = solve(part, cutoff=best if exact else np.inf)
            if not exact and res.status.has_solution:
                return res
            results.append(res)
        return best_part(results)

    def hand(self, i: int, share: tuple[int, ...], **solve) -> StepResult:
        """c_i(S) (``relaxations.py``): hand i delivers ``share`` alone, only its force costed,
        the rule instances that mention other objects left out, split by its orders."""
        return self.by_order(*self._relaxation(share, (i,)), [(i, share)], hands=(i,),
                             relaxed=True, **solve)

    def alone(self, j: int, **solve) -> StepResult:
        """c(j) (``relaxations.py``): both hands deliver object ``j`` alone."""
        return self.solve(*self._relaxation((j,), range(N_HANDS)), relaxed=True, **solve)

    def _relaxation(self, share: tuple[int, ...], hands: Iterable[int]
                    ) -> tuple[Specification, np.ndarray]:
        """The specification and η pairs of ``hands`` delivering ``share`` alone."""
        # An object held now may stay held by either hand: untouching it is not free (it would
        # slide off), so every relaxation leaves it as the node programs may.
        held = [(h, j) for j in self.held for h in range(N_HANDS)]
        pairs = [(i, j) for i in hands for j in share]
        return restricted(self.spec, share, share), self.mask(pairs + held)

    def order_bound(self, order: Order) -> float:
        """c_i(o) as proven so far: hand i alone along ``order`` costs at least this."""
        return self._order_bound.get(_key(order), 0.0)

    def _prove_order(self, order: Order, res: StepResult, cutoff: float, exact: bool) -> float:
        """Keep what ``res``, a solve of hand ``order.hand`` alone along ``order`` against
        ``cutoff``, proves of c_i(o), and return it. Against a cutoff the solver prunes every
        subtree bounded at it, so its bound past the cutoff proves nothing: a plan it returns
        above the cutoff, even "optimal", is not the order's optimum (five objects, seed 5:
        1.589 "optimal" against a cutoff of 1.147, where the order's optimum is 1.229)."""
        key, bound = _key(order), min(lower_bound(res), cutoff)
        with self._order_lock:
            self._order_bound[key] = max(self._order_bound.get(key, 0.0), bound)
            if exact and ((res.status is Status.OPTIMAL and res.cost < cutoff)
                          or (res.status is Status.INFEASIBLE and np.isinf(bound))):
                self._order_exact.add(key)
        return bound

    def _part_floor(self, part: tuple[Order, ...], shares, floor, cutoff: float
                    ) -> np.ndarray:
        """Each hand's floor in ``part`` of a joint program: its ``floor`` (its share's bound)
        or c_i(o) of its order, the larger. A joint plan of the part, restricted to hand i, is
        a plan of hand i alone along its order, so Σ_i c_i(o_i) bounds the part. Where the
        floors leave the part below ``cutoff`` and a hand's c_i(o) is known only as a bound,
        it is solved against what the part may still cost (a one-hand program, a fraction of
        the joint one's time), where the hand has other orders: with one, c_i(o) is its
        share's bound already. Solving stops once the floors reach ``cutoff``
        (:meth:`reaches`)."""
        f, share = self._floors(part, floor), dict(shares)
        for order in part:
            # the hand's cost at which the part reaches the cutoff
            need = cutoff - (f.sum() - f[order.hand])
            if self.reaches(f.sum(), cutoff):
                break
            if self._unproven(order, share, need):
                f[order.hand] = max(f[order.hand], self._solve_order(order, share, need))
        return f

    def _open_parts(self, parts: list, shares, floor, cutoff: float) -> tuple[list, list]:
        """The ``parts`` of a joint program whose floors (:meth:`_part_floor`) leave them below
        ``cutoff``, least floor first, and a closed result for each of the others. The orders
        still to be solved alone are solved first, on every worker, each against the most any
        of its parts may still cost, so that no wave holds a part that closes at once beside
        one that runs: its worker would idle (five objects, seed 8: 57 of 82 s)."""
        share, need = dict(shares), {}
        for part in parts:
            f = self._floors(part, floor)
            for order in part:
                most = cutoff - (f.sum() - f[order.hand])
                if not self.reaches(f.sum(), cutoff) and self._unproven(order, share, most):
                    need[order] = max(need.get(order, -np.inf), most)
        self.map(lambda order: self._solve_order(order, share, need[order]), list(need))
        bounds = {part: self._part_floor(part, shares, floor, cutoff).sum() for part in parts}
        closed = [replace(INFEASIBLE, bound=min(b, cutoff)) for b in bounds.values()
                  if self.reaches(b, cutoff)]
        return sorted((p for p in parts if not self.reaches(bounds[p], cutoff)),
                      key=bounds.get), closed

    def _floors(self, part: tuple[Order, ...], floor) -> np.ndarray:
        """Each hand's ``floor``, or the bound proven so far of its order in ``part``."""
        f = np.zeros(N_HANDS) if floor is None else np.array(floor, float)
        for order in part:
            f[order.hand] = max(f[order.hand], self.order_bound(order))
        return f

    def _unproven(self, order: Order, share: dict, need: float) -> bool:
        """Whether c_i(o) of ``order`` is worth a solve against ``need``: not known exactly,
        and not its share's bound already (the hand has other orders)."""
        return (np.isfinite(need) and len(self.orders(order.hand, share[order.hand])) > 1
                and _key(order) not in self._order_exact)

    def _solve_order(self, order: Order, share: dict, need: float) -> float:
        """Hand ``order.hand`` alone along ``order``, against ``need``: what it proves of
        c_i(o) (:meth:`_prove_order`)."""
        i = order.hand
        res = self.solve(*self._relaxation(share[i], (i,)), hands=(i,), orders=(order,),
                         cutoff=need, relaxed=True)
        return self._prove_order(order, res, need, exact=True)

    def reaches(self, bound: float, cutoff: float) -> bool:
        """Whether a program (a node, a part) bounded by ``bound`` has no plan cheaper than
        ``cutoff`` by more than the relative gap a solve calls optimal (``mip_rel_gap``).
        Exactly: where the part holds the incumbent and its hands do not meet, its bound is
        the incumbent's cost less the one-hand solves' own gaps, and the joint program spent
        its whole time proving that (five objects, seed 2: 24 s, 3.3302 against 3.3303)."""
        return bound >= cutoff * (1 - self.options.mip_rel_gap) - 1e-9

    def parts(self, node: Node) -> int:
        """How many order parts the node's joint program is split into (:meth:`by_order`)."""
        return math.prod(len(o) for i in range(N_HANDS)
                         if (o := self.orders(i, node.share(i))) is not None)

    def orders(self, i: int, share: tuple[int, ...]) -> list[Order] | None:
        """The orders in which hand i can deliver ``share`` within the horizon
        (``route.orders``), where no-throw (18) holds for all of its objects, at rest and not
        held: every plan then delivers them one after another, and the program of each order
        is much tighter than the whole (no object is grabbed, or in its goal, before its
        order's route allows; for one object, that alone). None where the split does not
        apply, or the share has more than ``SPLIT_MAX_OBJECTS``."""
        if (i, share) not in self._orders:
            local = tuple(self.local[j] for j in share)
            split = share and len(share) <= SPLIT_MAX_OBJECTS and set(local) <= self.no_throw \
                and self._route(i, share)
            self._orders[i, share] = orders(self.model, self.program.local_state, i, local,
                                            self.no_throw, self.horizon) if split else None
        return self._orders[i, share]

    def route(self, i: int, share: tuple[int, ...]) -> int:
        """The route bound (``route.py``), counted up to the horizon: more steps than the
        horizon and hand i cannot deliver ``share`` in it, whatever the rest of the plan does.
        Where the share is split by order, none of them fitting the horizon (the axes' visit
        times shared, ``route._times``) says so too, often where the bound alone does not."""
        steps = self._route(i, share)
        return self.horizon + 1 if steps <= self.horizon and self.orders(i, share) == [] else steps

    def _route(self, i: int, share: tuple[int, ...]) -> int:
        """The route bound over delivered sets (``route.route_steps``), each axis alone."""
        return route_steps(self.model, self.program.local_state, i,
                           tuple(self.local[j] for j in share), self.no_throw, self.horizon,
                           self.stopped)

    def mask(self, pairs: Iterable[tuple[int, int]]) -> np.ndarray:
        """The pairs (hand, object) whose η may be 1 after the first step."""
        allowed = np.zeros((N_HANDS, len(self.spec.objects)), bool)
        for i, j in pairs:
            allowed[i, self.local[j]] = True
        return allowed

    def replay(self, force: np.ndarray, grasp: np.ndarray) -> Trajectory:
        """The step's objects and hands under ``force`` and ``grasp`` (``mld.replay``)."""
        return replay(self.model, self.program.local_state, force, grasp)

    def satisfies(self, traj: Trajectory, spec: Specification) -> bool:
        return satisfies(self.problem.with_spec(spec), self.model, traj)

    def node_spec(self, node: Node) -> Specification:
        """φ_task replaced by "every j ∈ D delivered" (docs/search.md, "Skeleton nodes")."""
        return replace(self.spec, targets=node.targets, m_o=len(node.targets),
                       task_form="counting")

    def joint(self, node: Node, floor: np.ndarray, start: StepResult | None = None,
              exact: bool = True, cutoff: float = np.inf, spread: bool = False,
              slice_s: float = np.inf) -> StepResult:
        """The node's own program: the monolithic one restricted to the skeleton, with each
        hand's cost at least its ``floor`` (the proven bounds of its share); with a ``cutoff``,
        "infeasible" means no plan cheaper than it."""
        pairs = [(i, j) for j, h in zip(node.targets, node.hands, strict=True)
                 for i in range(N_HANDS) if h in (i, BOTH)]
        pairs += [(i, j) for j in node.free for i in range(N_HANDS)]
        return self.by_order(self.node_spec(node), self.mask(pairs),
                             [(i, node.share(i)) for i in range(N_HANDS)], start=start,
                             floor=floor, exact=exact, cutoff=cutoff, spread=spread,
                             slice_s=slice_s)


def satisfies(problem: StepProblem, model: Model, traj: Trajectory) -> bool:
    """Whether ``traj`` (over the objects of ``problem.spec``, from ``problem.state``) keeps the
    model's constraints (the objects' spacing, (C1)–(C3), included), ends at rest and satisfies
    ``problem.spec`` (evaluated on its trace by ``evaluate.py``, which shares no code with the
    encoder)."""
    scenario, state, spec = problem.scenario, problem.state, problem.spec
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


INFEASIBLE = StepResult.no_plan(Status.INFEASIBLE, 0, np.inf)  # proven without a solve


def best_part(results: list[StepResult]) -> StepResult:
    """The best of a program's parts (which together cover its plans): its solution, and the
    least of their bounds; optimal when every part is closed."""
    bound = min((lower_bound(r) for r in results), default=np.inf)
    found = [r for r in results if r.status.has_solution]
    if not found:
        undecided = [r for r in results if r.status is not Status.INFEASIBLE]
        return replace(undecided[0] if undecided else INFEASIBLE, bound=bound)
    best = min(found, key=lambda r: r.cost)
    closed = all(r.status in (Status.OPTIMAL, Status.INFEASIBLE) for r in results)
    return replace(best, status=Status.OPTIMAL if closed else Status.FEASIBLE,
                   bound=min(bound, best.cost))


def lower_bound(res: StepResult) -> float:
    """A proven lower bound of a program's cost: +inf when it is infeasible, its cutoff when it
    has nothing cheaper."""
    if res.status is Status.INFEASIBLE:
        return res.bound
    if res.status is Status.OPTIMAL:
        return max(min(res.bound, res.cost), 0.0) if np.isfinite(res.bound) else res.cost
    return max(res.bound, 0.0) if np.isfinite(res.bound) else 0.0


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


def _key(order: Order) -> tuple[int, tuple[int, ...]]:
    return order.hand, order.objects


def _follows(plan: StepResult | None, order: Order) -> bool:
    """Whether ``plan``'s hand first grabs the objects of ``order`` in its order."""
    if plan is None or plan.trajectory is None:
        return False
    grasp = plan.trajectory.grasp[1:, order.hand]
    first = [int(np.argmax(grasp[:, n])) if grasp[:, n].any() else len(grasp)
             for n in order.objects]
    return first == sorted(first)
