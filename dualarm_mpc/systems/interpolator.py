"""Interpolator: samples a timed plan into hand references and grasp commands at time t.

The plan is a :class:`~dualarm_mpc.model.plan.TimedTrajectory`: step k of its trajectory happens at
``t_k = t0 + k·dt``. In the plane each hand follows the cubic Hermite spline through the plan's
positions and velocities at the steps (with one exception at releases, below). Its height
follows a separate profile:

- at ``travel_height`` while the hand holds nothing (its tip clears every object);
- at ``grasp_height`` (its tip on the objects' top faces) while it holds any object, so that
  the tip never enters an object (docs/drake.md, the gripper);
- it descends during the step before a grasp begins and rises during the step after a release
  (a hand that releases at step k and grasps again at k + 1 stays down).

In numbers: the node height is ``z_k = grasp_height`` if hand i holds something at step k or at
step k − 1, else ``travel_height``; between nodes a smoothstep with zero end velocities. Held
objects stay on the table and slide with the hand (they are not lifted): that is how throws work.

Release: at a step where a hand lets an object go, the spline's velocity is the hand's velocity
of the step before, the one the released object keeps in the plan's model (see
:func:`node_velocities`), so the object leaves the hand as the planner predicted.

Limits: the plan's model changes a hand's velocity at once at a step, a curve with a continuous
velocity cannot, so where the velocity turns at a node the spline first passes it: by
centimetres at §V-C's speeds, out of the hand range or closer to the other hand than eq. (16)
allows (on a §V-C run, 5.2 cm in x where the nodes keep 10, the arms 2.3 cm apart). Given the
hand range and eq. (16)'s gap (:class:`Limits`), the reference is kept where every node of a
plan is: each hand inside the range (a component held at a bound stops there), and
``x_1 − x_2 ≥ gap`` by moving both hands apart by half the shortfall each (along the range's
edge when one is on it), both then at their mean x velocity, which keeps the gap. At the nodes
nothing moves, so grasps and releases happen where and at the velocity the plan says.

Grasp command: for ``t`` in ``[t_k, t_{k+1})`` it is ``grasp[k]``; after the last step K it stays
``grasp[K]``, before ``t0`` it is ``grasp[0]``. Outside ``[t0, t_K]`` the hand holds the first or
last planned position at zero velocity (the height profile still completes a rise after a release
at the last step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.model.plan import TimedTrajectory, Trajectory, empty_plan, sample_grasp
from dualarm_mpc.model.plan import step_at as _step

TRAVEL_HEIGHT = 0.10  # hand height above the table when it holds nothing (m)

__all__ = ["empty_plan", "sample_grasp"]  # in plan.py: the MPC core needs them without Drake


@dataclass(frozen=True)
class Limits:
    """What the planner keeps the hands in at every step: the hand range ``[x0, x1, y0, y1]``
    and eq. (16)'s ``gap`` (x of arm 2 + gap ≤ x of arm 1)."""

    hand_range: tuple[float, float, float, float]
    gap: float

    def keep(self, out: list[float]) -> None:
        """Moves the reference ``out`` (per arm [x, y, z, vx, vy, vz]) inside, in place."""
        for i in (0, 6):
            for a in (0, 1):
                lo, hi = self.hand_range[2 * a], self.hand_range[2 * a + 1]
                if not lo <= out[i + a] <= hi:
                    out[i + a] = min(max(out[i + a], lo), hi)
                    out[i + 3 + a] = 0.0
        short = self.gap - (out[0] - out[6])
        if short > 0:
            x1, x2, v = out[0] + short / 2, out[6] - short / 2, (out[3] + out[9]) / 2
            lo, hi = self.hand_range[0], self.hand_range[1]
            if x1 > hi:
                x1, x2, v = hi, hi - self.gap, 0.0
            elif x2 < lo:
                x1, x2, v = lo + self.gap, lo, 0.0
            out[0], out[6], out[3], out[9] = x1, x2, v, v


def node_velocities(traj: Trajectory, k: int) -> np.ndarray:
    """The hands' velocities (2, 2) the spline passes through at step k.

    That is ``hand_vel[k]``, except for a hand that releases an object at step k (η_ij(k−1) = 1,
    η_ij(k) = 0): there ``hand_vel[k−1]``. In the plan's Euler model (docs/model.md, the one-step
    slide) the hand moves with ``v(k−1)`` all through step k − 1 and the released object keeps
    ``v_obj(k) = v(k−1)``, so the hand must be moving at ``v(k−1)`` when the grip opens at ``t_k``;
    ``v(k)`` may differ from it by the whole force ``u(k−1)·Δt``. Positions are unchanged.
    """
    v = np.array(traj.hand_vel[k], dtype=float)
    if k > 0:
        grasp = np.asarray(traj.grasp)
        releases = (grasp[k - 1] > 0) & (grasp[k] == 0)  # (2, N)
        for i in np.flatnonzero(releases.any(axis=1)):
            v[i] = traj.hand_vel[k - 1][i]
    return v


class HandSpline:
    """A plan's spline, with its nodes computed once: the positions, :func:`node_velocities` and
    node heights of every step (sampling it runs at every 2 ms plant step, a plan lasts a Δt)."""

    def __init__(self, plan: TimedTrajectory, travel_height: float, grasp_height: float,
                 limits: Limits | None = None):
        traj = plan.trajectory
        self.plan = plan
        self._limits = limits
        self._last = len(traj.hand_pos) - 1
        # Nested lists of floats: sampling is scalar arithmetic, cheaper than small arrays.
        self._pos = np.asarray(traj.hand_pos, dtype=float).tolist()
        self._vel = [node_velocities(traj, k).tolist() for k in range(self._last + 1)]
        # Node m is low if hand i holds something at step m or m − 1 (steps clamped to the
        # plan): m = 0..K + 1, the last completing a rise after a release at step K.
        held = np.asarray(traj.grasp).any(axis=2)  # (K+1, 2)
        held = np.vstack([held[:1], held, held[-1:]])  # steps −1..K+1, clamped
        self._z = np.where(held[1:] | held[:-1], grasp_height, travel_height).tolist()

    def at(self, t: float) -> np.ndarray:
        """The hand reference at time t: per arm [x, y, z, vx, vy, vz] (length 12)."""
        k, s = _step(self.plan, t)
        dt, last = self.plan.dt, self._last
        z0 = self._z[min(max(k, 0), last + 1)]
        z1 = self._z[min(max(k + 1, 0), last + 1)]
        rise, rate = 3 * s * s - 2 * s * s * s, (6 * s - 6 * s * s) / dt
        out = []
        if 0 <= k < last:
            # Cubic Hermite on [t_k, t_{k+1}] through (p_k, v_k) and (p_{k+1}, v_{k+1}).
            s2, s3 = s * s, s * s * s
            h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
            d00, d10, d01, d11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
            p0, p1, v0, v1 = self._pos[k], self._pos[k + 1], self._vel[k], self._vel[k + 1]
            for i in range(2):
                (a, b), (c, d) = p0[i], p1[i]
                (va, vb), (vc, vd) = v0[i], v1[i]
                out += [h00 * a + h10 * dt * va + h01 * c + h11 * dt * vc,
                        h00 * b + h10 * dt * vb + h01 * d + h11 * dt * vd,
                        z0[i] + (z1[i] - z0[i]) * rise,
                        (d00 * a + d10 * dt * va + d01 * c + d11 * dt * vc) / dt,
                        (d00 * b + d10 * dt * vb + d01 * d + d11 * dt * vd) / dt,
                        (z1[i] - z0[i]) * rate]
        else:
            p = self._pos[0 if k < 0 else last]
            for i in range(2):
                out += [p[i][0], p[i][1], z0[i] + (z1[i] - z0[i]) * rise,
                        0.0, 0.0, (z1[i] - z0[i]) * rate]
        if self._limits is not None:
            self._limits.keep(out)
        return np.array(out)


def sample_hands(
    plan: TimedTrajectory, t: float, travel_height: float, grasp_height: float,
    limits: Limits | None = None,
) -> np.ndarray:
    """The hand reference at time t: per arm [x, y, z, vx, vy, vz] (length 12)."""
    return HandSpline(plan, travel_height, grasp_height, limits).at(t)


class Interpolator(LeafSystem):
    """Turns the timed plan into references for the arms and commands for the gripper.

    .. pydrake_system::

        name: Interpolator
        input_ports:
        - plan
        output_ports:
        - hand_reference
        - grasp_command

    ``plan`` is abstract-valued: a :class:`~dualarm_mpc.model.plan.TimedTrajectory`.
    ``hand_reference`` (12): per arm i = 0 (right), 1 (left) the block [x, y, z, vx, vy, vz] at
    ``6i``. ``grasp_command`` (2N): η_ij of the step in force, row-major, index ``i·N + j``.
    Both outputs are pure functions of the time and the plan (no state, no solver).
    """

    def __init__(
        self,
        n_objects: int,
        grasp_height: float,
        travel_height: float = TRAVEL_HEIGHT,
        limits: Limits | None = None,
    ):
        super().__init__()
        if n_objects < 0:
            raise ValueError(f"n_objects must be >= 0, got {n_objects}")
        if not 0 <= grasp_height < travel_height:
            raise ValueError(
                f"need 0 <= grasp_height < travel_height, got {grasp_height}, {travel_height}"
            )
        self._n_objects = n_objects
        self._grasp_height = grasp_height
        self._travel_height = travel_height
        self._limits = limits
        self._last: HandSpline | None = None  # a cache only: outputs depend on (t, plan) alone
        self._plan = self.DeclareAbstractInputPort(
            "plan", AbstractValue.Make(empty_plan(n_objects))
        )
        self._hand_reference = self.DeclareVectorOutputPort(
            "hand_reference", 12, self._calc_hand_reference
        )
        self._grasp_command = self.DeclareVectorOutputPort(
            "grasp_command", 2 * n_objects, self._calc_grasp_command
        )

    def get_plan_input_port(self):
        return self._plan

    def get_hand_reference_output_port(self):
        return self._hand_reference

    def get_grasp_command_output_port(self):
        return self._grasp_command

    def _spline(self, context) -> HandSpline:
        """The spline of the plan in force; built and checked once per plan (the planner's
        output holds the same object until the next replan)."""
        plan = self._plan.Eval(context)
        if self._last is None or self._last.plan is not plan:
            if not isinstance(plan, TimedTrajectory):
                raise TypeError(f"Interpolator.plan: expected a TimedTrajectory, got {type(plan)}")
            n = plan.trajectory.grasp.shape[2]
            if n != self._n_objects:
                raise ValueError(f"Interpolator.plan: {n} objects, expected {self._n_objects}")
            self._last = HandSpline(plan, self._travel_height, self._grasp_height, self._limits)
        return self._last

    def _calc_hand_reference(self, context, output):
        output.SetFromVector(self._spline(context).at(context.get_time()))

    def _calc_grasp_command(self, context, output):
        output.SetFromVector(sample_grasp(self._spline(context).plan, context.get_time()))
