"""Interpolator: samples a timed plan into hand references and grasp commands at time t.

The plan is a :class:`~dualarm_mpc.plan.TimedTrajectory`: step k of its trajectory happens at
``t_k = t0 + k·dt``. In the plane each hand follows the cubic Hermite spline through the plan's
positions and velocities at the steps (with one exception at releases, below). Its height
follows a separate profile:

- at ``travel_height`` while the hand holds nothing;
- at ``grasp_height`` (the object's centre) while it holds any object;
- it descends during the step before a grasp begins and rises during the step after a release
  (a hand that releases at step k and grasps again at k + 1 stays down).

In numbers: the node height is ``z_k = grasp_height`` if hand i holds something at step k or at
step k − 1, else ``travel_height``; between nodes a smoothstep with zero end velocities. Held
objects stay on the table and slide with the hand (they are not lifted): that is how throws work.

Release: at a step where a hand lets an object go, the spline's velocity is the hand's velocity
of the step before, the one the released object keeps in the plan's model (see
:func:`node_velocities`), so the object leaves the hand as the planner predicted.

Grasp command: for ``t`` in ``[t_k, t_{k+1})`` it is ``grasp[k]``; after the last step K it stays
``grasp[K]``, before ``t0`` it is ``grasp[0]``. Outside ``[t0, t_K]`` the hand holds the first or
last planned position at zero velocity (the height profile still completes a rise after a release
at the last step).
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.plan import TimedTrajectory, Trajectory, empty_plan, sample_grasp
from dualarm_mpc.plan import step_at as _step

TRAVEL_HEIGHT = 0.10  # hand height above the table when it holds nothing (m)

__all__ = ["empty_plan", "sample_grasp"]  # in plan.py: the MPC core needs them without Drake
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


def sample_hands(
    plan: TimedTrajectory, t: float, travel_height: float, grasp_height: float
) -> np.ndarray:
    """The hand reference at time t: per arm [x, y, z, vx, vy, vz] (length 12)."""
    traj = plan.trajectory
    last = len(traj.hand_pos) - 1
    k, s = _step(plan, t)
    dt = plan.dt
    out = np.zeros((2, 6))
    if 0 <= k < last:
        # Cubic Hermite on [t_k, t_{k+1}] through (p_k, v_k) and (p_{k+1}, v_{k+1}).
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        d00, d10, d01, d11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
        p0, p1 = traj.hand_pos[k], traj.hand_pos[k + 1]
        v0, v1 = node_velocities(traj, k), node_velocities(traj, k + 1)
        out[:, 0:2] = h00 * p0 + h10 * dt * v0 + h01 * p1 + h11 * dt * v1
        out[:, 3:5] = (d00 * p0 + d10 * dt * v0 + d01 * p1 + d11 * dt * v1) / dt
    else:
        out[:, 0:2] = traj.hand_pos[0 if k < 0 else last]

    held = np.asarray(traj.grasp).any(axis=2)  # (K+1, 2): hand i holds something at step k

    def node_low(m: int) -> np.ndarray:
        a, b = held[min(max(m, 0), last)], held[min(max(m - 1, 0), last)]
        return a | b

    z0 = np.where(node_low(k), grasp_height, travel_height)
    z1 = np.where(node_low(k + 1), grasp_height, travel_height)
    out[:, 2] = z0 + (z1 - z0) * (3 * s * s - 2 * s * s * s)
    out[:, 5] = (z1 - z0) * (6 * s - 6 * s * s) / dt
    return out.reshape(-1)


class Interpolator(LeafSystem):
    """Turns the timed plan into references for the arms and commands for the gripper.

    .. pydrake_system::

        name: Interpolator
        input_ports:
        - plan
        output_ports:
        - hand_reference
        - grasp_command

    ``plan`` is abstract-valued: a :class:`~dualarm_mpc.plan.TimedTrajectory`.
    ``hand_reference`` (12): per arm i = 0 (right), 1 (left) the block [x, y, z, vx, vy, vz] at
    ``6i``. ``grasp_command`` (2N): η_ij of the step in force, row-major, index ``i·N + j``.
    Both outputs are pure functions of the time and the plan (no state, no solver).
    """

    def __init__(
        self,
        n_objects: int,
        grasp_height: float,
        travel_height: float = TRAVEL_HEIGHT,
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

    def _checked_plan(self, context) -> TimedTrajectory:
        plan = self._plan.Eval(context)
        if not isinstance(plan, TimedTrajectory):
            raise TypeError(f"Interpolator.plan: expected a TimedTrajectory, got {type(plan)}")
        n = plan.trajectory.grasp.shape[2]
        if n != self._n_objects:
            raise ValueError(f"Interpolator.plan: {n} objects, expected {self._n_objects}")
        return plan

    def _calc_hand_reference(self, context, output):
        plan = self._checked_plan(context)
        output.SetFromVector(
            sample_hands(plan, context.get_time(), self._travel_height, self._grasp_height)
        )

    def _calc_grasp_command(self, context, output):
        output.SetFromVector(sample_grasp(self._checked_plan(context), context.get_time()))
