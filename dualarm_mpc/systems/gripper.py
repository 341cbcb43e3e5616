"""Gripper: attaches objects to hands with a stiff in-plane spring-damper, and releases them.

Weld constraints must exist before ``Finalize`` and can only be toggled from outside the Diagram;
an off-centre weld also snaps the object across at several m/s (docs/drake.md, gripper). This
gripper instead applies equal and opposite ``ExternallyAppliedSpatialForce`` forces to hand i and
object j while the pair is attached::

    F_j = −k·(Δp − d_ij) − c·Δv,      Δp = p_j − p_hand_i,  Δv = v_j − v_hand_i   (x, y only),

with ``d_ij`` the in-plane offset captured at the grip instant, ``c = 2ζ·sqrt(k·m_j)``, plus a
yaw damping torque on the object. The z direction is left to contact: a held object stays on the
table and slides with the hand. On release the force stops and the object keeps the hand's
velocity until the table stops it (a throw).

The table (``slide_time_constant`` τ): an object that no hand holds feels the table's viscous
drag ``F = −m·v/τ`` in the plane, so from speed v it slides ``v·τ`` — with τ = Δt, exactly the
one-step slide of the planner's object model at *every* speed (docs/model.md, the one-step slide).
Coulomb friction alone gives v²/(2μg), which matches v·Δt at one speed only: a throw at 0.35 m/s
with μ tuned for 0.5 m/s fell 10–15 cm short of the plan, beyond the hands' reach (measured).
Below ``STOP_SPEED`` (0.1 mm/s) the object is stopped within one plant step, so that it comes to
rest (at most 0.1 mm·τ/s short of the slide's limit).

Pair (i, j) attaches at an update when ``grasp_command[i·N + j] > 0.5`` and hand i is inside the
grasp box of object j: ``|Δp|∞ ≤ grasp_half_size_j + tolerance`` in the plane and within
``height_tolerance`` of ``hold_height`` above the object's centre in z (the hand has come down:
its tip on the top face, a suction cup; it never enters the object). It detaches as soon
as the command drops. The attachments and offsets are discrete state, updated every
``update_period`` (the plant's time step).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue, Value
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialForce, SpatialVelocity
from pydrake.multibody.plant import ExternallyAppliedSpatialForce, MultibodyPlant
from pydrake.multibody.tree import RigidBody
from pydrake.systems.framework import BasicVector, LeafSystem

# m/s: an unheld object slower than this is stopped within one plant step (F = −m·v/h) instead
# of dragged: the drag alone decays its speed but never ends it, and the scenarios' tables have
# no Coulomb friction (μ = 0) to hold it, so without the stop a delivered object crept on.
STOP_SPEED = 1e-4
# m/s: an object at rest on the table moves at ~1e-15 m/s (SAP's round-off); it gets no force.
# Objects mostly rest, and building a force for each of them every 2 ms step was the closed
# loop's costliest Python.
REST_NOISE = 1e-9


class Gripper(LeafSystem):
    """Diagram-native grasping by spring-damper forces between hands and objects.

    .. pydrake_system::

        name: Gripper
        input_ports:
        - grasp_command
        - body_poses
        - body_spatial_velocities
        output_ports:
        - spatial_forces
        - grasp

    ``grasp_command`` (2N): η_ij, row-major, index ``i·N + j`` (hand i = 0 right, 1 left).
    ``body_poses`` / ``body_spatial_velocities``: the plant's outputs of the same names.
    ``spatial_forces``: list of ExternallyAppliedSpatialForce, for
    ``plant.get_applied_spatial_force_input_port()``. ``grasp`` (2N, 0/1): the pairs attached now.

    State: one discrete vector [attached (2N); offset (2N × 2, pair-major)].
    """

    def __init__(
        self,
        plant: MultibodyPlant,
        hand_bodies: Sequence[RigidBody],
        object_bodies: Sequence[RigidBody],
        grasp_half_sizes: Sequence[float],
        update_period: float,
        stiffness: float = 2000.0,
        damping_ratio: float = 1.0,
        tolerance: float = 0.01,
        hold_height: float = 0.0,
        height_tolerance: float = 0.015,
        yaw_time_constant: float = 0.05,
        slide_time_constant: float | None = None,
    ):
        super().__init__()
        n = len(object_bodies)
        if not plant.is_finalized():
            raise ValueError("Gripper: the plant must be finalized (body indices and masses)")
        if len(hand_bodies) != 2:
            raise ValueError(f"hand_bodies: expected 2 (right, left), got {len(hand_bodies)}")
        if len(grasp_half_sizes) != n:
            raise ValueError(f"grasp_half_sizes: expected {n} values, got {len(grasp_half_sizes)}")
        if stiffness <= 0 or update_period <= 0:
            raise ValueError(
                f"stiffness and update_period must be > 0: {stiffness}, {update_period}"
            )
        self._n = n
        self._hands = tuple(int(b.index()) for b in hand_bodies)
        self._objects = tuple(int(b.index()) for b in object_bodies)
        self._reach = np.asarray(grasp_half_sizes, dtype=float) + tolerance
        self._hold_height = hold_height
        self._height_tolerance = height_tolerance
        self._k = stiffness
        masses = np.array([b.default_mass() for b in object_bodies])
        # Per-object coefficients as floats (the forces are computed in Python floats); no drag
        # list without a slide time constant.
        self._c = (2.0 * damping_ratio * np.sqrt(stiffness * masses)).tolist()
        self._drag = None if slide_time_constant is None else (
            masses / slide_time_constant).tolist()
        self._stop = (masses / update_period).tolist()
        yaw_inertia = np.array(
            [
                b.default_spatial_inertia().CalcRotationalInertia().get_moments()[2]
                for b in object_bodies
            ]
        )
        self._c_yaw = (yaw_inertia / yaw_time_constant).tolist()

        # The applied forces, their F_Bq_W set at each evaluation: the drag on each object, and
        # the spring-damper of each pair (i, j) on its object and on its hand.
        self._drag_on = [_applied_force(b.index()) for b in object_bodies]
        self._pair_on_object = [_applied_force(b.index()) for _ in hand_bodies
                                for b in object_bodies]
        self._pair_on_hand = [_applied_force(h.index()) for h in hand_bodies
                              for _ in object_bodies]

        self._grasp_command = self.DeclareVectorInputPort("grasp_command", 2 * n)
        self._body_poses = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self._body_velocities = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self._state = self.DeclareDiscreteState(6 * n)
        self.DeclarePeriodicDiscreteUpdateEvent(update_period, 0.0, self._update)
        self._spatial_forces = self.DeclareAbstractOutputPort(
            "spatial_forces",
            lambda: Value[list[ExternallyAppliedSpatialForce]]([]),
            self._calc_spatial_forces,
        )
        self._grasp = self.DeclareVectorOutputPort(
            "grasp", BasicVector(2 * n), self._calc_grasp, {self.xd_ticket()}
        )

    def get_grasp_command_input_port(self):
        return self._grasp_command

    def get_body_poses_input_port(self):
        return self._body_poses

    def get_body_spatial_velocities_input_port(self):
        return self._body_velocities

    def get_spatial_forces_output_port(self):
        return self._spatial_forces

    def get_grasp_output_port(self):
        return self._grasp

    def detach(self, context, j: int) -> None:
        """Let go of object j at once (an environment event knocked it out of the hand): without
        this the spring pulls a moved object straight back into the hand. It attaches again only
        under the usual conditions (commanded, hand inside its grasp box, at its height)."""
        state = context.get_mutable_discrete_state(self._state)
        x = state.get_value().copy()
        x[j : 2 * self._n : self._n] = 0.0  # pairs (0, j) and (1, j)
        state.SetFromVector(x)

    def _split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n2 = 2 * self._n
        return x[:n2], x[n2:].reshape(n2, 2)

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._state).get_value()
        attached, offset = self._split(x.copy())
        command = self._grasp_command.Eval(context) > 0.5
        if not command.any() and not attached.any():
            return
        poses = self._body_poses.Eval(context)
        for i, hand in enumerate(self._hands):
            p_hand = poses[hand].translation()
            for j, obj in enumerate(self._objects):
                pair = i * self._n + j
                if not command[pair]:
                    attached[pair] = 0.0
                elif attached[pair] == 0.0:
                    d = poses[obj].translation() - p_hand
                    if (
                        np.max(np.abs(d[:2])) <= self._reach[j]
                        and abs(d[2] + self._hold_height) <= self._height_tolerance
                    ):
                        attached[pair] = 1.0
                        offset[pair] = d[:2]
        discrete_state.get_mutable_vector(self._state).SetFromVector(
            np.concatenate([attached, offset.reshape(-1)])
        )

    def _calc_spatial_forces(self, context, output):
        # Python floats, and the applied forces kept from call to call (the output copies them
        # into Drake's vector): this runs at every 2 ms plant step.
        x = context.get_discrete_state(self._state).get_value()
        pairs = np.flatnonzero(x[: 2 * self._n]).tolist()
        held = {pair % self._n for pair in pairs}
        forces = []
        if self._drag is not None and len(held) < self._n:
            velocities = self._body_velocities.Eval(context)
            for j, obj in enumerate(self._objects):
                if j in held:
                    continue
                vx, vy, _ = velocities[obj].translational().tolist()
                speed = max(abs(vx), abs(vy))
                if speed < REST_NOISE:
                    continue
                c = self._stop[j] if speed < STOP_SPEED else self._drag[j]
                forces.append(_applied(self._drag_on[j], 0.0, -c * vx, -c * vy))
        if pairs:
            poses = self._body_poses.Eval(context)
            velocities = self._body_velocities.Eval(context)
            offsets = x[2 * self._n :].tolist()
            for pair in pairs:
                i, j = divmod(pair, self._n)
                hand, obj = self._hands[i], self._objects[j]
                ox, oy, _ = poses[obj].translation().tolist()
                hx, hy, _ = poses[hand].translation().tolist()
                vox, voy, _ = velocities[obj].translational().tolist()
                vhx, vhy, _ = velocities[hand].translational().tolist()
                k, c = self._k, self._c[j]
                fx = -k * (ox - hx - offsets[2 * pair]) - c * (vox - vhx)
                fy = -k * (oy - hy - offsets[2 * pair + 1]) - c * (voy - vhy)
                yaw = -self._c_yaw[j] * velocities[obj].rotational()[2]
                forces.append(_applied(self._pair_on_object[pair], yaw, fx, fy))
                forces.append(_applied(self._pair_on_hand[pair], 0.0, -fx, -fy))
        output.set_value(forces)

    def _calc_grasp(self, context, output):
        attached, _ = self._split(context.get_discrete_state(self._state).get_value())
        output.SetFromVector(attached)


def _applied_force(body_index) -> ExternallyAppliedSpatialForce:
    applied = ExternallyAppliedSpatialForce()
    applied.body_index = body_index
    applied.p_BoBq_B = np.zeros(3)
    return applied


def _applied(applied: ExternallyAppliedSpatialForce, yaw: float, fx: float,
             fy: float) -> ExternallyAppliedSpatialForce:
    """``applied`` with the torque (0, 0, yaw) and the force (fx, fy, 0) in the world frame."""
    applied.F_Bq_W = SpatialForce(np.array([0.0, 0.0, yaw]), np.array([fx, fy, 0.0]))
    return applied
