"""The plan in force as Drake's own trajectories, for stock systems (``TrajectorySource``,
``TrajectoryAffineSystem``, plotting) and for users who never read a
:class:`~dualarm_mpc.model.plan.TimedTrajectory`'s arrays. Step k of the plan is at
``t_k = t0 + k·Δt`` in simulated time.

- ``hand`` (4 rows: x, y of hand 1, the right, then of hand 2; m): the cubic Hermite spline
  through the plan's positions and the interpolator's node velocities
  (:func:`~dualarm_mpc.systems.interpolator.node_velocities`) at the steps: the planar curve
  the robot's reference follows (the interpolator further keeps it in the hand range and
  eq. (16)'s gap between steps, where a turning velocity swings it out by centimetres).
  C¹: its derivative is that reference's velocity.
- ``objects`` (2N rows: x_j, y_j; m): first-order hold, which is the plan's Euler model exactly:
  an object moves at ``v_obj(k)`` all through step k (still while at rest, with its hand while
  held, one step on after its release).
- ``grasp`` (2N rows, η_ij row-major ``i·N + j``, 0 or 1; the layout of the interpolator's
  ``grasp_command`` and the measured ``grasp_state``): zero-order hold, η(k) over
  ``[t_k, t_{k+1})``. It spans one Δt more than the others, so that η(K) holds from ``t_K`` on.

Drake evaluates a trajectory outside its span at the nearest end: before the plan and after it
the hands and objects stand at its first and last positions, as the interpolator keeps them. A
plan of one step (K = 0) holds its positions for one Δt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.trajectories import PiecewisePolynomial

from dualarm_mpc.model.plan import TimedTrajectory
from dualarm_mpc.systems.interpolator import node_velocities


@dataclass(frozen=True)
class PlanTrajectories:
    """A plan's hands, objects and grasps over simulated time (the module's docstring)."""

    hand: PiecewisePolynomial  # 4 rows: x, y of hand 1 (right), then hand 2; cubic Hermite
    objects: PiecewisePolynomial  # 2N rows: x, y of each object; first-order hold
    grasp: PiecewisePolynomial  # 2N rows: η_ij at i·N + j; zero-order hold


def _knots(timed: TimedTrajectory) -> tuple[np.ndarray, int]:
    """The steps' times, and how many steps the plan has (a plan of one step is held a Δt)."""
    last = max(len(timed.trajectory.hand_pos) - 1, 1)
    return timed.t0 + timed.dt * np.arange(last + 1), last


def _columns(rows: np.ndarray, last: int) -> np.ndarray:
    """Per-step arrays (K+1, …) as Drake's samples, one column per knot (K = 0 held)."""
    rows = rows.reshape(len(rows), int(np.prod(rows.shape[1:])))
    return np.vstack([rows, rows[-1:].repeat(last + 1 - len(rows), axis=0)]).T


def hand_trajectory(timed: TimedTrajectory) -> PiecewisePolynomial:
    """The hands' planar curve: cubic Hermite through the steps' positions and node velocities."""
    traj = timed.trajectory
    breaks, last = _knots(timed)
    velocity = np.array([node_velocities(traj, k) for k in range(len(traj.hand_pos))])
    if len(traj.hand_pos) == 1:  # held: at rest over the one Δt
        velocity = np.zeros_like(velocity)
    return PiecewisePolynomial.CubicHermite(breaks, _columns(traj.hand_pos, last),
                                            _columns(velocity, last))


def object_trajectory(timed: TimedTrajectory) -> PiecewisePolynomial:
    """The objects' positions, linear between steps as the plan's model moves them."""
    breaks, last = _knots(timed)
    return PiecewisePolynomial.FirstOrderHold(breaks, _columns(timed.trajectory.object_pos, last))


def grasp_schedule(timed: TimedTrajectory) -> PiecewisePolynomial:
    """η of each step held over it; the last one from ``t_K`` on."""
    grasp = np.asarray(timed.trajectory.grasp, dtype=float)
    breaks = timed.t0 + timed.dt * np.arange(len(grasp) + 1)
    return PiecewisePolynomial.ZeroOrderHold(breaks, _columns(grasp, len(grasp)))


def plan_trajectories(timed: TimedTrajectory) -> PlanTrajectories:
    """The plan ``timed`` as three Drake ``PiecewisePolynomial`` objects (module docstring)."""
    return PlanTrajectories(hand_trajectory(timed), object_trajectory(timed),
                            grasp_schedule(timed))
