"""Differential IK controller: hand references → desired joint states of any two arms.

The SCARA has a closed form (:mod:`dualarm_mpc.systems.controller`); any other arm goes through
Drake's differential inverse kinematics (``DoDifferentialInverseKinematics``, a small QP per arm
and update). Every ``IK_PERIOD`` (100 Hz, a robot controller's rate) each arm's commanded posture
q_c moves by h·q̇, q̇ the QP's answer to the hand's desired spatial velocity

    v = v_ref + K_P·(p_ref − p(q_c)),      ω = K_R·log(R_n·R(q_c)ᵀ),

with R_n the hand's orientation in the nominal posture (:mod:`dualarm_mpc.sim.robot`: tool down,
the hand frame's x axis along the line between the hands, where grippers are narrow): the hand
follows the reference and keeps its orientation. The QP keeps the joint position and velocity
limits, and its null-space term pulls toward the nominal posture, so that a redundant arm does
not drift. Joints outside an arm's chain (fingers, a torso both arms share) are held at the
nominal posture, their velocity bound zero.

The output is the plant's desired state [q_c + (t − t_k)·q̇; q̇] per robot model instance, q_c
as of the last update t_k, so that the desired posture moves on between updates at the plant's
2 ms steps; its PD controllers track it (gains and gravity compensation:
:mod:`dualarm_mpc.sim.robot`). At every plant step instead, the QPs cost half the physics of a
Panda pair again (measured).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pydrake.multibody.inverse_kinematics import (
    DifferentialInverseKinematicsParameters,
    DifferentialInverseKinematicsStatus,
    DoDifferentialInverseKinematics,
)
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import Frame, Joint
from pydrake.systems.framework import BasicVector, LeafSystem

K_P = 20.0  # 1/s: the hand's position error closes with a 50 ms time constant
K_R = 20.0  # 1/s: the tool axis's
CENTERING = 1.0  # 1/s: the null-space pull toward the nominal posture
IK_PERIOD = 0.01  # s


@dataclass(frozen=True)
class ArmModel:
    """One arm as the controller sees it: a plant of its model alone (no geometry)."""

    plant: MultibodyPlant
    hand: Frame  # the hand frame in ``plant``
    joints: tuple[Joint, ...]  # the chain the arm moves, base first (the rest held)
    nominal: np.ndarray  # q of ``plant``: the hand above its start, tool down


class DifferentialIkController(LeafSystem):
    """Differential inverse kinematics of two arms, feeding the plant's PD actuators.

    .. pydrake_system::

        name: DifferentialIkController
        input_ports:
        - hand_reference
        output_ports:
        - desired_state_0
        - desired_state_1 (one per robot model instance)

    ``hand_reference`` (12): per arm i = 0 (right), 1 (left) [x, y, z, vx, vy, vz] at ``6i``.
    ``outputs[k]``: the joint names of robot model instance k's actuators in the order of its
    desired-state port, and the arms they may belong to; ``desired_state_k`` is [q; v] of them.
    """

    def __init__(self, arms: Sequence[ArmModel], outputs: Sequence[Sequence[tuple[int, str]]],
                 period: float = IK_PERIOD):
        super().__init__()
        if len(arms) != 2:
            raise ValueError(f"arms: expected 2 (right, left), got {len(arms)}")
        self._arms = tuple(arms)
        self._h = period
        self._contexts = [arm.plant.CreateDefaultContext() for arm in arms]
        self._params = [self._parameters(arm) for arm in arms]
        self._orientations = []  # R_n per arm
        for arm, context in zip(arms, self._contexts, strict=True):
            arm.plant.SetPositions(context, arm.nominal)
            self._orientations.append(arm.hand.CalcPoseInWorld(context).rotation())
        # the chain's slots in the state, per arm: positions, then velocities
        self._sizes = [len(arm.joints) for arm in arms]
        start = np.cumsum([0, *self._sizes])
        self._slots = [slice(start[i], start[i + 1]) for i in range(2)]
        n = int(start[-1])
        self._n = n
        # [q_c (n); q̇ (n); t_k]: the posture and its rate as of the last update t_k
        initial = np.concatenate([*(arm.nominal[[j.position_start() for j in arm.joints]]
                                    for arm in arms), np.zeros(n + 1)])
        self._state = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self._hand_reference = self.DeclareVectorInputPort("hand_reference", 12)
        self._outputs = [self._layout(names) for names in outputs]
        for k, layout in enumerate(self._outputs):
            self.DeclareVectorOutputPort(
                f"desired_state_{k}", 2 * len(layout),
                lambda context, output, layout=layout: self._desired(context, output, layout),
                {self.xd_ticket(), self.time_ticket()})

    def get_hand_reference_input_port(self):
        return self._hand_reference

    def _parameters(self, arm: ArmModel) -> DifferentialInverseKinematicsParameters:
        plant = arm.plant
        params = DifferentialInverseKinematicsParameters(plant.num_positions(),
                                                         plant.num_velocities())
        params.set_time_step(self._h)
        lo, hi = plant.GetPositionLowerLimits().copy(), plant.GetPositionUpperLimits().copy()
        vmax = plant.GetVelocityUpperLimits().copy()
        moving_q = np.zeros(plant.num_positions(), bool)
        moving = np.zeros(plant.num_velocities(), bool)
        for joint in arm.joints:
            moving_q[joint.position_start()] = moving[joint.velocity_start()] = True
        lo[~moving_q] = hi[~moving_q] = arm.nominal[~moving_q]
        vmax[~moving] = 0.0
        params.set_joint_position_limits((lo, hi))
        params.set_joint_velocity_limits((-vmax, vmax))
        params.set_nominal_joint_position(arm.nominal)
        params.set_joint_centering_gain(CENTERING * np.diag(moving.astype(float)))
        return params

    def _layout(self, names: Sequence[tuple[int, str]]) -> list[tuple[int, int | None, float]]:
        """Per actuated joint: (arm, its slot in the arm's chain or None, held position)."""
        layout = []
        for arm_index, name in names:
            arm = self._arms[arm_index]
            chain = [j.name() for j in arm.joints]
            held = arm.nominal[arm.plant.GetJointByName(name).position_start()]
            layout.append((arm_index, chain.index(name) if name in chain else None, held))
        return layout

    def _update(self, context, discrete_state) -> None:
        x = discrete_state.get_mutable_vector(self._state).get_mutable_value()
        ref = self._hand_reference.Eval(context)
        n, t = self._n, context.get_time()
        x[:n] += (t - x[2 * n]) * x[n:2 * n]  # where the last update's rate has taken q_c
        x[2 * n] = t
        for i, arm in enumerate(self._arms):
            q_chain = x[self._slots[i]].copy()
            plant, ctx = arm.plant, self._contexts[i]
            q = arm.nominal.copy()
            q[[j.position_start() for j in arm.joints]] = q_chain
            plant.SetPositions(ctx, q)
            pose = arm.hand.CalcPoseInWorld(ctx)
            r = ref[6 * i: 6 * i + 6]
            v = r[3:] + K_P * (r[:3] - pose.translation())
            error = self._orientations[i].multiply(pose.rotation().inverse()).ToAngleAxis()
            w = K_R * error.angle() * error.axis()
            result = DoDifferentialInverseKinematics(plant, ctx, np.concatenate([w, v]),
                                                     arm.hand, self._params[i])
            speed = np.zeros(self._sizes[i])
            if result.status == DifferentialInverseKinematicsStatus.kSolutionFound:
                speed = result.joint_velocities.ravel()[[j.velocity_start()
                                                         for j in arm.joints]]
            x[n + self._slots[i].start: n + self._slots[i].stop] = speed

    def _desired(self, context, output: BasicVector, layout) -> None:
        x = context.get_discrete_state(self._state).value()
        elapsed = context.get_time() - x[2 * self._n]
        q, v = [], []
        for arm_index, slot, held in layout:
            if slot is None:
                q.append(held)
                v.append(0.0)
            else:
                k = self._slots[arm_index].start + slot
                q.append(x[k] + elapsed * x[self._n + k])
                v.append(x[self._n + k])
        output.SetFromVector(np.array(q + v))
