"""Controller: hand references → desired joint states of both SCARA arms, by closed-form IK.

Kinematics of one arm (base at ``b``, link lengths ``l1``, ``l2``, shoulder angle ``q1`` from +x,
elbow angle ``q2`` relative to link 1, hand height ``q3``)::

    p = b + l1·(cos q1, sin q1) + l2·(cos(q1 + q2), sin(q1 + q2)),    z = q3.

Inverse: ``cos q2 = (|p − b|² − l1² − l2²) / (2 l1 l2)`` (clamped to [−1, 1] outside the reach),
``q2 = s·acos(·)`` with a fixed elbow sign ``s`` per arm, then
``q1 = atan2(p − b) − atan2(l2 sin q2, l1 + l2 cos q2)``. The default signs (+1 right, −1 left)
put each elbow on the outer side of the line from its base to its hand: the bases stand in front
of the hands' range, so every hand lies beyond its base line and the elbows stay outside, away
from each other (docs/drake.md, "Arms that keep clear"). A fixed sign keeps the joint path
continuous; it never flips elbows.

Gap guard: the references keep eq. (16) between the hands (the Interpolator's limits), but a
hand can lag its reference, pushing a carried object against another one (objects touch each
other on the plant, not in the model): measured on §V-D, the left hand held 2.5 cm behind while
the right one came on, and the arms came 2.9 cm apart. Given eq. (16)'s gap, each hand's x
reference is kept at least ``gap − GAP_SLACK`` from where the other hand is measured, at rest
along x while the guard holds it; ``GAP_SLACK`` is above the millimetres the arms lag in normal
tracking, so the guard acts only on such blocks.

Joint velocities come from the Jacobian, inverted with a small damping near the singularities
(arm stretched or folded), and clipped. The revolute angles are unwrapped to the
measured ones (the nearest multiple of 2π), so a reference crossing atan2's branch cut does not
send the shoulder around a full turn.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import LeafSystem

ELBOW_SIGNS = (1, -1)  # arm 1 (right), arm 2 (left): elbows point away from each other
_DAMPING = 1e-3  # damped least squares near singularities (m)
_MAX_JOINT_SPEED = 20.0  # rad/s clip of the reference joint speed
GAP_SLACK = 0.01  # m: what the gap guard lets a hand's lag take off eq. (16)'s gap


def scara_fk(q: Sequence[float], base: Sequence[float], lengths: Sequence[float]) -> np.ndarray:
    """The hand's in-plane position for joint angles ``q = (q1, q2)``."""
    return np.array(_hand_xy(q[0], q[1], base, lengths))


def _hand_xy(q1: float, q2: float, base: Sequence[float], lengths: Sequence[float]
             ) -> tuple[float, float]:
    l1, l2 = lengths
    return (base[0] + l1 * math.cos(q1) + l2 * math.cos(q1 + q2),
            base[1] + l1 * math.sin(q1) + l2 * math.sin(q1 + q2))


def scara_ik(
    p: Sequence[float], base: Sequence[float], lengths: Sequence[float], elbow_sign: int
) -> np.ndarray:
    """Joint angles (q1, q2) placing the hand at ``p``; q1 in (−π, π], sign(q2) = elbow_sign."""
    # Scalar math, not numpy: the controller runs this at every 2 ms plant step.
    l1, l2 = lengths
    dx, dy = p[0] - base[0], p[1] - base[1]
    c2 = (dx * dx + dy * dy - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    q2 = elbow_sign * math.acos(_clamp(c2, 1.0))
    q1 = math.atan2(dy, dx) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
    q1 = (q1 + math.pi) % (2.0 * math.pi) - math.pi
    return np.array([q1, q2])


def scara_jacobian(q: Sequence[float], lengths: Sequence[float]) -> np.ndarray:
    """∂p/∂(q1, q2), 2×2."""
    return np.array(_jacobian(q, lengths)).reshape(2, 2)


def _jacobian(q: Sequence[float], lengths: Sequence[float]) -> tuple[float, ...]:
    """The Jacobian's entries, row-major, as floats."""
    l1, l2 = lengths
    s1, c1 = math.sin(q[0]), math.cos(q[0])
    s12, c12 = math.sin(q[0] + q[1]), math.cos(q[0] + q[1])
    return -l1 * s1 - l2 * s12, -l2 * s12, l1 * c1 + l2 * c12, l2 * c12


def scara_joint_velocity(
    q: Sequence[float], v: Sequence[float], lengths: Sequence[float]
) -> np.ndarray:
    """(q1', q2') giving hand velocity ``v`` at ``q``: damped least squares
    Jᵀ (J Jᵀ + λ² I)⁻¹ v, clipped; the 2×2 inverse in closed form (every plant step)."""
    a, b, c, d = _jacobian(q, lengths)
    m00, m01, m11 = a * a + b * b + _DAMPING**2, a * c + b * d, c * c + d * d + _DAMPING**2
    det = m00 * m11 - m01 * m01
    y0, y1 = (m11 * v[0] - m01 * v[1]) / det, (m00 * v[1] - m01 * v[0]) / det
    return np.array([_clamp(a * y0 + c * y1, _MAX_JOINT_SPEED),
                     _clamp(b * y0 + d * y1, _MAX_JOINT_SPEED)])


def _clamp(x: float, limit: float) -> float:
    """``x`` within [−limit, limit] (``np.clip`` for one float, without numpy's overhead)."""
    return min(limit, max(-limit, x))


def unwrap_to(angle: float, reference: float) -> float:
    """``angle`` + 2πn closest to ``reference``."""
    return angle + 2.0 * math.pi * round((reference - angle) / (2.0 * math.pi))


class Controller(LeafSystem):
    """Closed-form SCARA inverse kinematics for both arms, feeding the plant's PD actuators.

    .. pydrake_system::

        name: Controller
        input_ports:
        - hand_reference
        - plant_state
        output_ports:
        - desired_state

    ``hand_reference`` (12): per arm i = 0 (right), 1 (left) [x, y, z, vx, vy, vz] at ``6i``
    (the Interpolator's output). ``plant_state``: the plant's full state [q; v]
    (``plant.get_state_output_port()``), read only to unwrap the revolute angles.
    ``desired_state`` (12): [q_d; v_d] of the six actuated joints in the order of the robot's
    desired-state input port (``plant.get_desired_state_input_port(robot)``).

    Joint bookkeeping is passed in, not looked up, so the system is plant-free: canonical joint
    c = 3i + m is arm i's shoulder (m = 0), elbow (1) or z joint (2); ``position_indices[c]`` is
    its index in the plant's q, and ``actuator_order[a]`` the canonical joint driven by slot a of
    the desired-state port. The z joint's position is the hand's height (the model's convention).
    """

    def __init__(
        self,
        arm_bases: Sequence[Sequence[float]],
        link_lengths: Sequence[float],
        position_indices: Sequence[int],
        actuator_order: Sequence[int],
        plant_state_size: int,
        elbow_signs: Sequence[int] = ELBOW_SIGNS,
        hand_gap: float | None = None,
    ):
        super().__init__()
        self._hand_gap = hand_gap
        self._bases = np.asarray(arm_bases, dtype=float).reshape(2, 2).tolist()
        self._lengths = tuple(float(x) for x in link_lengths)
        if len(self._lengths) != 2 or min(self._lengths) <= 0:
            raise ValueError(f"link_lengths: expected two positive lengths, got {link_lengths}")
        if sorted(actuator_order) != list(range(6)):
            raise ValueError(
                f"actuator_order: expected a permutation of 0..5, got {actuator_order}"
            )
        if len(position_indices) != 6 or not all(
            0 <= k < plant_state_size for k in position_indices
        ):
            raise ValueError(f"position_indices: expected 6 indices into q, got {position_indices}")
        if any(s not in (-1, 1) for s in elbow_signs) or len(elbow_signs) != 2:
            raise ValueError(f"elbow_signs: expected two of ±1, got {elbow_signs}")
        self._positions = np.asarray(position_indices, dtype=int)
        order = np.asarray(actuator_order, dtype=int)
        self._desired_order = np.concatenate([order, 6 + order])  # canonical [q; v] → port's
        self._signs = tuple(int(s) for s in elbow_signs)
        self._hand_reference = self.DeclareVectorInputPort("hand_reference", 12)
        self._plant_state = self.DeclareVectorInputPort("plant_state", plant_state_size)
        self._desired_state = self.DeclareVectorOutputPort(
            "desired_state", 12, self._calc_desired_state
        )

    def get_hand_reference_input_port(self):
        return self._hand_reference

    def get_plant_state_input_port(self):
        return self._plant_state

    def get_desired_state_output_port(self):
        return self._desired_state

    def joint_targets(self, hand_reference: np.ndarray, q_measured: np.ndarray) -> np.ndarray:
        """[q(6); v(6)] in canonical order from a reference (12) and measured canonical q (6)."""
        # Python floats, not numpy slices: this runs at every 2 ms plant step.
        ref = np.asarray(hand_reference, dtype=float).tolist()
        measured = np.asarray(q_measured, dtype=float).tolist()
        if self._hand_gap is not None:
            self._guard_gap(ref, measured)
        q, v = [], []
        for i in range(2):
            x, y, z, vx, vy, vz = ref[6 * i : 6 * i + 6]
            q1, q2 = scara_ik((x, y), self._bases[i], self._lengths, self._signs[i])
            q1, q2 = unwrap_to(q1, measured[3 * i]), unwrap_to(q2, measured[3 * i + 1])
            w1, w2 = scara_joint_velocity((q1, q2), (vx, vy), self._lengths)
            q += [q1, q2, z]
            v += [w1, w2, vz]
        return np.array(q + v)

    def _guard_gap(self, ref: list[float], measured: list[float]) -> None:
        """Keeps each hand's x reference ``gap − GAP_SLACK`` from the other hand's measured x
        (arm 1 right of arm 2, eq. 16), in place."""
        x1, x2 = (_hand_xy(measured[3 * i], measured[3 * i + 1], self._bases[i],
                           self._lengths)[0] for i in range(2))
        gap = self._hand_gap - GAP_SLACK
        if ref[0] < x2 + gap:
            ref[0], ref[3] = x2 + gap, 0.0
        if ref[6] > x1 - gap:
            ref[6], ref[9] = x1 - gap, 0.0

    def _calc_desired_state(self, context, output):
        x = self._plant_state.Eval(context)
        canonical = self.joint_targets(self._hand_reference.Eval(context), x[self._positions])
        output.SetFromVector(canonical[self._desired_order])
