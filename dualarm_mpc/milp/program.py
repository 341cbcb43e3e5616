"""The MILP of one horizon: the MLD model (eqs. 1, 7–11, 14–16) and cost (17) as a program.

One ``add_<family>`` function per constraint family, built in vectorized blocks (``linear.Rows``)
with every big-M derived from the scenario's bounds and the reachable boxes of ``mld.reachability``.
The LTL part is added by ``encoding.py``; this module knows nothing of formulas. With the objects'
spacing, :class:`Clearance` holds (C1)–(C2) (ours, docs/formulation.md), whose rows a solve adds
pair by pair, as its solutions need them (``HorizonProgram.solve``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from dualarm_mpc.milp.linear import Rows, bound, new_variables
from dualarm_mpc.model.mld import FIRST_MOVE_TOL, N_HANDS, Model, Reach, State, meet

# The four sides (C1) of another object's square a moving one may keep to: +x, −x, +y, −y
SIDES = ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0))


@dataclass(frozen=True)
class HorizonVariables:
    """Indices (into ``prog.decision_variables()``) of the variables of one horizon k = 0..T."""

    horizon: int
    hand_pos: np.ndarray  # (T+1, 2, 2)
    hand_vel: np.ndarray  # (T+1, 2, 2)
    force: np.ndarray  # (T, 2, 2): u
    force_abs: np.ndarray  # (T, 2, 2): |u|, for cost (17)
    object_pos: np.ndarray  # (T+1, N, 2)
    object_vel: np.ndarray  # (T+1, N, 2)
    eta: np.ndarray  # (T+1, 2, N) binary: hand i grabs object j
    theta: np.ndarray  # (T+1, N) binary: object j in its goal (one-sided, eq. 7)

    @property
    def binaries(self) -> np.ndarray:
        return np.concatenate([self.eta.ravel(), self.theta.ravel()])


def new_horizon_variables(prog: MathematicalProgram, horizon: int, n: int) -> HorizonVariables:
    T = horizon
    return HorizonVariables(
        horizon=T,
        hand_pos=new_variables(prog, (T + 1, N_HANDS, 2), "p_hand"),
        hand_vel=new_variables(prog, (T + 1, N_HANDS, 2), "v_hand"),
        force=new_variables(prog, (T, N_HANDS, 2), "u"),
        force_abs=new_variables(prog, (T, N_HANDS, 2), "abs_u"),
        object_pos=new_variables(prog, (T + 1, n, 2), "p_obj"),
        object_vel=new_variables(prog, (T + 1, n, 2), "v_obj"),
        eta=new_variables(prog, (T + 1, N_HANDS, n), "eta", binary=True),
        theta=new_variables(prog, (T + 1, n), "theta", binary=True),
    )


def object_speed_bound(model: Model, state: State) -> float:
    """|v_obj| per component: a hand's speed, or the measured speed if an object slides faster."""
    return max(model.v_max, float(np.abs(state.object_vel).max(initial=0.0)))


def add_bounds(prog, x: HorizonVariables, model: Model, state: State, reach: Reach,
               pruning: bool) -> None:
    """Initial state, variable bounds, reachable boxes and pruning (§IV-C.2).

    Pruning fixes η_ij(k) = 0 before hand i can reach object j and θ_j(k) = 0 before object j can
    reach its goal; the reachable boxes bound every position, which also tightens every big-M."""
    vo = object_speed_bound(model, state)
    bound(prog, x.hand_pos, reach.hand_lo, reach.hand_hi)
    bound(prog, x.hand_vel[1:], -model.v_max, model.v_max)
    bound(prog, x.hand_vel[0], state.hand_vel, state.hand_vel)
    bound(prog, x.force, -model.u_max, model.u_max)
    bound(prog, x.force_abs, 0.0, model.u_max)
    bound(prog, x.object_pos, reach.object_lo, reach.object_hi)
    bound(prog, x.object_vel[1:], -vo, vo)
    bound(prog, x.object_vel[0], state.object_vel, state.object_vel)
    eta_ub = np.ones(x.eta.shape)
    theta_ub = np.ones(x.theta.shape)
    if pruning:
        eta_ub = reach.grab_possible().astype(float)
        theta_ub = reach.goal_possible().astype(float)
    eta_lb = np.zeros(x.eta.shape)
    eta_lb[0] = eta_ub[0] = state.grasp  # the grasp in force now is measured, not decided
    bound(prog, x.eta, eta_lb, eta_ub)
    bound(prog, x.theta, 0.0, theta_ub)


def add_dynamics(prog, x: HorizonVariables, model: Model) -> None:
    """Eq. (1): double integrators ``p⁺ = p + Δt·v`` (hands, objects), ``v⁺ = v + Δt·u`` (hands)."""
    rows = Rows()
    dt = model.dt
    rows.add([(1, x.hand_pos[1:]), (-1, x.hand_pos[:-1]), (-dt, x.hand_vel[:-1])], 0, 0)
    rows.add([(1, x.hand_vel[1:]), (-1, x.hand_vel[:-1]), (-dt, x.force)], 0, 0)
    rows.add([(1, x.object_pos[1:]), (-1, x.object_pos[:-1]), (-dt, x.object_vel[:-1])], 0, 0)
    rows.emit(prog, "dynamics (1)")


def add_picking(prog, x: HorizonVariables, model: Model, state: State, reach: Reach) -> None:
    """The picking model, eqs. (8)–(11) as docs/model.md explains them, linearized with big-M.

    For k ≥ 1, with ``held_j(k) = Σ_i η_ij(k)`` (0 or 1 by eq. 14):

    * (8)  η_ij(k) = 1 → v_obj_j(k) = v_hand_i(k):   |v_obj − v_hand| ≤ M_v·(1 − η_ij)
    * slide after release:  |v_obj(k) − v_obj(k−1)| ≤ M_v·(held(k) + 1 − held(k−1))
    * otherwise at rest:   |v_obj(k)| ≤ v̄·(held(k) + held(k−1))
    * (10)–(11) η_ij(k) = 1 → |p_hand_i − p_obj_j| ≤ h_j per axis, with M from the reachable boxes.
    """
    rows = Rows()
    vo = object_speed_bound(model, state)
    Mv = model.v_max + vo
    eta = x.eta[1:]  # (T, 2, N)
    v_obj = x.object_vel[1:][:, None]  # (T, 1, N, 2)
    v_hand = x.hand_vel[1:][:, :, None]  # (T, 2, 1, 2)
    e = eta[..., None]
    rows.add([(1, v_obj), (-1, v_hand), (Mv, e)], ub=Mv)
    rows.add([(-1, v_obj), (1, v_hand), (Mv, e)], ub=Mv)

    # held(k) and held(k−1) as sums over the hands, broadcast over the axis.
    now = [x.eta[1:, i, :, None] for i in range(N_HANDS)]
    before = [x.eta[:-1, i, :, None] for i in range(N_HANDS)]
    slide = [(-2 * vo, h) for h in now] + [(2 * vo, h) for h in before]
    rows.add([(1, x.object_vel[1:]), (-1, x.object_vel[:-1])] + slide, ub=2 * vo)
    rows.add([(-1, x.object_vel[1:]), (1, x.object_vel[:-1])] + slide, ub=2 * vo)
    rest = [(-vo, h) for h in now + before]
    rows.add([(1, x.object_vel[1:])] + rest, ub=0)
    rows.add([(-1, x.object_vel[1:])] + rest, ub=0)

    # (10)-(11): the hand inside H_ij while grabbing; M from the reachable boxes of both.
    half = model.grasp_half[None, None, :, None]
    hand_lo = reach.hand_lo[1:, :, None]
    hand_hi = reach.hand_hi[1:, :, None]
    obj_lo = reach.object_lo[1:, None]
    obj_hi = reach.object_hi[1:, None]
    p_hand = x.hand_pos[1:][:, :, None]
    p_obj = x.object_pos[1:][:, None]
    m_up = np.maximum(hand_hi - obj_lo - half, 0.0)
    m_down = np.maximum(obj_hi - hand_lo - half, 0.0)
    rows.add([(1, p_hand), (-1, p_obj), (m_up, e)], ub=half + m_up)
    rows.add([(-1, p_hand), (1, p_obj), (m_down, e)], ub=half + m_down)
    rows.emit(prog, "picking model (8)-(11)")


def add_system_constraints(prog, x: HorizonVariables, model: Model) -> None:
    """Eqs. (14)–(16), and a rest at the horizon's end so the next sequential step can go on:
    (14) Σ_i η_ij ≤ 1, (15) Σ_j η_ij ≤ 1, (16) x_arm2 + gap ≤ x_arm1; v_hand(T) = v_obj(T) = 0."""
    rows = Rows()
    rows.add([(1, x.eta[1:, 0]), (1, x.eta[1:, 1])], ub=1)
    n = x.eta.shape[2]
    for i in range(N_HANDS):
        rows.add([(1, x.eta[1:, i, j]) for j in range(n)], ub=1)
    rows.add([(1, x.hand_pos[1:, 0, 0]), (-1, x.hand_pos[1:, 1, 0])], lb=model.hand_gap)
    rows.emit(prog, "system constraints (14)-(16)")
    bound(prog, x.hand_vel[-1], 0.0, 0.0)
    bound(prog, x.object_vel[-1], 0.0, 0.0)


def add_goal_atoms(prog, x: HorizonVariables, model: Model, reach: Reach) -> None:
    """Eqs. (7), (12): θ_j(k) = 1 → p_obj_j(k) in goal box H_j, one-sided big-M [18]."""
    rows = Rows()
    lo = np.array([g.lo for g in model.goals])[None]  # (1, N, 2)
    hi = np.array([g.hi for g in model.goals])[None]
    m_up = np.maximum(reach.object_hi - hi, 0.0)
    m_down = np.maximum(lo - reach.object_lo, 0.0)
    th = x.theta[..., None]
    rows.add([(1, x.object_pos), (m_up, th)], ub=hi + m_up)
    rows.add([(-1, x.object_pos), (m_down, th)], ub=-lo + m_down)
    rows.emit(prog, "goal atoms (7), (12)")


def add_cost(prog, x: HorizonVariables, state_weight: float = 0.0) -> list[np.ndarray]:
    """Eq. (17): J = Σ_k ‖u_1(k)‖₁ + ‖u_2(k)‖₁ via |u| ≥ ±u, plus an optional ‖v_hand‖₁ weight.

    Returns each hand's share of the linear cost over ``prog.decision_variables()``, so that the
    skeleton search can cost one hand alone."""
    rows = Rows()
    rows.add([(1, x.force_abs), (-1, x.force)], lb=0)
    rows.add([(1, x.force_abs), (1, x.force)], lb=0)
    terms = [(x.force_abs, 1.0)]
    if state_weight > 0:
        speed = new_variables(prog, x.hand_vel.shape, "abs_v")
        rows.add([(1, speed), (-1, x.hand_vel)], lb=0)
        rows.add([(1, speed), (1, x.hand_vel)], lb=0)
        terms.append((speed, state_weight))
    rows.emit(prog, "cost (17) epigraph")
    shares = [np.zeros(prog.num_vars()) for _ in range(N_HANDS)]
    for index, weight in terms:  # index (steps, hand, axis)
        for i in range(N_HANDS):
            shares[i][index[:, i].ravel()] = weight
    total = sum(shares)
    used = np.flatnonzero(total)
    prog.AddLinearCost(total[used], 0.0, prog.decision_variables()[used])
    return shares


def add_settling(prog, x: HorizonVariables, state: State) -> None:
    """(C3), with the objects' spacing (docs/formulation.md): an object released at k is not
    held again at k + 1 — held_j(k + 1) + held_j(k − 1) − held_j(k) ≤ 1, held_j = Σ_i η_ij —
    and one sliding now (unheld, moving) is not held at 1. The model's slide ends at k + 1;
    the robot's is a third short there (the table's drag), and a hand that takes it there
    carries it that far off its plan, past the spacing (C1) keeps."""
    rows = Rows()
    held = [x.eta[:, i] for i in range(N_HANDS)]  # (T+1, N) each
    rows.add([(1, h[2:]) for h in held] + [(1, h[:-2]) for h in held]
             + [(-1, h[1:-1]) for h in held], ub=1)
    rows.emit(prog, "settling (C3)")
    sliding = ~state.grasp.any(axis=0) & (np.abs(state.object_vel).max(axis=1) > 0)
    bound(prog, x.eta[1][:, sliding], 0.0, 0.0)


@dataclass(frozen=True)
class Clearance:
    """(C1)–(C2) of one horizon (docs/formulation.md, "Objects that keep apart"): the triples
    that can matter, each (j, o, k, d_jo) — object j of the step (local index), the other o
    (another object of the step, o < N, or standing box o − N, ``mld.standing``), the step k
    (k ≥ 1) of the segment from k to k + 1, and the spacing it keeps, d_jo = min(d, their
    distance at k = 1, fixed by the state), d = ``model.spacing`` (less ``mld.FIRST_MOVE_TOL``
    at k = 1) — and the rows of any of their pairs."""

    n: int  # objects of the step
    triples: tuple[tuple[int, int, int, float], ...]
    obstacle_lo: np.ndarray  # (N + M, T+1, 2): the other's reachable box (a standing box: fixed)
    obstacle_hi: np.ndarray
    object_lo: np.ndarray  # (T+1, N, 2): the reachable boxes of the step's objects
    object_hi: np.ndarray

    def pairs(self) -> set[tuple[int, int]]:
        return {(j, o) for j, o, _, _ in self.triples}

    def rows(self, x: HorizonVariables, pairs: set[tuple[int, int]], columns: int
             ) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray, np.ndarray]:
        """The rows (A, lb, ub) of the triples of ``pairs`` over the first ``columns`` columns
        (the program's and its specification's) and a binary b_σ per side of each triple after
        them, and each b_σ's upper bound: with r = p_j − p_o (p_o a standing box's face) and
        σ = (axis a, sign s),

        * (C1) s·r_a(k) ≥ d_jo − M·(1 − b_σ), s·r_a(k + 1) ≥ d_jo − M·(1 − b_σ), M from the
          reachable boxes (a side they cannot reach is fixed to 0);
        * (C2) Σ_σ b_σ ≥ held_j(k), held_j(k − 1) (and held_o's, o of the step), with
          held_j = Σ_i η_ij.
        """
        chosen = [t for t in self.triples if (t[0], t[1]) in pairs]
        rows, side_ub = Rows(), []
        for t, (j, o, k, d) in enumerate(chosen):
            ub = []
            for sigma, (a, sign) in enumerate(SIDES):
                b = columns + len(SIDES) * t + sigma
                possible = True
                for step in (k, k + 1):
                    # s·r_a over the reachable boxes: low, high
                    if sign > 0:
                        low = self.object_lo[step, j, a] - self.obstacle_hi[o, step, a]
                        high = self.object_hi[step, j, a] - self.obstacle_lo[o, step, a]
                    else:
                        low = self.obstacle_lo[o, step, a] - self.object_hi[step, j, a]
                        high = self.obstacle_hi[o, step, a] - self.object_lo[step, j, a]
                    M = max(d - low, 0.0)
                    terms = [(sign, int(x.object_pos[step, j, a])), (-M, b)]
                    if o < self.n:
                        terms.append((-sign, int(x.object_pos[step, o, a])))
                        rows.add_row(terms, lb=d - M)
                    else:  # the box's face is a constant
                        face = self.obstacle_hi[o, step, a] if sign > 0 else \
                            -self.obstacle_lo[o, step, a]
                        rows.add_row(terms, lb=d - M + face)
                    possible &= high >= d - 1e-9
                ub.append(1.0 if possible else 0.0)
            side_ub += ub
            sides = [(1.0, columns + len(SIDES) * t + sigma) for sigma in range(len(SIDES))]
            for obj in (j,) if o >= self.n else (j, o):
                for step in (k, k - 1):
                    rows.add_row(sides + [(-1.0, int(x.eta[step, i, obj]))
                                          for i in range(N_HANDS)], lb=0.0)
        return (*rows.matrix(columns + len(SIDES) * len(chosen)), np.array(side_ub, float))

    def broken(self, x: HorizonVariables, values: np.ndarray, pairs: set[tuple[int, int]],
               tol: float = 1e-6) -> set[tuple[int, int]]:
        """The pairs among ``pairs`` whose (C1)–(C2) the solver's ``values`` break: for a triple
        whose objects are held at k or k − 1, no side keeps them ``d_jo`` apart at both ends."""
        held = np.round(values[x.eta]).sum(axis=1) > 0.5  # (T+1, N)
        p = values[x.object_pos]
        out = set()
        for j, o, k, d in self.triples:
            if (j, o) not in pairs or (j, o) in out:
                continue
            if not (held[k, j] or held[k - 1, j] or (o < self.n and (held[k, o]
                                                                      or held[k - 1, o]))):
                continue
            if not any(all(self._beyond(p, j, o, step, a, sign) >= d - tol
                           for step in (k, k + 1)) for a, sign in SIDES):
                out.add((j, o))
        return out

    def _beyond(self, p: np.ndarray, j: int, o: int, step: int, a: int, sign: float) -> float:
        """s·r_a: how far object j lies beyond the other along axis a, side s, at ``step``."""
        if o < self.n:
            return sign * (p[step, j, a] - p[step, o, a])
        face = self.obstacle_hi[o, step, a] if sign > 0 else self.obstacle_lo[o, step, a]
        return sign * (p[step, j, a] - face)


def clearance(x: HorizonVariables, model: Model, state: State, reach: Reach,
              standing_lo: np.ndarray, standing_hi: np.ndarray) -> Clearance:
    """The triples of (C1)–(C2) that can matter: a step k ≥ 1 in which either object may be held
    (pruning's earliest grabs, §IV-C.2), where their reachable boxes over [k, k + 1], widened by
    d_jo, meet; and d_jo > 0 (a pair that starts one inside the other keeps no spacing). The
    first move, k = 1, keeps d_jo less ``mld.FIRST_MOVE_TOL``."""
    d = model.spacing
    T = x.horizon
    p1 = state.object_pos + model.dt * state.object_vel  # where every object is at k = 1
    n = len(p1)
    grab = reach.grab_possible().any(axis=1)  # (T+1, N): may be held at k
    # the others' reachable boxes: the step's objects', then each standing box at every step
    m = len(standing_lo)
    obstacle_lo = np.concatenate([reach.object_lo.transpose(1, 0, 2),
                                  np.broadcast_to(standing_lo[:, None], (m, T + 1, 2))])
    obstacle_hi = np.concatenate([reach.object_hi.transpose(1, 0, 2),
                                  np.broadcast_to(standing_hi[:, None], (m, T + 1, 2))])
    triples = []
    for j in range(n):
        for o in range(j + 1, n + m):
            lo1, hi1 = obstacle_lo[o, 1], obstacle_hi[o, 1]
            d_jo = min(d, max(p1[j, 0] - hi1[0], lo1[0] - p1[j, 0], p1[j, 1] - hi1[1],
                              lo1[1] - p1[j, 1]))
            if d_jo <= 0:
                continue
            for k in range(1, T):
                moves = grab[k - 1:k + 1, j].any() or (o < n and grab[k - 1:k + 1, o].any())
                near = meet(np.minimum(reach.object_lo[k, j], reach.object_lo[k + 1, j]) - d_jo,
                            np.maximum(reach.object_hi[k, j], reach.object_hi[k + 1, j]) + d_jo,
                            np.minimum(obstacle_lo[o, k], obstacle_lo[o, k + 1]),
                            np.maximum(obstacle_hi[o, k], obstacle_hi[o, k + 1]))
                keep = d_jo - (FIRST_MOVE_TOL if k == 1 else 0.0)  # the state is measured
                if moves and near and keep > 0:
                    triples.append((j, o, k, float(keep)))
    return Clearance(n, tuple(triples), obstacle_lo, obstacle_hi, reach.object_lo,
                     reach.object_hi)
