"""The motion bound: the least force cost (17) of delivering objects, without a solve.

Where no-throw (18) holds for an object for both arms, every release puts it in its goal, so
the hand that first grabs it carries it there in one grasp, and a hand holds one object at a
time (eq. 15): a hand's plan is a chain of carries, one per object of its share, in some order.
On one axis the chain moves the hand back and forth, and where it must (§V-D: every object is
grabbed below every goal, on y), each carry is a run of its own one way and each walk to the
next object a run the other way. A run of length L in N steps of a double integrator (eq. 1,
|v| ≤ v_max, |u| ≤ u_max per component) needs a peak speed P, and the hand, at rest at the start
and at the end of every plan (v_hand(T) = 0), gains and loses it: Σ_k |u(k)| ≥ 2ΣP/Δt over the
runs. Which N each run gets is the plan's choice, so the bound is the least over the splits of
the horizon, taken through a Lagrangian (λ per step): for every λ ≥ 0,

    J_i ≥ Σ_runs min_N (2P(L, N)/Δt + λN) − λ(T − 1),

and the runs' terms add up, so the least over the orders of a share is a Held–Karp over its
subsets (as the route bound, ``route.py``), and the best λ is kept for each share. A run's
lengths come from the geometry alone:

* a carry of j: from j's place, where the hand grabs it at rest (eq. 8), to its goal G_j: the
  object is in G_j the step after its release (18) and has moved with the hand until then;
* a walk from j to the next object m: the hand is within h_j of j in G_j at that step and
  within h_m of m at its grab (eqs. 10–11);
* the first walk, from the hand's start, joins the first carry where it goes the same way.

Both axes. The runs above leave the other axis out, and say nothing where no axis alternates.
A second bound puts both axes on one split of the steps, between the hand's events: its start,
each first grab and each first release. Over the steps from one event to the next, the leg,
the hand moves at least the least displacement between where the events let it be: from its
start to the object's box; over a carry, the object's own move from its place into G_j (it
moves with the hand and keeps its offset, and (18) puts it in G_j at its release); from
G_j ⊕ h_j to the next object's box. That displacement over the leg's N steps is an average
speed, so the axis reaches it in the leg. On each axis the velocity starts at 0 and ends at 0,
so its total variation, Δt·Σ_k|u(k)|, is at least twice the peak of each run of legs that go
one way (a leg whose ends overlap on that axis goes neither way and is in no run): a leg that
starts a run is charged twice its average speed over Δt, or the larger of its own and the next
leg's where that goes the same way. Only the runs whose start the Held–Karp sees are charged
(the leg before goes the other way, or the hand was at rest). The legs' steps add up to at most
T, priced by λ as above, and each transition prices a walk and the carry after it together,
min over N_1 + N_2. Each hand's bound is the larger of the two.

Nothing else enters (the other hand, eq. 16, the other rules): each only adds cost.
``tests/test_motion.py`` checks a run's least peak against a linear program and each share's
bound against the optimum of its one-hand program (the search's c_i(S)) and each hand's force
in verified plans, also on scenes where no axis alternates. On §V-D's 28 scenes of three to
five objects whose optima the search proves (``bench/whole.py``) it is 0.47–0.72 of the
optimum (0.40–0.67 with the runs alone): the whole task's certificate where the search proves
less (docs/search.md, "The anytime plan").
"""

from __future__ import annotations

import numpy as np

from dualarm_mpc.model.mld import POSITION_TOL, Model, State, in_goal

# 2^n subsets times n² per Held–Karp stage: twelve objects take a few seconds.
MAX_OBJECTS = 12
# λ (cost per step) tried for each share: the bound holds for every one, the best is kept.
LAMBDAS = np.concatenate([[0.0], np.geomspace(1e-3, 1.0, 120)])


def task_bound(model: Model, state: State, objects: list[int], horizon: int) -> float:
    """A lower bound of the cost (17) of every plan of ``horizon`` steps or fewer that delivers
    every one of ``objects`` (model indices) from ``state``, each released only in its goal
    (no-throw (18) for both arms): the least over the hands' shares of the sum of
    :func:`hand_bounds`. 0 where it does not apply: the state not at rest, an object held, or
    more than ``MAX_OBJECTS``."""
    todo = [j for j in objects if not in_goal(state.object_pos[j], model.goals[j])]
    if not todo or len(todo) > MAX_OBJECTS or not state.is_still():
        return 0.0
    full = (1 << len(todo)) - 1
    shares = np.arange(full + 1)
    total = hand_bounds(model, state, 0, todo, horizon) + \
        hand_bounds(model, state, 1, todo, horizon)[full ^ shares]
    least = float(total.min())
    # A bound past every plan would mean no plan within the horizon, which the route bound
    # decides, not this one: it says nothing then.
    return least * (1 - 1e-6) if np.isfinite(least) else 0.0


def hand_bounds(model: Model, state: State, hand: int, objects: list[int],
                horizon: int) -> np.ndarray:
    """For every share S of ``objects`` (bit b of the index for ``objects[b]``), a lower bound of
    the cost (17) of ``hand`` delivering S: the runs' bound summed over the axes on which the
    carries and walks alternate, or the events' bound, the larger (module docstring)."""
    bound = np.zeros(1 << len(objects))
    for axis in range(2):
        for sense in (1.0, -1.0):
            legs = _legs(model, state, hand, objects, axis, sense)
            if legs is not None:
                bound += _held_karp(model, horizon, *legs)
    return np.maximum(bound, _event_bound(model, state, hand, objects, horizon))


def _legs(model: Model, state: State, hand: int, objects: list[int], axis: int,
          sense: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The run lengths on ``axis`` with carries going ``sense``: each object's carry, the walk
    between each pair and the first walk (against ``sense``, and with it, added to the first
    carry); None where a carry or a walk between two objects is not a run of its own."""
    place = sense * state.object_pos[objects, axis]
    half = model.grasp_half[objects] + POSITION_TOL
    near = np.array([g.lo[axis] if sense > 0 else -g.hi[axis] for g in
                     (model.goals[j] for j in objects)]) - POSITION_TOL  # the goal's near side
    carry = near - place
    walk = near[:, None] - half[:, None] - place[None, :] - half[None, :]
    apart = ~np.eye(len(objects), dtype=bool)
    if np.any(carry <= 0) or np.any(walk[apart] <= 0):
        return None
    start = sense * state.hand_pos[hand, axis]
    back = np.maximum(0.0, start - place - half)
    ahead = np.maximum(0.0, place - half - start)
    return carry, walk, back, ahead + carry


def _held_karp(model: Model, horizon: int, carry: np.ndarray, walk: np.ndarray,
               back: np.ndarray, first: np.ndarray) -> np.ndarray:
    """max_λ of the least over the orders of each share of Σ_runs min_N (2P/Δt + λN) − λ(T−1)."""
    steps = max(horizon - 1, 0)  # v(0) and v(T) are zero: the runs share steps 1 … T−1
    price = _Price(model, steps)
    first_leg = price(back) + price(first)  # (Λ, n)
    leg = price(walk) + price(carry)[:, None, :]  # (Λ, n, n): from j to k, then k's carry
    return _dual(_chains(first_leg, leg), steps)


def _chains(first_leg: np.ndarray, leg: np.ndarray) -> np.ndarray:
    """Held–Karp over the shares: the least price (Λ, shares, last object) of a chain that
    starts with ``first_leg`` (Λ, n) to its first object and goes on by ``leg`` (Λ, n, n), from
    one object to the next."""
    n = first_leg.shape[1]
    best = np.full((len(LAMBDAS), 1 << n, n), np.inf)
    for j in range(n):
        best[:, 1 << j, j] = first_leg[:, j]
    for share in range(1, 1 << n):
        row = best[:, share, :]
        if not np.isfinite(row).any():
            continue
        ahead = (row[:, :, None] + leg).min(axis=1)  # (Λ, n)
        for k in range(n):
            if not share >> k & 1:
                nxt = best[:, share | 1 << k, k]
                np.minimum(nxt, ahead[:, k], out=nxt)
    return best


def _dual(best: np.ndarray, steps: int) -> np.ndarray:
    """The Lagrangian bound of each share from ``best`` (Λ, shares, last object), the least
    priced chains: max over λ of the least chain less λ·``steps``."""
    least = best.min(axis=2)
    least[:, 0] = 0.0
    bound = (least - LAMBDAS[:, None] * steps).max(axis=0)
    bound[0] = 0.0
    return np.where(np.isfinite(bound), bound, np.inf)


def _event_bound(model: Model, state: State, hand: int, objects: list[int],
                 horizon: int) -> np.ndarray:
    """For every share, the bound from the legs between a hand's events, both axes on one split
    of the steps (module docstring, "Both axes")."""
    first, carry, walk = _displacements(model, state, hand, objects)
    n = len(objects)
    first_leg = _leg_prices(model, horizon, None, first, carry)  # (Λ, n)
    leg = _leg_prices(model, horizon, np.broadcast_to(carry[:, None], walk.shape), walk,
                      np.broadcast_to(carry[None, :], walk.shape))
    leg[:, np.arange(n), np.arange(n)] = np.inf
    return _dual(_chains(first_leg, leg), horizon)


def _displacements(model: Model, state: State, hand: int, objects: list[int]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The least signed displacement (x, y) of ``hand`` over each leg between its events: from
    its start to each object's grab (n, 2), over each carry (n, 2), from each delivery to each
    other object's grab (n, n, 2). 0 where the leg's ends overlap on that axis."""
    tol = POSITION_TOL
    place = state.object_pos[objects]
    half = (model.grasp_half[objects] + tol)[:, None]
    lo = np.array([model.goals[j].lo for j in objects]) - tol
    hi = np.array([model.goals[j].hi for j in objects]) + tol
    start = state.hand_pos[hand]
    first = _apart(start, start, place - half, place + half)
    carry = _apart(place, place, lo, hi)  # the object moves with the hand until it is in G
    walk = _apart((lo - half)[:, None], (hi + half)[:, None], (place - half)[None],
                  (place + half)[None])
    return first, carry, walk


def _apart(a_lo, a_hi, b_lo, b_hi) -> np.ndarray:
    """The least signed move from a point of [a_lo, a_hi] to one of [b_lo, b_hi]."""
    return np.where(b_lo > a_hi, b_lo - a_hi, np.where(b_hi < a_lo, b_hi - a_lo, 0.0))


def _leg_prices(model: Model, horizon: int, before: np.ndarray | None, one: np.ndarray,
                two: np.ndarray) -> np.ndarray:
    """min over N_1 + N_2 = N ≤ T of the force two legs in turn (displacements ``one``, ``two``,
    (…, 2)) must cost, + λN, for every λ (Λ, …). ``before``: the leg before them (the carry of
    the object delivered last), or None: the hand at rest before them."""
    dt, steps = model.dt, np.arange(horizon + 1)
    shape = one.shape[:-1]
    one, two = one.reshape(-1, 2), two.reshape(-1, 2)
    mode = _modes(None if before is None else np.sign(before).reshape(-1, 2), np.sign(one),
                  np.sign(two))
    r1, r2 = _average(one, steps * dt)[..., None], _average(two, steps * dt)[..., None, :]
    peak = np.select([mode[..., None, None] == m for m in (_ONE, _TWO, _BOTH, _EITHER)],
                     [r1, r2, r1 + r2, np.maximum(r1, r2)], 0.0)  # (m, 2, N_1, N_2)
    cost = 2 * peak.sum(axis=1) / dt  # (m, N_1, N_2)
    reach = model.v_max * dt * steps + POSITION_TOL
    cost[np.abs(one).max(axis=1)[:, None] > reach[None, :]] = np.inf  # v_max: too few steps
    cost.transpose(0, 2, 1)[np.abs(two).max(axis=1)[:, None] > reach[None, :]] = np.inf
    least = np.full((len(one), horizon + 1), np.inf)  # over N_1 + N_2 = N
    for n1 in steps:
        np.minimum(least[:, n1:], cost[:, n1, : horizon + 1 - n1], out=least[:, n1:])
    price = (least[None] + LAMBDAS[:, None, None] * steps).min(axis=2)
    return price.reshape((len(LAMBDAS),) + shape)


def _average(move: np.ndarray, time: np.ndarray) -> np.ndarray:
    """|move| / time (m, 2, N), the least peak speed of a leg; 0 for no move in no time."""
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.abs(move)[:, :, None] / time
    return np.where(np.isnan(speed), 0.0, speed)


# Which peaks of two legs a plan must pay for on one axis (:func:`_modes`).
_NONE, _ONE, _TWO, _BOTH, _EITHER = range(5)


def _modes(before: np.ndarray | None, one: np.ndarray, two: np.ndarray) -> np.ndarray:
    """Per axis, the signs of the leg before (None: the hand at rest), and of two legs: which
    of their average speeds start a run of their own (module docstring, "Both axes"). A leg
    starts a run where the last leg that had to move before it went the other way (or none
    did, from rest); one whose way is not known (0) neither starts nor ends one, and where the
    leg before is not known the run is not counted."""
    last = np.zeros_like(one) if before is None else before
    known = (last != 0) | (before is None)
    start1 = (one != 0) & known & (last != one)
    after = np.where(one != 0, one, last)  # the last way before the second leg
    start2 = (two != 0) & (after != two) & ((one != 0) | known)
    return np.select([start1 & (two == one), start1 & (two == -one), start1, start2],
                     [_EITHER, _BOTH, _ONE, _TWO], _NONE)


class _Price:
    """min_N (2P(L, N)/Δt + λN) for run lengths L, every λ of ``LAMBDAS``: P(L, N) the least peak
    speed with which N steps cover L, at most ``steps`` steps."""

    def __init__(self, model: Model, steps: int) -> None:
        self.model = model
        n = np.arange(1, steps + 1)
        k = np.arange(1, steps + 1)
        ramp = model.u_max * model.dt * np.minimum(k[None, :], n[:, None] + 1 - k[None, :])
        self.n = n
        self.ramp = np.where(k[None, :] <= n[:, None], ramp, 0.0)  # (N, k)

    def __call__(self, lengths: np.ndarray) -> np.ndarray:
        flat = np.asarray(lengths, float).ravel()
        out = np.array([self._one(L) for L in flat])  # (m, Λ)
        return np.moveaxis(out, -1, 0).reshape((len(LAMBDAS),) + np.shape(lengths))

    def _one(self, length: float) -> np.ndarray:
        if length <= 0:
            return np.zeros(len(LAMBDAS))
        peak = self._peak(length)
        if not np.isfinite(peak).any():
            return np.full(len(LAMBDAS), np.inf)
        cost = 2 * peak / self.model.dt
        return (cost[None, :] + LAMBDAS[:, None] * self.n[None, :]).min(axis=1)

    def _peak(self, length: float) -> np.ndarray:
        """The least peak speed per number of steps N (inf where v_max cannot cover it):
        N steps at peak P cover at most Δt·Σ_k min(P, u_max·Δt·k, u_max·Δt·(N + 1 − k)), the
        speed rising from zero and back, and splitting them between runs covers less."""
        dt = self.model.dt

        def reach(p: np.ndarray) -> np.ndarray:
            return dt * np.minimum(p[:, None], self.ramp).sum(axis=1)

        hi = np.full(len(self.n), self.model.v_max)
        able = reach(hi) >= length
        lo = np.zeros(len(self.n))
        for _ in range(50):
            mid = (lo + hi) / 2
            enough = reach(mid) >= length
            hi = np.where(enough, mid, hi)
            lo = np.where(enough, lo, mid)
        return np.where(able, lo, np.inf)


__all__ = ["MAX_OBJECTS", "hand_bounds", "task_bound"]
