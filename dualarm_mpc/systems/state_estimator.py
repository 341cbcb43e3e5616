"""State estimator: reads the plant into the planner's measured state vector (planar x, y only).

The "estimate" is exact (the simulated plant is observed perfectly); its job is the layout.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.tree import RigidBody
from pydrake.systems.framework import LeafSystem


def measured_state_size(n_objects: int) -> int:
    """8 + 6N: hand positions and velocities, object positions and velocities, grasp."""
    return 8 + 6 * n_objects


def split_measured_state(x: np.ndarray, n_objects: int) -> dict[str, np.ndarray]:
    """The measured state vector as arrays: hand_pos, hand_vel (2, 2), object_pos, object_vel
    (N, 2), grasp (2, N)."""
    n = n_objects
    x = np.asarray(x, dtype=float)
    if x.shape != (measured_state_size(n),):
        raise ValueError(f"measured state: expected {measured_state_size(n)} values, got {x.shape}")
    return {
        "hand_pos": x[0:4].reshape(2, 2),
        "hand_vel": x[4:8].reshape(2, 2),
        "object_pos": x[8 : 8 + 2 * n].reshape(n, 2),
        "object_vel": x[8 + 2 * n : 8 + 4 * n].reshape(n, 2),
        "grasp": x[8 + 4 * n : 8 + 6 * n].reshape(2, n),
    }


class StateEstimator(LeafSystem):
    """Measured planar state of hands and objects, plus the gripper's attachments.

    .. pydrake_system::

        name: StateEstimator
        input_ports:
        - body_poses
        - body_spatial_velocities
        - grasp
        output_ports:
        - measured_state

    ``body_poses`` / ``body_spatial_velocities``: the plant's outputs of the same names (the
    plant's own kinematics, shared with the Gripper; no scratch context is needed).
    ``grasp`` (2N): the Gripper's ``grasp`` output.
    ``measured_state`` (8 + 6N) = [hand_pos (4: x0, y0, x1, y1), hand_vel (4), object_pos (2N:
    x_j, y_j), object_vel (2N), grasp (2N, row-major [i][j])]; hand i = 0 is the right hand,
    1 the left, measured at the end-effector body's origin.
    """

    def __init__(self, hand_bodies: Sequence[RigidBody], object_bodies: Sequence[RigidBody]):
        super().__init__()
        if len(hand_bodies) != 2:
            raise ValueError(f"hand_bodies: expected 2 (right, left), got {len(hand_bodies)}")
        self._n = len(object_bodies)
        self._bodies = tuple(int(b.index()) for b in (*hand_bodies, *object_bodies))
        self._body_poses = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self._body_velocities = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self._grasp = self.DeclareVectorInputPort("grasp", 2 * self._n)
        self._measured_state = self.DeclareVectorOutputPort(
            "measured_state", measured_state_size(self._n), self._calc_measured_state
        )

    def get_body_poses_input_port(self):
        return self._body_poses

    def get_body_spatial_velocities_input_port(self):
        return self._body_velocities

    def get_grasp_input_port(self):
        return self._grasp

    def get_measured_state_output_port(self):
        return self._measured_state

    def _calc_measured_state(self, context, output):
        poses = self._body_poses.Eval(context)
        velocities = self._body_velocities.Eval(context)
        p = np.array([poses[b].translation()[:2] for b in self._bodies])
        v = np.array([velocities[b].translational()[:2] for b in self._bodies])
        output.SetFromVector(
            np.concatenate(
                [
                    p[:2].reshape(-1),
                    v[:2].reshape(-1),
                    p[2:].reshape(-1),
                    v[2:].reshape(-1),
                    self._grasp.Eval(context),
                ]
            )
        )
