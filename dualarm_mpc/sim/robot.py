"""Robot: the two arms that carry the hands, from any URDF or SDF model (docs/robots.md).

The planner moves two points on the table (the hands); which arms carry them is the scenario's
``robot_model`` (read by :mod:`dualarm_mpc.sim.robot_files`), with ``hand_frames`` naming the
frame that holds objects: one (a one-arm model, loaded once per ``arm_bases`` entry, arm 1 = the
right one) or two (one model with both arms, placed at ``robot_base``). :func:`AddArms` welds
the model(s) in place, hangs a massless hand body at each hand frame and actuates every moving
joint with PD gains; each arm also gets a *control model* of its own, the same file in a plant
without geometry, which the differential inverse kinematics
(:mod:`dualarm_mpc.systems.differential_ik`) works on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.inverse_kinematics import InverseKinematics
from pydrake.multibody.parsing import PackageMap, Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import (
    Frame,
    Joint,
    ModelInstanceIndex,
    PdControllerGains,
    RigidBody,
    SpatialInertia,
)
from pydrake.solvers import Solve

from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.sim.robot_files import (
    PreparedModel,
    RobotError,
    installed_packages,
    model_path,
    prepare_model,
)
from dualarm_mpc.systems.differential_ik import ArmModel
from dualarm_mpc.systems.interpolator import TRAVEL_HEIGHT

ARM_SIDES = ("right", "left")  # arm 1 (index 0) is the right arm
# The hands' tool axis: the hand frame's +z, the approach direction (REP 103's tool frames,
# Franka's TCP); "tool down" is +z along the world's −z, within this angle.
TOOL_AXIS = np.array([0.0, 0.0, 1.0])
TOOL_TILT = 0.02  # rad
# The hands' orientations: tool down, the hand frame's x axis along ±x, the line between the
# hands (eq. 16), so that a gripper opening along its y (Franka's; ROS's convention) is narrow
# where the hands come closest.
FACINGS = (RotationMatrix(np.diag([1.0, -1.0, -1.0])), RotationMatrix(np.diag([-1.0, 1.0, -1.0])))
# The joint-space controller: MultibodyPlant's PD on every joint, critically damped at this
# natural frequency (rad/s) for the joint's own inertia, with gravity on the arms switched off
# (an ideal gravity compensation, docs/robots.md).
PD_FREQUENCY = 60.0


@dataclass(frozen=True)
class Arm:
    """One arm in the station's plant."""

    instance: ModelInstanceIndex
    hand: RigidBody  # a massless body whose origin is the hand frame, welded to it
    joints: tuple[Joint, ...]  # ``control.joints``' namesakes
    bodies: tuple[RigidBody, ...]  # what collides with the other arm
    hand_bodies: tuple[RigidBody, ...]  # the tool: bodies welded to the hand and beyond
    base: np.ndarray  # (3,) where the arm's first joint stands
    control: ArmModel


def _parse(plant: MultibodyPlant, model: PreparedModel, packages: PackageMap,
           scope: str | None) -> ModelInstanceIndex:
    parser = Parser(plant, scope) if scope else Parser(plant)
    parser.package_map().AddMap(packages)
    try:
        instances = parser.AddModels(str(model.path))
    except RuntimeError as err:
        raise RobotError(f"robot_model: Drake cannot parse it: {str(err).splitlines()[0]}") \
            from err
    if len(instances) != 1:
        raise RobotError(f"robot_model: expected one model in the file, got {len(instances)}")
    return instances[0]


def _root(plant: MultibodyPlant, instance: ModelInstanceIndex, model: PreparedModel) -> RigidBody:
    """The body to weld: the link the file welded to world, else the one no joint moves."""
    if model.root is not None:
        return plant.GetBodyByName(model.root, instance)
    children = {plant.get_joint(j).child_body().index() for j in plant.GetJointIndices(instance)}
    roots = [plant.get_body(b) for b in plant.GetBodyIndices(instance) if b not in children]
    if len(roots) != 1:
        raise RobotError(f"robot_model: cannot tell its base among {[b.name() for b in roots]}")
    return roots[0]


def _pose(place: list[float]) -> RigidTransform:
    """[x, y], [x, y, z] or [x, y, z, yaw] as a pose."""
    x, y, z, yaw = [*place, 0.0, 0.0][:4]
    return RigidTransform(RotationMatrix.MakeZRotation(yaw), [x, y, z])


def _hand_frame(plant: MultibodyPlant, instance: ModelInstanceIndex, name: str,
                key: str) -> Frame:
    if plant.HasFrameNamed(name, instance):
        return plant.GetFrameByName(name, instance)
    frames = sorted(known for f in plant.GetFrameIndices(instance)
                    if (known := plant.get_frame(f).name()) and
                    not known.endswith(("_parent", "_F", "_M", "_child")))
    near = [f for f in frames if any(w in f.lower() for w in ("hand", "tcp", "tool", "ee"))]
    raise RobotError(f"{key}: no frame {name!r} in the robot model (frames such as: "
                     f"{', '.join((near or frames)[:8])})")


def _chain(plant: MultibodyPlant, frame: Frame) -> list[Joint]:
    """The joints from the world to ``frame``'s body that move (welds skipped), base first."""
    parent_joint = {plant.get_joint(j).child_body().index(): plant.get_joint(j)
                    for j in plant.GetJointIndices()}
    chain, body = [], frame.body()
    while body.index() in parent_joint:
        joint = parent_joint[body.index()]
        if joint.num_velocities() > 1:
            raise RobotError(f"robot_model: joint {joint.name()} ({joint.type_name()}) on the "
                             "way to the hand: only revolute and prismatic joints are driven")
        if joint.num_velocities() == 1:
            chain.append(joint)
        body = joint.parent_body()
    return chain[::-1]


def _placements(scenario: Scenario) -> list[tuple[str | None, RigidTransform]]:
    """(scope, pose of the model) per model loaded: one per arm, or one for both."""
    robot = scenario.robot
    if len(robot.hand_frames) == 1:
        return [(side, _pose(base)) for side, base in zip(ARM_SIDES, robot.arm_bases,
                                                           strict=True)]
    return [(None, _pose(robot.robot_base or [0.0, 0.0, 0.0, 0.0]))]


def _load(plant: MultibodyPlant, scenario: Scenario, model: PreparedModel,
          packages: PackageMap) -> list[tuple[ModelInstanceIndex, Frame, int]]:
    """The model(s) parsed and welded into ``plant``; per arm (instance, hand frame, index of
    its model)."""
    frames = scenario.robot.hand_frames
    arms = []
    for k, (scope, pose) in enumerate(_placements(scenario)):
        instance = _parse(plant, model, packages, scope)
        plant.WeldFrames(plant.world_frame(), _root(plant, instance, model).body_frame(),
                         pose @ model.weld)
        names = frames if len(frames) == 2 else [frames[0]]
        for i, name in enumerate(names):
            arm = k if len(frames) == 1 else i
            arms.append((instance, _hand_frame(plant, instance, name, f"hand_frames[{arm}]"), k))
    return arms


def _control_models(scenario: Scenario, model: PreparedModel, packages: PackageMap
                    ) -> list[ArmModel]:
    """Each arm's control plant, its chain (joints shared by both arms' chains, a torso, are
    held) and its nominal posture."""
    plants = []
    for _, pose in _placements(scenario):
        plant = MultibodyPlant(0.0)
        instance = _parse(plant, model, packages, None)
        plant.WeldFrames(plant.world_frame(), _root(plant, instance, model).body_frame(),
                         pose @ model.weld)
        plant.Finalize()
        plants.append((plant, instance))
    frames = scenario.robot.hand_frames
    arms = [(plants[i], frames[0]) for i in range(2)] if len(frames) == 1 else \
        [(plants[0], name) for name in frames]
    hands = [(plant, _hand_frame(plant, instance, name,
                                 f"hand_frames[{frames.index(name)}]"))
             for (plant, instance), name in arms]
    chains = [_chain(plant, frame) for plant, frame in hands]
    if len(frames) == 2:
        shared = {j.name() for j in chains[0]} & {j.name() for j in chains[1]}
        chains = [[j for j in chain if j.name() not in shared] for chain in chains]
    postures = []
    for i, ((plant, frame), chain) in enumerate(zip(hands, chains, strict=True)):
        if not chain:
            raise RobotError(f"hand_frames[{i}]: {frame.name()} is welded to the world: no "
                             "joint moves it")
        start = [*scenario.robot.hand_start[i], TRAVEL_HEIGHT]
        # a two-arm model: the second arm from the first's posture, so that one q holds both
        guess = postures[0] if len(frames) == 2 and postures else _mid_range(plant)
        # first the tool down alone, nearest the middle of the joints' ranges; then turned
        guess = solve_hand_ik(plant, frame, chain, start, guess)
        if guess is None:
            raise RobotError(f"hand_start[{i}]: arm {i + 1} cannot hold its tool down at "
                             f"{[round(v, 4) for v in start]}")
        # the hand's x axis along the line between the hands, whichever way keeps the joints
        # farther from their limits (the wrist turns as the arm sweeps the hand range)
        found = [q for q in (solve_hand_ik(plant, frame, chain, start, guess, facing)
                             for facing in FACINGS) if q is not None]
        q = max(found, key=lambda q: _limit_margin(plant, chain, q), default=None)
        if q is None:
            raise RobotError(f"hand_start[{i}]: arm {i + 1} cannot hold its tool down at "
                             f"{[round(v, 4) for v in start]}")
        postures.append(q)
    if len(frames) == 2:
        postures = [postures[1], postures[1]]
    return [ArmModel(plant, frame, tuple(chain), q) for (plant, frame), chain, q
            in zip(hands, chains, postures, strict=True)]


def _limit_margin(plant: MultibodyPlant, chain, q: np.ndarray) -> float:
    """The least distance of a chain joint from its nearer limit, in fractions of its range."""
    lo, hi = plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits()
    k = [joint.position_start() for joint in chain]
    return float(np.min(np.minimum(q[k] - lo[k], hi[k] - q[k]) / (hi[k] - lo[k])))


def _mid_range(plant: MultibodyPlant) -> np.ndarray:
    """Each joint at the middle of its limits (0 where unlimited): a posture away from them."""
    lo, hi = plant.GetPositionLowerLimits(), plant.GetPositionUpperLimits()
    return np.where(np.isfinite(lo) & np.isfinite(hi), (lo + hi) / 2, 0.0)


def solve_hand_ik(plant: MultibodyPlant, frame: Frame, chain, point, guess: np.ndarray,
                  facing: RotationMatrix | None = None) -> np.ndarray | None:
    """q placing ``frame``'s origin at ``point`` with the tool down, within the joint limits,
    nearest ``guess``, moving only ``chain`` (Drake's InverseKinematics); ``facing``: the hand's
    whole orientation instead (within ``TOOL_TILT``). None if none found."""
    ik = InverseKinematics(plant)
    ik.AddPositionConstraint(frame, [0, 0, 0], plant.world_frame(), point, point)
    if facing is None:
        ik.AddAngleBetweenVectorsConstraint(frame, TOOL_AXIS, plant.world_frame(), -TOOL_AXIS,
                                            0.0, TOOL_TILT)
    else:
        ik.AddOrientationConstraint(frame, RotationMatrix(), plant.world_frame(), facing,
                                    TOOL_TILT)
    prog, q = ik.prog(), ik.q()
    moving = np.zeros(plant.num_positions(), bool)
    for joint in chain:
        moving[joint.position_start()] = True
    fixed = np.flatnonzero(~moving)
    prog.AddBoundingBoxConstraint(guess[fixed], guess[fixed], q[fixed])
    prog.AddQuadraticErrorCost(np.eye(len(guess)), guess, q)
    prog.SetInitialGuess(q, guess)
    result = Solve(prog)
    return result.GetSolution(q) if result.is_success() else None


def AddArms(plant: MultibodyPlant, scenario: Scenario) -> tuple[Arm, Arm]:
    """Parses ``scenario.robot.robot_model`` into ``plant`` (before ``Finalize``): welded at
    its bases, a massless hand body at each hand frame, every moving joint actuated with PD
    gains, the arms' gravity off. Raises :class:`~dualarm_mpc.sim.robot_files.RobotError`,
    which names what is wrong."""
    packages = installed_packages()
    model = prepare_model(model_path(scenario.robot.robot_model, packages), packages)
    controls = _control_models(scenario, model, packages)
    loaded = _load(plant, scenario, model, packages)
    instances = sorted({instance for instance, _, _ in loaded})
    for instance in instances:
        plant.set_gravity_enabled(instance, False)
    arms = []
    for i, ((instance, frame, _), control) in enumerate(zip(loaded, controls, strict=True)):
        hand = plant.AddRigidBody(f"{ARM_SIDES[i]}_hand_point", instance, SpatialInertia.Zero())
        plant.WeldFrames(frame, hand.body_frame(), RigidTransform())
        joints = tuple(plant.GetJointByName(j.name(), instance) for j in control.joints)
        arms.append((instance, hand, joints, control))
    _actuate(plant, instances, controls)
    return tuple(_arm(plant, *arm) for arm in arms)


def place_arms(plant: MultibodyPlant, arms: tuple[Arm, Arm]) -> None:
    """A robot model's default posture: each joint at its arm's nominal posture (the hands
    above ``hand_start`` at the travel height, tools down)."""
    for arm in arms:
        nominal, control = arm.control.nominal, arm.control.plant
        for j in plant.GetJointIndices(arm.instance):
            joint = plant.get_joint(j)
            if joint.num_positions() == 1 and control.HasJointNamed(joint.name()):
                k = control.GetJointByName(joint.name()).position_start()
                joint.set_default_positions(nominal[k:k + 1])


def _actuate(plant: MultibodyPlant, instances, controls: list[ArmModel]) -> None:
    """An actuator with PD gains on every moving joint of the robot: kp = m ω², kd = 2 m ω,
    m the joint's diagonal entry of the mass matrix at the nominal posture (its control plant's)."""
    inertia = {}
    for control in controls:
        context = control.plant.CreateDefaultContext()
        control.plant.SetPositions(context, control.nominal)
        mass = control.plant.CalcMassMatrix(context)
        for j in control.plant.GetJointIndices():
            joint = control.plant.get_joint(j)
            if joint.num_velocities() == 1:
                v = joint.velocity_start()
                inertia[joint.name()] = max(inertia.get(joint.name(), 0.0), mass[v, v])
    for instance in instances:
        actuated = {plant.get_joint_actuator(a).joint().index(): plant.get_joint_actuator(a)
                    for a in plant.GetJointActuatorIndices(instance)}
        for j in plant.GetJointIndices(instance):
            joint = plant.get_joint(j)
            if joint.num_velocities() != 1:
                continue
            actuator = actuated.get(j) or plant.AddJointActuator(
                f"{joint.name()}_actuator", joint, math.inf)
            m = max(inertia.get(joint.name(), 0.0), 1e-3)
            actuator.set_controller_gains(PdControllerGains(
                p=m * PD_FREQUENCY**2, d=2 * m * PD_FREQUENCY))


def _arm(plant: MultibodyPlant, instance: ModelInstanceIndex, hand: RigidBody,
         joints: tuple[Joint, ...], control: ArmModel) -> Arm:
    first = joints[0].child_body()
    bodies = _outboard(plant, [first]) if _shared_instance(plant, instance) else \
        [plant.get_body(b) for b in plant.GetBodyIndices(instance)]
    base = RigidTransform(control.plant.GetFrameByName(
        control.joints[0].frame_on_child().name()).CalcPoseInWorld(
        control.plant.CreateDefaultContext())).translation()
    return Arm(instance, hand, joints, tuple(bodies),
               tuple(_outboard(plant, plant.GetBodiesWeldedTo(hand))), base, control)


def _shared_instance(plant: MultibodyPlant, instance: ModelInstanceIndex) -> bool:
    """Whether ``instance`` carries both arms (a two-arm model)."""
    hands = [b for b in plant.GetBodyIndices(instance)
             if plant.get_body(b).name().endswith("_hand_point")]
    return len(hands) == 2


def _outboard(plant: MultibodyPlant, bodies) -> list[RigidBody]:
    """``bodies`` and every body a chain of joints hangs from them."""
    found = {b.index() for b in bodies}
    grew = True
    while grew:
        grew = False
        for j in plant.GetJointIndices():
            joint = plant.get_joint(j)
            if joint.parent_body().index() in found and joint.child_body().index() not in found:
                found.add(joint.child_body().index())
                grew = True
    return [plant.get_body(b) for b in sorted(found)]


def tool_depth(plant: MultibodyPlant, scene_graph, arm: Arm) -> float:
    """How far the arm's tool (its hand bodies' collision geometry, at the default posture)
    reaches beyond the hand frame along the tool axis: the hand frame rides that high above a
    box it holds, so that the tool rests on the box's top face instead of entering it."""
    inspector = scene_graph.model_inspector()
    context = plant.CreateDefaultContext()
    X_HW = plant.EvalBodyPoseInWorld(context, arm.hand).inverse()
    depth = 0.0
    for body in arm.hand_bodies:
        X_HB = X_HW @ plant.EvalBodyPoseInWorld(context, body)
        for g in plant.GetCollisionGeometriesForBody(body):
            points = _shape_points(inspector, g)
            if len(points):
                in_hand = (X_HB @ inspector.GetPoseInFrame(g)).multiply(points.T).T
                depth = max(depth, float(np.max(in_hand @ TOOL_AXIS)))
    return depth


def _shape_points(inspector, geometry) -> np.ndarray:
    """Points whose convex hull holds the geometry, in its frame (k, 3); empty if unknown."""
    shape = inspector.GetShape(geometry)
    name = type(shape).__name__
    if name == "Box":
        half = np.array([shape.width(), shape.depth(), shape.height()]) / 2
        return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                         for sz in (-1, 1)]) * half
    if name in ("Sphere", "Ellipsoid"):
        r = [shape.radius()] * 3 if name == "Sphere" else [shape.a(), shape.b(), shape.c()]
        return np.vstack([np.diag(r), -np.diag(r)])
    if name in ("Cylinder", "Capsule"):
        r, half = shape.radius(), shape.length() / 2 + (shape.radius() if name == "Capsule"
                                                        else 0.0)
        return np.array([[sx * r, sy * r, sz * half] for sx in (-1, 0, 1) for sy in (-1, 0, 1)
                         for sz in (-1, 1)])
    hull = inspector.GetConvexHull(geometry)
    if hull is None:
        return np.zeros((0, 3))
    return np.array([hull.vertex(k) for k in range(hull.num_vertices())])
