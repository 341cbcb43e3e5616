"""The band bound: the least force cost (17) of delivering objects that may be thrown, without
a solve.

The motion bound (``motion.py``) needs no-throw (18): a chain of carries per hand. Under rule 2 a
hand may throw an object, or leave it part way for the other hand, so neither holds. What does
hold, on one axis of the table and over a band B = [b_lo, b_hi] of it:

* **Demand.** Every object must rise from where it is, p_j, to its goal's near side g_j, so its
  rises inside B add up to at least |[p_j, g_j] ∩ B|; the band's demand D is their sum (and the
  same downwards for the goals below their objects).
* **An object moves only with a hand.** Held, it moves as the hand does, at an offset of at most
  h_j (eqs. 8, 10–11), so its rise in B is the hand's in B' = B ⊕ h; released at k, it slides one
  step at the hand's velocity of step k − 1 (docs/model.md, "The one-step slide"), while the
  hand moves at its velocity of step k: the object gets ahead of the hand by Δt·(v(k−1) − v(k)),
  what the hand's speed drops at the release.
* **One object at a time.** A hand holds one object (15), and with no-swap (20) none other in
  the step after a release, so what a hand lifts during one of its runs (a maximal stretch of
  steps with v > 0 on the axis) is what that run climbs in B', a, plus the drops of its speed,
  at most Q: half the variation of its velocity, for which it pays 2Q/Δt of (17) on that axis.
  Q is at least the least peak P(a, N) of a run of N steps that covers a (``motion.py``).
* **Runs alternate.** Up and down in turn, one more of one kind at most; and what a hand climbs
  in B' it descends again but for the band's width: Σ a_up − Σ a_down ≤ b'_hi − z_0 (z_0 its
  start, clipped to B'), and the other way.
* **The runs share the steps 1 … T − 1**: every plan starts and ends at rest.

For each hand, direction and run length N (steps), a linear program counts the runs X, the
sum A of what they climb in B' and the sum S of their Q: S ≥ Σ P(a, N), which, P being convex
in a (the inverse of the concave distance a run at peak P covers), its tangents bound from
below, linearly in (X, A); A ≤ X·min(width of B', what v_max covers in N steps); the demand
Σ (A + Δt·S) ≥ D on the runs that go its way; cost Σ 2S/Δt. Its least cost bounds what both
hands pay on that axis in every plan (relaxing the counts to reals only lowers it). The bound
is the best over a few bands per axis, the axes added.

It holds without no-throw and without rule 2's no-juggle (19); it needs no-swap (20) for each
object that may be thrown (or no-throw, whose slide stays in the goal, outside every band). It
is weaker than the motion bound where that holds: a run may lift several objects part of the
way each, which the model allows. ``tests/test_band.py`` checks it against verified plans that
throw and relay, and the optima of small rule-2 tasks.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import coo_matrix

from dualarm_mpc.model.mld import N_HANDS, POSITION_TOL, Model, State, at_rest, in_goal
from dualarm_mpc.model.spec import Specification

# Each run's least peak P(a, N) is bounded from below by its tangents at these many peaks.
TANGENTS = 24
# The band's ends on each axis are drawn from this many quantiles of the objects' places and
# their goals' edges: every pair of them is one band.
BAND_ENDS = 7


def holds(spec: Specification) -> bool:
    """Whether the bound holds under ``spec``: for each of its objects, no-throw (18) or no-swap
    (20) in force for both arms."""
    return spec.released_only_in_goal() | spec.kept_by("no-swap (20)") == frozenset(spec.objects)


def task_bound(model: Model, state: State, objects: list[int], horizon: int,
               m_o: int | None = None) -> float:
    """A lower bound of the cost (17) of every plan of ``horizon`` steps or fewer that delivers
    every one of ``objects`` (model indices) from ``state``, or any ``m_o`` of them (φ_task,
    eq. 13), for a specification that forbids a swap (20) after each release outside the goal.
    0 where it does not apply: a hand or an object moving (an object held at rest is one more
    grasp; a hand's runs start from rest, and only a hand moves an object)."""
    todo = [j for j in objects if not in_goal(state.object_pos[j], model.goals[j])]
    # the objects in their goals already may be among the m_o: the fewest left to deliver
    need = len(todo) if m_o is None else m_o - (len(objects) - len(todo))
    if need <= 0 or horizon < 2 or not (at_rest(state.hand_vel).all() and
                                        at_rest(state.object_vel).all()):
        return 0.0
    total = 0.0
    program = _Program(model, state, todo, horizon)
    for axis in range(2):
        places = state.object_pos[todo, axis]
        near = np.array([model.goals[j].lo[axis] for j in todo]) - POSITION_TOL
        far = np.array([model.goals[j].hi[axis] for j in todo]) + POSITION_TOL
        ends = np.unique(np.quantile(np.r_[places, near, far], np.linspace(0, 1, BAND_ENDS)))
        bounds = [program.bound(axis, lo, hi, places, near, far, need)
                  for lo, hi in itertools.combinations(ends, 2)]
        # A band no plan within the horizon meets would mean no plan at all, which the route
        # bound and the search decide, not this one: it says nothing then.
        total += max((b for b in bounds if np.isfinite(b)), default=0.0)
    return total * (1 - 1e-6)


class _Program:
    """The linear program of one axis (module docstring), built once for both: an axis and a
    band change only the width's caps and the right-hand sides."""

    def __init__(self, model: Model, state: State, objects: list[int], horizon: int) -> None:
        self.model, self.steps = model, horizon - 1
        self.half = float(model.grasp_half[objects].max()) + POSITION_TOL
        self.start = state.hand_pos  # (hand, axis)
        dt, T1 = model.dt, self.steps
        n = np.arange(1, T1 + 1)
        # the speed a run of N steps can have at its k-th step, from rest and back (|u| ≤ u_max)
        ramp = model.u_max * dt * np.minimum(n[None, :], n[:, None] + 1 - n[None, :])
        ramp = np.where(n[None, :] <= n[:, None], ramp, 0.0)  # (N, k)
        peak = np.linspace(0.0, model.v_max, TANGENTS)
        # a run of N steps at peak P covers Δt·Σ_k min(P, ramp_k) at most: concave in P, so the
        # least peak P(a, N) is convex in a, its slope from the left 1 / (Δt·#{k : ramp_k ≥ P})
        length = dt * np.minimum(peak[None, :, None], ramp[:, None, :]).sum(axis=2)  # (N, P)
        capped = (ramp[:, None, :] >= peak[None, :, None]).sum(axis=2)
        self.reach = length[:, -1]  # what v_max covers in N steps
        # columns (hand, way, X | A | S, N): X the runs, A what they climb in B', S their Q
        self.shape = (N_HANDS, 2, 3, T1)
        rows, cols, vals, caps = [], [], [], []

        def add(row, col, val, cap=False):
            row, col, val = np.broadcast_arrays(row, col, val)
            rows.append(row.ravel())
            cols.append(col.ravel())
            vals.append(np.asarray(val, float).ravel())
            caps.append(np.full(row.size, cap))

        def col(hand, way, var):
            return np.ravel_multi_index((hand, way, var, 0), self.shape) + np.arange(T1)

        r = 0
        for hand in range(N_HANDS):
            up, down = (col(hand, way, 0) for way in range(2))
            climb, descent = (col(hand, way, 1) for way in range(2))
            add(r, np.r_[up, down], np.r_[n, n])  # the steps 1 … T − 1
            add(r + 1, np.r_[up, down], np.r_[np.ones(T1), -np.ones(T1)])  # runs alternate
            add(r + 2, np.r_[up, down], np.r_[-np.ones(T1), np.ones(T1)])
            add(r + 3, np.r_[climb, descent], np.r_[np.ones(T1), -np.ones(T1)])  # B' returns
            add(r + 4, np.r_[climb, descent], np.r_[-np.ones(T1), np.ones(T1)])
            r += 5
        for hand in range(N_HANDS):
            for way in range(2):
                x, a, s = (col(hand, way, var) for var in range(3))
                add(r + np.arange(T1), a, 1.0)  # A ≤ X·min(width of B', reach)
                add(r + np.arange(T1), x, -self.reach, cap=True)
                r += T1
                ok = capped > 0  # S ≥ Σ tangents: S ≥ P·X + slope·(A − length·X)
                N, t = np.nonzero(ok)
                slope = 1.0 / (dt * capped[N, t])
                cut = r + np.arange(len(N))
                add(cut, s[N], -1.0)
                add(cut, a[N], slope)
                add(cut, x[N], peak[t] - slope * length[N, t])
                r += len(N)
        self.demand_rows = (r, r + 1)  # what the objects must move, against what runs lift
        for way in range(2):
            for hand in range(N_HANDS):
                add(r + way, col(hand, way, 1), -1.0)
                add(r + way, col(hand, way, 2), -dt)
        self.n_rows = r + 2
        self.rows, self.cols = np.concatenate(rows), np.concatenate(cols)
        self.vals, self.caps = np.concatenate(vals), np.concatenate(caps)
        cost = np.zeros(self.shape)
        cost[:, :, 2] = 2 / dt
        self.cost = cost.ravel()

    def bound(self, axis: int, lo: float, hi: float, places: np.ndarray, near: np.ndarray,
              far: np.ndarray, need: int) -> float:
        """The least cost of both hands on ``axis`` for the band [lo, hi] and any ``need`` of
        the objects (inf: none within the horizon)."""
        # the cost grows with both demands, so each is the least over the choices of objects
        demand = [np.sort(np.clip(rise, 0, None))[:need].sum() for rise in
                  (np.minimum(near, hi) - np.maximum(places, lo),
                   np.minimum(places, hi) - np.maximum(far, lo))]
        if max(demand) <= 0:
            return 0.0
        ws = self.model.workspace
        b_hi = min(hi + self.half, ws.hi[axis])
        b_lo = min(max(lo - self.half, ws.lo[axis]), b_hi)  # empty past the hand range
        vals = self.vals.copy()
        vals[self.caps] = np.maximum(-(b_hi - b_lo), vals[self.caps])
        rhs = np.zeros(self.n_rows)
        for hand in range(N_HANDS):
            z0 = np.clip(self.start[hand, axis], b_lo, b_hi)
            rhs[5 * hand: 5 * hand + 5] = [self.steps, 1.0, 1.0, b_hi - z0, z0 - b_lo]
        rhs[list(self.demand_rows)] = [-demand[0], -demand[1]]
        matrix = coo_matrix((vals, (self.rows, self.cols)), shape=(self.n_rows, self.cost.size))
        lp = linprog(self.cost, A_ub=matrix.tocsr(), b_ub=rhs, bounds=(0, None), method="highs")
        return lp.fun if lp.status == 0 else np.inf if lp.status == 2 else 0.0


__all__ = ["holds", "task_bound"]
