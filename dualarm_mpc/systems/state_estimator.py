"""State estimator: reads the plant into the planner's measured state vector (planar x, y only).

The "estimate" is exact (the simulated plant is observed perfectly); the layout is
:meth:`dualarm_mpc.model.mld.State.vector`'s.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.tree import RigidBody
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.model.mld import State


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
        - hand_positions
        - hand_velocities
        - object_positions
        - object_velocities
        - grasp_state

    ``body_poses`` / ``body_spatial_velocities``: the plant's outputs of the same names (the
    plant's own kinematics, shared with the Gripper; no scratch context is needed).
    ``grasp`` (2N): the Gripper's ``grasp`` output.
    ``measured_state`` (8 + 6N): the measured :class:`~dualarm_mpc.model.mld.State` as
    :meth:`~dualarm_mpc.model.mld.State.vector` lays it out (hand_pos, hand_vel, object_pos,
    object_vel, grasp); hand i = 0 is the right hand, 1 the left, measured at the end-effector
    body's origin. The same values, by name, for stock systems (a ``VectorLogSink``) and readers
    who do not know the layout: ``hand_positions`` (4: x, y of hand 1, then hand 2; m),
    ``hand_velocities`` (4; m/s), ``object_positions`` (2N: x, y of each object; m),
    ``object_velocities`` (2N; m/s), ``grasp_state`` (2N: η_ij at ``i·N + j``, 1 while the
    gripper holds object j in hand i, else 0).
    """

    # The named ports in the order of State.vector's layout.
    PARTS = ("hand_positions", "hand_velocities", "object_positions", "object_velocities",
             "grasp_state")

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
            "measured_state", State.size(self._n), self._calc_measured_state
        )
        start = 0
        for name, size in zip(self.PARTS, (4, 4, *[2 * self._n] * 3), strict=True):
            self.DeclareVectorOutputPort(name, size, self._part(start, size))
            start += size

    def get_body_poses_input_port(self):
        return self._body_poses

    def get_body_spatial_velocities_input_port(self):
        return self._body_velocities

    def get_grasp_input_port(self):
        return self._grasp

    def get_measured_state_output_port(self):
        return self._measured_state

    def _part(self, start: int, size: int):
        """The calc of a named port: its slice of ``measured_state`` (cached: computed once)."""
        def calc(context, output):
            output.SetFromVector(self._measured_state.Eval(context)[start:start + size])
        return calc

    def _calc_measured_state(self, context, output):
        poses = self._body_poses.Eval(context)
        velocities = self._body_velocities.Eval(context)
        p = np.array([poses[b].translation()[:2] for b in self._bodies])
        v = np.array([velocities[b].translational()[:2] for b in self._bodies])
        measured = State(hand_pos=p[:2], hand_vel=v[:2], object_pos=p[2:], object_vel=v[2:],
                         grasp=self._grasp.Eval(context).reshape(2, self._n))
        output.SetFromVector(measured.vector())
