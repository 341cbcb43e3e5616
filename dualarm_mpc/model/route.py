"""The route bound: the fewest steps in which one hand can deliver a set of objects.

A hand holds one object at a time (eq. 15). To deliver object j it visits j's grasp box
(eqs. 10–11) and later a place from which j is in its goal box (eq. 12), and every plan ends
with the hand at rest (the program's v_hand(T) = 0). Each axis of a hand is a double integrator
of its own (eq. 1, |v| ≤ v_max and |u| ≤ u_max per component, the hand range as a box), so the
steps the visits need on one axis, the other axis left free, bound the planar plan from below.

On one axis we propagate step by step the set of reachable (position, velocity) pairs after
each visit: convex polygons, since the dynamics are linear and the bounds boxes; where two ways
of getting somewhere meet we keep their convex hull, a superset, so the count stays a bound.
A visit is a set of hand states:

* grab j at a step k ≥ 1: |p_hand(k) − p_j| ≤ h_j;
* deliver j: j is held with a constant offset of at most h_j (eq. 8), so while held it is in
  its goal G_j when p_hand(k) ∈ G_j ⊕ h_j; released, it slides one step at the hand's last
  velocity (docs/model.md), so from the last held step k it ends in G_j when
  p_hand(k) + 2Δt·v_hand(k) ∈ G_j ⊕ h_j.

Under no-throw (18) a hand holds j from its first grab until j is in its goal, so in between
the propagation follows j itself, not the hand: at the grab j stands at p_j and takes the
hand's velocity, it moves as the hand does (in the hand range widened by h_j), and it is
delivered when p_j(k) ∈ G_j; after that the hand is j's position ⊕ [−h_j, h_j]. Taken on the
hand, G_j ⊕ h_j lets a carry end up to 2h_j short of the distance the object has to travel,
whatever offset the hand grabbed it at: half a step at full speed, and a pair's route one step
shorter than any plan (found on (3,5) rule 1: the one-hand programs of an order had to make
their first grabs a step before the latest steps the hand-frame route allowed).

Visits are chained in the order of a route. When no-throw (18) holds for every object of the
set, an object is released only in its goal, so the hand finishes one object before it grabs
the next (eq. 15) and the routes are the orders of the set; otherwise a hand could put an
object down on the way and come back for it, and the bound is that of the slowest object alone.
(Routes that interleave two objects' visits, the first put down on the way, bound that case
more tightly, but measured under rule 2 they cost more time than they save.)

The least over the m! orders is taken over delivered sets instead (Held–Karp): the stage after
a set S delivered with j last is entered from the stages of S − {j}, whichever object they
ended with, by j's grab; the grab puts the frame at j's place, so those ways in differ only in
their speeds, and their union loses next to nothing (on the built-in and random scenes it gives
the orders' bound exactly, tests/test_route.py). m·2^m stages per axis in place of m! routes:
a hand's ten objects in 21 s where the orders never finished; every count polls ``stopped``.

Counted alone, each axis makes each visit at its own earliest step. Where a hand's share is
split by order (``orders``), the axes share them: every plan makes a visit at one step on both
axes, so each axis is counted again with the visit allowed only from the later axis's earliest
step, until nothing changes (``_times``). Over delivered sets the orders' ways in are merged,
so there each axis stays alone.

Run from any state of the hand, the same propagation counts the steps from an object's first
grab to the end of its order's route (``Order.after``), so a plan of horizon T grabs it by
T − after: the latest first grab.

Nothing else enters (no other rule, no other hand, no eq. 16): every plan of one hand's program
makes these visits, so when the bound exceeds a horizon, the program has no plan there.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dualarm_mpc.model.mld import Model, Rect, State, in_goal

_EPS = 1e-9
# A convex polygon of (position, velocity) vertices, counter-clockwise; [] is empty. Pure
# Python: the polygons have a handful of vertices, where numpy's per-call cost dominates.
Polygon = list[tuple[float, float]]


def _hull(points: list[tuple[float, float]]) -> Polygon:
    """The convex hull of ``points``, counter-clockwise (Andrew's monotone chain)."""
    pts = sorted(set(points))
    if len(pts) <= 2:
        return pts

    def chain(seq) -> list:
        out: list = []
        for p in seq:
            while len(out) >= 2 and (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1]) \
                    - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0]) <= 1e-15:
                out.pop()
            out.append(p)
        return out

    return chain(pts)[:-1] + chain(pts[::-1])[:-1]


def _clip(poly: Polygon, a0: float, a1: float, b: float) -> Polygon:
    """``poly`` ∩ {z : a0·z0 + a1·z1 ≤ b} (Sutherland–Hodgman against one half-plane)."""
    if not poly:
        return poly
    s = [a0 * x + a1 * v - b for x, v in poly]
    inside = [d <= _EPS for d in s]
    if all(inside):
        return poly
    if not any(inside):
        return []
    out = []
    n = len(poly)
    for k in range(n):
        q = (k + 1) % n
        if inside[k]:
            out.append(poly[k])
        if inside[k] != inside[q]:
            t = s[k] / (s[k] - s[q])
            out.append((poly[k][0] + (poly[q][0] - poly[k][0]) * t,
                        poly[k][1] + (poly[q][1] - poly[k][1]) * t))
    return out


def _slab(poly: Polygon, lo: float, hi: float, slope: float = 0.0, speed: bool = False) -> Polygon:
    """``poly`` ∩ {lo ≤ p + slope·v ≤ hi}, or ∩ {lo ≤ v ≤ hi} with ``speed``."""
    if not poly:
        return poly
    a0, a1 = (0.0, 1.0) if speed else (1.0, slope)
    z = [a0 * x + a1 * v for x, v in poly]
    low, high = min(z), max(z)
    if low > hi + _EPS or high < lo - _EPS:
        return []
    if high > hi + _EPS:
        poly = _clip(poly, a0, a1, hi)
    if low < lo - _EPS:
        poly = _clip(poly, -a0, -a1, -lo)
    return poly


def _union(polys: list[Polygon]) -> Polygon:
    """The convex hull of the union (a polygon alone is its own)."""
    polys = [poly for poly in polys if poly]
    if len(polys) <= 1:
        return polys[0] if polys else []
    return _hull([p for poly in polys for p in poly])


Slab = tuple[float, float, float]  # lo ≤ p + slope·v ≤ hi
Axis = tuple[float, float, float, float, float]  # Δt, v_max, u_max, and the hand range lo, hi
Stopped = Callable[[], bool]  #: polled by every loop of the bound that can run long


def _step(axis: Axis, poly: Polygon) -> Polygon:
    """Every state one step after one of ``poly`` (eq. 1), within the velocity and range bounds."""
    if not poly:
        return poly
    dt, v_max, u_max, lo, hi = axis
    poly = _sheared_sum([(x + dt * v, v) for x, v in poly], dt * u_max)
    return _slab(_slab(poly, -v_max, v_max, speed=True), lo, hi)


def _sheared_sum(poly: Polygon, du: float) -> Polygon:
    """``poly`` ⊕ {0} × [−du, du], in O(n): the position update x + Δt·v is a shear, so the
    polygon stays convex and counter-clockwise, and adding a vertical segment moves its lower
    chain (from the leftmost to the rightmost vertex, the lowest of each) down by du and its
    upper chain (back, the highest of each) up."""
    n = len(poly)
    left_low = min(range(n), key=lambda k: poly[k])
    right_high = max(range(n), key=lambda k: poly[k])
    right_low = max(range(n), key=lambda k: (poly[k][0], -poly[k][1]))
    left_high = min(range(n), key=lambda k: (poly[k][0], -poly[k][1]))
    out = []
    for first, last, d in ((left_low, right_low, -du), (right_high, left_high, du)):
        k = first
        while True:
            out.append((poly[k][0], poly[k][1] + d))
            if k == last:
                break
            k = (k + 1) % n
    return out


@dataclass(frozen=True)
class _Grab:
    """The first grab of an object held until it is in its goal (under no-throw): the visit's
    ``slabs`` are on the hand, and from then on the stage follows the object, which stands at
    ``at`` and takes the hand's velocity (eq. 8); it stays within the hand range ⊕ ``half``."""

    slabs: tuple[Slab, ...]
    at: float
    half: float


@dataclass(frozen=True)
class _Release:
    """The object held since its :class:`_Grab` is in its goal (``slabs``, on the object): from
    then on the stage follows the hand again, anywhere within ``half`` of the object."""

    slabs: tuple[Slab, ...]
    half: float


Visit = tuple[Slab, ...] | _Grab | _Release  #: a union of slabs on the hand, or a change of frame


def _enter(visit: Visit, poly: Polygon) -> Polygon:
    """The states that make ``visit`` (``poly``, already within its slabs) in the frame that
    follows it."""
    if not poly or not isinstance(visit, (_Grab, _Release)):
        return poly
    if isinstance(visit, _Grab):
        speeds = [v for _, v in poly]
        return _hull([(visit.at, min(speeds)), (visit.at, max(speeds))])
    return _hull([(x + d, v) for x, v in poly for d in (-visit.half, visit.half)])


def _slabs(visit: Visit) -> tuple[Slab, ...]:
    return visit.slabs if isinstance(visit, (_Grab, _Release)) else visit


class _Stage:
    """The (position, velocity) set of one axis after some visits, step by step (``sets[k]``)
    as far as it has been asked; the first step at which it is not empty, and the first at
    which it holds a state at rest. It is entered from each of its ``entries`` (a stage before
    it, the visit that leaves that stage for this one, and the first step at which that visit
    may be made), or at ``start`` without any. Routes that begin alike share their stages (an
    order's pairs and triples start with its single objects), and the horizons of a sequential
    step ask the same, a little further."""

    def __init__(self, axis: Axis, start: tuple[float, float] | None,
                 entries: tuple[tuple[_Stage, Visit, int], ...]) -> None:
        dt, v_max, u_max, lo, hi = axis
        if entries and isinstance(entries[0][1], _Grab):  # the object, in the range ⊕ its half
            half = entries[0][1].half
            axis = (dt, v_max, u_max, lo - half, hi + half)
        self.axis, self.entries = axis, entries
        if entries:
            first: Polygon = []
        elif start is None:  # any state within the bounds
            first = [(lo, -v_max), (hi, -v_max), (hi, v_max), (lo, v_max)]
        else:
            first = [start]
        self.sets: list[Polygon] = [first]
        self.first: int | None = None if entries else 0
        self.rest: int | None = None

    def at(self, k: int) -> Polygon:
        while len(self.sets) <= k:
            j = len(self.sets)
            reached = _step(self.axis, self.sets[-1])
            if self.entries:  # or makes a visit at step j
                reached = _union([reached] + [_enter(visit, _slab(parent.at(j), *s))
                                              for parent, visit, earliest in self.entries
                                              if j >= earliest for s in _slabs(visit)])
            self.sets.append(reached)
            if reached and self.first is None:
                self.first = j
            if self.rest is None and _slab(reached, -_EPS, _EPS, speed=True):
                self.rest = j
        return self.sets[k]

    def count(self, cap: int, stopped: Stopped) -> int | None:
        """The first step ≤ ``cap`` at which the stage holds a state at rest (``cap + 1``:
        none), counted step by step; None once ``stopped()``."""
        while self.rest is None and len(self.sets) <= cap:
            if stopped():
                return None
            self.at(len(self.sets))
        return cap + 1 if self.rest is None or self.rest > cap else self.rest


def _never() -> bool:
    return False


_STAGES: dict[tuple, _Stage] = {}
_STAGES_LOCK = threading.Lock()  # the search's workers ask too
# Stages kept between calls, about 5 kB each: a hand's ten objects make 5,120 per axis
_STAGES_KEPT = 65_536


def _kept() -> None:
    if len(_STAGES) >= _STAGES_KEPT:  # the stages of earlier steps are of no use
        _STAGES.clear()


def _stages(axis: Axis, start: tuple[float, float] | None, visits: tuple[Visit, ...],
            earliest: tuple[int, ...] | None = None) -> list[_Stage]:
    """The stages of a route: after none of ``visits``, after the first, and so on; visit m
    made at step ``earliest[m]`` or later (by default at any step ≥ 1)."""
    earliest = earliest or (1,) * len(visits)
    stages: list[_Stage] = []
    for m in range(len(visits) + 1):
        key = (axis, start, visits[:m], earliest[:m])
        if key not in _STAGES:
            entry = ((stages[-1], visits[m - 1], earliest[m - 1]),) if m else ()
            _STAGES[key] = _Stage(axis, start, entry)
        stages.append(_STAGES[key])
    return stages


def _delivered(axis: Axis, start: tuple[float, float] | None,
               deliveries: frozenset[tuple[int, _Grab, _Release]],
               last: tuple[int, _Grab, _Release]) -> _Stage:
    """The stage of one axis after a hand has delivered every one of ``deliveries`` (each a
    no-throw object, its grab and its release), ``last`` the last. Held–Karp's recursion:
    ``last``'s grab is entered from the stage of the set without it, whichever object it
    ended with (their union: the grab puts the object at its place, so only the speeds of
    the ways in differ), m·2^(m−1) stages for m objects where the orders are m!."""
    key = (axis, start, deliveries, last)
    if key not in _STAGES:
        n, grab, release = last
        rest = deliveries - {last}
        held = (axis, start, rest, n, grab)
        if held not in _STAGES:
            before = tuple((_delivered(axis, start, rest, d), grab, 1)
                           for d in sorted(rest, key=lambda d: d[0]))
            _STAGES[held] = _Stage(axis, start,
                                   before or ((_stages(axis, start, ())[0], grab, 1),))
        _STAGES[key] = _Stage(axis, start, ((_STAGES[held], release, 1),))
    return _STAGES[key]


def axis_times(axis: Axis, start: tuple[float, float] | None, visits: tuple[Visit, ...],
               cap: int, earliest: tuple[int, ...] | None = None) -> tuple[int, ...]:
    """The earliest step of each visit when one axis of a hand starting at ``start``
    (position, velocity; None: any state within the bounds) makes ``visits`` in order, each at
    a step ≥ 1 (several may share one) and visit m at ``earliest[m]`` or later, and last the
    fewest steps T ≤ ``cap`` after which it is also at rest; ``cap + 1`` for what it cannot
    reach. A visit is a union of slabs on the hand, or a change of frame (:data:`Visit`).
    Pure, so kept and resumed."""
    with _STAGES_LOCK:
        _kept()
        stages = _stages(axis, start, visits, earliest)
        stages[-1].count(cap, _never)
        times = [stage.first for stage in stages[1:]] + [stages[-1].rest]
        return tuple(cap + 1 if t is None or t > cap else t for t in times)


def axis_steps(axis: Axis, start: tuple[float, float] | None, visits: tuple[Visit, ...],
               cap: int) -> int:
    """The fewest steps after which one axis has made ``visits`` and is at rest
    (:func:`axis_times`)."""
    return axis_times(axis, start, visits, cap)[-1]


def route_steps(model: Model, state: State, hand: int, objects: tuple[int, ...],
                no_throw: frozenset[int], cap: int, stopped: Stopped | None = None) -> int:
    """A lower bound on the horizon of any plan in which ``hand`` alone delivers every one of
    ``objects`` (indices into ``model`` and ``state``); ``cap + 1`` means more than ``cap``.
    ``no_throw``: the objects whose no-throw (18) instances are in force. 0 when the bound
    cannot speak: an object held now, moving, or already in its goal, or ``stopped()`` before
    the count was done (the stop of a run, the end of a search's time)."""
    for n in objects:
        if state.grasp[:, n].any() or np.abs(state.object_vel[n]).max() > 0 \
                or in_goal(state.object_pos[n], model.goals[n]):
            return 0
    if not objects:
        return 0
    if len(objects) > 1 and not set(objects) <= no_throw:  # it may put one down on the way
        return max(route_steps(model, state, hand, (n,), no_throw, cap, stopped)
                   for n in objects)
    steps = 0
    with _STAGES_LOCK:
        _kept()
        for a in range(2):
            axis, start, visits = _route(model, state, hand, objects, a, no_throw)
            if objects[0] in no_throw:  # delivered one after another, in any order
                deliveries = frozenset(zip(objects, visits[::2], visits[1::2], strict=True))
                ends = [_delivered(axis, start, deliveries, d) for d in deliveries]
            else:  # one object
                ends = [_stages(axis, start, visits)[-1]]
            count = cap + 1
            for end in ends:  # each counted only as far as the least so far
                counted = end.count(count - 1, stopped or _never)
                if counted is None:
                    return 0
                count = min(count, counted)
            steps = max(steps, count)
            if steps > cap:
                break
    return steps


@dataclass(frozen=True)
class Order:
    """One order in which a hand delivers a set of no-throw objects, and what its route bounds:
    the earliest step at which each object can be first grabbed and first in its goal, the
    fewest steps of the whole route (at rest), and the fewest steps from each object's first
    grab to the route's end (``after``): in a plan of horizon T the hand grabs it by step
    T − after (:meth:`latest`)."""

    hand: int
    objects: tuple[int, ...]
    grab: tuple[int, ...]
    goal: tuple[int, ...]
    steps: int
    after: tuple[int, ...]

    def latest(self, horizon: int) -> tuple[int, ...]:
        """The latest step of each object's first grab in a plan of ``horizon`` steps."""
        return tuple(horizon - a for a in self.after)


def orders(model: Model, state: State, hand: int, objects: tuple[int, ...],
           no_throw: frozenset[int], cap: int) -> list[Order]:
    """Every order in which ``hand`` can deliver ``objects`` (all under no-throw, at rest, not
    held, not in their goal) within ``cap`` steps, the shortest route first. Under no-throw a
    plan delivers them one after another, so every plan of the hand follows one of these
    orders and makes each visit no earlier than its order's route allows (``_times``)."""
    found = []
    for order in itertools.permutations(objects):
        times = _times(model, state, hand, order, no_throw, cap)
        if times[-1] <= cap:
            found.append(Order(hand, order, tuple(int(t) for t in times[0:-1:2]),
                               tuple(int(t) for t in times[1:-1:2]), int(times[-1]),
                               _after(model, state, hand, order, no_throw, cap)))
    return sorted(found, key=lambda o: o.steps)


def _times(model: Model, state: State, hand: int, order: tuple[int, ...],
           no_throw: frozenset[int], cap: int) -> tuple[int, ...]:
    """The earliest step of each visit of ``order`` and the fewest steps of its route, the two
    axes' visit times shared. Each axis counted alone may make a visit at a step at which the
    other cannot yet; every plan makes visit m at one step on both axes, no earlier than the
    later axis's earliest E_m. So each axis is propagated again with visit m allowed from E_m
    on — a subset of what it kept, still holding every plan's states — which may delay the
    visits after it, until nothing changes (two to four rounds; a pair's route a step or two
    longer on a fifth to nearly half of a five-object task's pairs, the exact least horizon
    where checked: bench/search-experiments.md, "Orders")."""
    routes = [_route(model, state, hand, order, a, no_throw) for a in range(2)]
    earliest = (1,) * (2 * len(order))
    while True:
        times = tuple(map(max, *(axis_times(*route, cap, earliest) for route in routes)))
        if times[:-1] == earliest or times[-1] > cap:
            return times
        earliest = times[:-1]


def _after(model: Model, state: State, hand: int, order: tuple[int, ...],
           no_throw: frozenset[int], cap: int) -> tuple[int, ...]:
    """The fewest steps from the first grab of each object of ``order`` to the end of its
    route, at rest: the route of the objects from there on, from any state of the hand (at
    step 0) whose grab at step 1 leaves the object at its place with any velocity (eq. 8)."""
    after = []
    for m in range(len(order)):
        routes = (_route(model, state, hand, order[m:], a, no_throw) for a in range(2))
        after.append(max(axis_steps(axis, None, visits, cap + 1) for axis, _, visits in routes) - 1)
    return tuple(after)


def _route(model: Model, state: State, hand: int, order: tuple[int, ...], a: int,
           no_throw: frozenset[int]) -> tuple[Axis, tuple[float, float], tuple]:
    """Axis a of ``hand`` delivering ``order``: the axis, its start and the visits in turn."""
    ws: Rect = model.workspace
    axis = (model.dt, model.v_max, model.u_max, float(ws.lo[a]), float(ws.hi[a]))
    start = (float(state.hand_pos[hand, a]), float(state.hand_vel[hand, a]))
    return axis, start, tuple(v for n in order for v in _visits(model, state, n, a, no_throw))


def _visits(model: Model, state: State, n: int, a: int,
            no_throw: frozenset[int]) -> tuple[Visit, Visit]:
    """Object n's two visits on axis a: grab, then deliver (held, or after its slide)."""
    p, h = float(state.object_pos[n, a]), float(model.grasp_half[n])
    if n in no_throw:  # held from its first grab until it is in its goal: follow the object
        goal = (float(model.goals[n].lo[a]), float(model.goals[n].hi[a]), 0.0)
        return _Grab(((p - h, p + h, 0.0),), p, h), _Release((goal,), h)
    lo, hi = float(model.goals[n].lo[a]) - h, float(model.goals[n].hi[a]) + h
    return ((p - h, p + h, 0.0),), ((lo, hi, 0.0), (lo, hi, 2 * model.dt))


def horizon_bound(model: Model, state: State, m_o: int, no_throw: frozenset[int],
                  cap: int, stopped: Stopped | None = None) -> int:
    """A lower bound on the horizon of any plan delivering m_o of the objects, when no-throw
    (18) holds for every one of them (else 0); ``cap + 1``: none within ``cap``.

    Under no-throw the first hand to hold an object delivers it before it lets go, hand-over
    or not, so every plan has, for some m_o objects and some choice of the hand that first
    holds each, both hands' routes: the bound is the least over those choices of the slower
    hand's route bound. A hand's route is no shorter than that of any one of its objects, so
    the choices go in the order of that cheap bound, and stop once it reaches the best so far;
    each route is counted only as far as the best so far (the search resumes it later).
    0 once ``stopped()``."""
    if not set(range(model.n_objects)) <= no_throw:
        return 0
    stopped = stopped or _never
    single = [[route_steps(model, state, i, (n,), no_throw, cap, stopped)
               for n in range(model.n_objects)] for i in range(2)]
    choices = sorted(
        (max(single[h][n] for n, h in zip(delivered, hands, strict=True)), delivered, hands)
        for delivered in itertools.combinations(range(model.n_objects), m_o)
        for hands in itertools.product(range(2), repeat=m_o))
    best = cap + 1
    for quick, delivered, hands in choices:
        if stopped():
            return 0
        if quick >= best:
            break
        slower = quick
        for i in range(2):
            share = tuple(n for n, h in zip(delivered, hands, strict=True) if h == i)
            if len(share) > 1:
                slower = max(slower, route_steps(model, state, i, share, no_throw, best - 1,
                                                 stopped))
            if slower >= best:
                break
        best = min(best, slower)
    return best
