"""Station: the simulated table-top — plant, robot, table, objects, goal patches — and its drivers.

:func:`AddStation` builds the physical scene from a :class:`~dualarm_mpc.model.scenario.Scenario`;
:func:`AddControlStack` wires the low-level systems around it (interpolator → controller → plant,
gripper ↔ plant, state estimator), leaving the plan input and the measured state for the caller
(the planner, or a fixed plan in tests).

Physics (docs/drake.md, measured): MultibodyPlant with the SAP discrete solver at ``time_step``,
hydroelastic contact with point-contact fallback. The table is a ``HalfSpace`` at z = 0; the
objects are ``object_size`` boxes, resting on it at their scenario positions on four small
spheres at their bottom corners (point contact, four points of support). The boxes themselves,
compliant hydroelastic, touch each other but not the table. Table and objects share the Coulomb
friction μ = ``scenario.table.friction`` (so the combined μ is exactly that), low by design: a
released object slides v²/(2μg). The robot comes from ``models/dual_scara.sdf`` (the single
source of its geometry and gains); the table, objects and goal patches are made here because
their count, colours and friction come from the scenario. The arms' collision geometries collide
with the other arm's only: contact between an arm and the table or the objects is filtered out
here (the gripper holds objects by force, the hand's tip on the object's top face), within an arm by
the model's filter groups.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from pydrake.geometry import (
    AddCompliantHydroelasticProperties,
    AddContactMaterial,
    Box,
    CollisionFilterDeclaration,
    GeometryId,
    GeometrySet,
    HalfSpace,
    ProximityProperties,
    Role,
    SceneGraph,
    Sphere,
)
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import (
    AddMultibodyPlant,
    CoulombFriction,
    MultibodyPlant,
    MultibodyPlantConfig,
)
from pydrake.multibody.tree import Joint, ModelInstanceIndex, RigidBody, SpatialInertia
from pydrake.systems.framework import DiagramBuilder

from dualarm_mpc.base.palette import TABLE_COLOUR, goal_colour
from dualarm_mpc.model.scenario import ROBOT_ARM_BASES, ROBOT_LINKS, Scenario
from dualarm_mpc.sim.reach import check_robot
from dualarm_mpc.sim.resources import ROBOT_URL, package_map
from dualarm_mpc.sim.robot import ARM_SIDES, AddArms, Arm, place_arms, tool_depth
from dualarm_mpc.systems.controller import ELBOW_SIGNS, Controller, scara_ik
from dualarm_mpc.systems.differential_ik import DifferentialIkController
from dualarm_mpc.systems.gripper import Gripper
from dualarm_mpc.systems.interpolator import TRAVEL_HEIGHT, Interpolator, Limits
from dualarm_mpc.systems.state_estimator import StateEstimator

# Drake's log lines that say nothing about this station, each by the start of its message: the
# table is a rigid half space, and no deformable body is ever added to touch it; the URL of a
# Meshcat server, which the command line prints itself where a person is to open it (--meshcat).
DRAKE_NOISE = ("Rigid (non-deformable) half spaces are not currently supported for deformable "
               "contact", "Meshcat listening for connections at")


class _DrakeNoise(logging.Filter):
    """Drops ``DRAKE_NOISE`` from the ``drake`` logger, where Drake's C++ logs arrive."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(DRAKE_NOISE)


def quiet_drake() -> None:
    """Install the filter of ``DRAKE_NOISE`` on the ``drake`` logger, once. Done when this
    module loads: a Meshcat server may start before the station is built
    (``closed_loop.simulate``)."""
    drake = logging.getLogger("drake")
    if not any(isinstance(f, _DrakeNoise) for f in drake.filters):
        drake.addFilter(_DrakeNoise())


quiet_drake()


JOINTS = ("shoulder", "elbow", "z")  # canonical joint c = 3·i + m of arm i
OBJECT_MASS = 0.1  # kg
OBJECT_MODULUS = 1e7  # Pa, compliant hydroelastic modulus of the objects
# m: the spheres an object stands on. Point contact of a box on the table is one point, and a
# pushed box sank 6-8 mm into it; hydroelastic box-table contact cost 1.4x the physics of a step.
SUPPORT_RADIUS = 0.002


@dataclass(frozen=True)
class Scara:
    """The SCARA of ``models/dual_scara.sdf``, as its closed-form controller needs it."""

    arm_joints: tuple[tuple[Joint, Joint, Joint], ...]  # (shoulder, elbow, z) per arm
    link_lengths: tuple[float, float]  # read from the model
    elbow_signs: tuple[int, int]
    position_indices: tuple[int, ...]  # canonical joint c → index in the plant's q
    actuator_order: tuple[int, ...]  # desired-state slot a → canonical joint c


@dataclass(frozen=True)
class Station:
    """What :func:`AddStation` made. Index conventions: arm i = 0 right, 1 left; object j in
    scenario order. The arms are our SCARA (``scara``) or a scenario's robot model (``arms``)."""

    plant: MultibodyPlant
    scene_graph: SceneGraph
    robots: tuple[ModelInstanceIndex, ...]  # the robot's model instances (one, or one per arm)
    object_instances: tuple[ModelInstanceIndex, ...]
    hands: tuple[RigidBody, RigidBody]  # per arm, the body whose origin holds objects
    objects: tuple[RigidBody, ...]
    arm_bases: np.ndarray  # (2, 2): where each arm stands on the table, read from the model
    scara: Scara | None
    arms: tuple[Arm, Arm] | None
    grasp_half_sizes: tuple[float, ...]
    object_size: float
    grasp_height: float  # hand height when it holds an object: its tip on the object's top face
    travel_height: float  # hand height when it holds nothing
    hand_range: tuple[float, float, float, float]  # the planner's workspace: [x0, x1, y0, y1]
    hand_gap: float  # eq. (16): x_arm2 + hand_gap ≤ x_arm1
    time_step: float
    slide_time_constant: float | None  # the table's viscous drag on sliding objects (Gripper)
    table: list[float]  # the table top drawn: [x0, x1, y0, y1]
    # The pairs of collision geometries, one of each arm (right first), that may touch.
    arm_pairs: tuple[tuple[GeometryId, GeometryId], ...]
    # Each collision geometry of a hand (tip, quill) with each object's box.
    hand_object_pairs: tuple[tuple[GeometryId, GeometryId], ...]

    @property
    def n_objects(self) -> int:
        return len(self.objects)


def _point_contact(mu: float) -> ProximityProperties:
    props = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(mu, mu), properties=props)
    return props


def _object_proximity(size: float, mu: float) -> ProximityProperties:
    props = _point_contact(mu)
    AddCompliantHydroelasticProperties(size, OBJECT_MODULUS, props)
    return props


def table_extent(scenario: Scenario, margin: float = 0.15) -> list[float]:
    """The table top [x0, x1, y0, y1]: ``margin`` beyond the workspace, every goal and every
    object's start."""
    xs = [scenario.robot.workspace[0], scenario.robot.workspace[1]]
    ys = [scenario.robot.workspace[2], scenario.robot.workspace[3]]
    for box in scenario.task.goals.values():
        xs += box[:2]
        ys += box[2:]
    for o in scenario.task.objects:
        xs.append(o.position[0])
        ys.append(o.position[1])
    return [min(xs) - margin, max(xs) + margin, min(ys) - margin, max(ys) + margin]


def _add_table_and_goals(plant: MultibodyPlant, scenario: Scenario) -> GeometryId:
    """The table (its collision geometry is returned) and the goal patches drawn on it."""
    world = plant.world_body()
    table = plant.RegisterCollisionGeometry(world, RigidTransform(), HalfSpace(), "table",
                                            _point_contact(scenario.table.friction))
    x0, x1, y0, y1 = table_extent(scenario)
    thickness = 0.02
    plant.RegisterVisualGeometry(
        world,
        RigidTransform([(x0 + x1) / 2, (y0 + y1) / 2, -thickness / 2]),
        Box(x1 - x0, y1 - y0, thickness),
        "table_top",
        np.array(TABLE_COLOUR),
    )
    for name, (gx0, gx1, gy0, gy1) in scenario.task.goals.items():
        rgb = np.array(goal_colour(name))
        plant.RegisterVisualGeometry(
            world,
            RigidTransform([(gx0 + gx1) / 2, (gy0 + gy1) / 2, 0.0005]),
            Box(gx1 - gx0, gy1 - gy0, 0.001),
            f"goal_{name}",
            np.append(0.6 * rgb + 0.4, 1.0),
        )
    return table


def _add_objects(
    plant: MultibodyPlant, scenario: Scenario
) -> tuple[tuple[ModelInstanceIndex, ...], tuple[RigidBody, ...], tuple[GeometryId, ...]]:
    """The objects: their model instances, bodies and box collision geometries."""
    size = scenario.table.object_size
    support = _point_contact(scenario.table.friction)
    corner = size / 2 - SUPPORT_RADIUS
    instances, bodies, boxes = [], [], []
    for o in scenario.task.objects:
        instance = plant.AddModelInstance(o.name)
        body = plant.AddRigidBody(
            o.name, instance, SpatialInertia.SolidBoxWithMass(OBJECT_MASS, size, size, size)
        )
        box = Box(size, size, size)
        boxes.append(plant.RegisterCollisionGeometry(
            body, RigidTransform(), box, "collision",
            _object_proximity(size, scenario.table.friction)))
        for k, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
            plant.RegisterCollisionGeometry(
                body, RigidTransform([sx * corner, sy * corner, -corner]),
                Sphere(SUPPORT_RADIUS), f"support_{k}", support)
        plant.RegisterVisualGeometry(
            body, RigidTransform(), box, "visual", np.append(goal_colour(o.goal), 1.0)
        )
        plant.SetDefaultFloatingBaseBodyPose(
            body, RigidTransform([o.position[0], o.position[1], size / 2])
        )
        instances.append(instance)
        bodies.append(body)
    return tuple(instances), tuple(bodies), tuple(boxes)


def _arm_geometry(plant: MultibodyPlant, joints) -> tuple[np.ndarray, tuple[float, float]]:
    """Base positions and link lengths, read from the finalized model at q = 0."""
    context = plant.CreateDefaultContext()  # called before the arms' default angles are set
    bases, lengths = [], []
    for shoulder, elbow, z in joints:

        def xy(frame):
            return frame.CalcPoseInWorld(context).translation()

        p0 = xy(shoulder.frame_on_child())
        p1 = xy(elbow.frame_on_child())
        p2 = xy(z.frame_on_child())
        if abs(p2[2]) > 1e-9:
            raise ValueError(f"model: the hand of {z.name()} is not at z = q at q = 0 ({p2[2]})")
        bases.append(p0[:2])
        lengths.append((np.linalg.norm(p1[:2] - p0[:2]), np.linalg.norm(p2[:2] - p1[:2])))
    if not np.allclose(lengths[0], lengths[1]):
        raise ValueError(f"model: the two arms' link lengths differ: {lengths}")
    return np.array(bases), (float(lengths[0][0]), float(lengths[0][1]))


def _arm_pairs(plant: MultibodyPlant, arms: tuple[list[RigidBody], list[RigidBody]],
               scene_graph: SceneGraph) -> tuple[tuple[GeometryId, GeometryId], ...]:
    """Filters out contact between the arms and everything else (table, objects) and within
    each arm; returns the pairs of collision geometries, one of each arm, left unfiltered (the
    SCARA's two columns, both welded to the world, are not)."""
    geometries = tuple([g for body in bodies for g in plant.GetCollisionGeometriesForBody(body)]
                       for bodies in arms)
    robot_ids = [g for arm in geometries for g in arm]
    rest = [g for g in scene_graph.model_inspector().GetAllGeometryIds(Role.kProximity)
            if g not in robot_ids]
    declaration = CollisionFilterDeclaration().ExcludeBetween(GeometrySet(robot_ids),
                                                              GeometrySet(rest))
    for arm in geometries:
        declaration.ExcludeWithin(GeometrySet(arm))
    scene_graph.collision_filter_manager().Apply(declaration)
    inspector = scene_graph.model_inspector()
    return tuple((a, b) for a in geometries[0] for b in geometries[1]
                 if not inspector.CollisionFiltered(a, b))


def _tip_radius(plant: MultibodyPlant, hand: RigidBody, scene_graph: SceneGraph) -> float:
    """The radius of the hand's tip, the sphere at its frame origin (the model's)."""
    inspector = scene_graph.model_inspector()
    (tip,) = [g for g in plant.GetCollisionGeometriesForBody(hand)
              if isinstance(inspector.GetShape(g), Sphere)]
    return inspector.GetShape(tip).radius()


def AddStation(builder: DiagramBuilder, scenario: Scenario, time_step: float = 2e-3) -> Station:
    """Adds the plant and scene graph of ``scenario`` to ``builder``; returns what was made.

    The arms start at rest with the hands above ``scenario.robot.hand_start`` at the travel height.
    Raises ValueError if the scenario's ``arm_bases`` differ from the SCARA model's, and
    :class:`~dualarm_mpc.sim.robot_files.RobotError` for a robot model that cannot carry the
    hands.
    """
    if time_step <= 0:
        raise ValueError(f"time_step must be positive, got {time_step}")
    config = MultibodyPlantConfig(
        time_step=time_step,
        discrete_contact_approximation="sap",
        contact_model="hydroelastic_with_fallback",
    )
    plant, scene_graph = AddMultibodyPlant(config, builder)
    table = _add_table_and_goals(plant, scenario)
    object_instances, objects, boxes = _add_objects(plant, scenario)
    scene_graph.collision_filter_manager().Apply(  # the objects stand on their spheres
        CollisionFilterDeclaration().ExcludeBetween(GeometrySet(table), GeometrySet(list(boxes))))
    if scenario.robot.robot_model is None:
        robots, hands, scara = _add_scara(plant)
        arms = None
        arm_bodies = tuple([plant.get_body(b) for b in plant.GetBodyIndices(robots[0])
                            if plant.get_body(b).name().startswith(f"{side}_")]
                           for side in ARM_SIDES)
        hand_bodies = tuple([hand] for hand in hands)
    else:
        check_robot(scenario)
        arms = AddArms(plant, scenario)
        robots = tuple(dict.fromkeys(arm.instance for arm in arms))
        hands, scara = tuple(arm.hand for arm in arms), None
        arm_bodies = tuple(list(arm.bodies) for arm in arms)
        hand_bodies = tuple(list(arm.hand_bodies) for arm in arms)
    plant.Finalize()

    if scara is not None:
        scara, bases = _place_scara(plant, scara, scenario)
        grasp_height = scenario.table.object_size + _tip_radius(plant, hands[0], scene_graph)
    else:
        place_arms(plant, arms)
        bases = np.array([arm.base[:2] for arm in arms])
        # the tool on the box's top face, 1 mm above it
        grasp_height = scenario.table.object_size + 1e-3 + max(
            tool_depth(plant, scene_graph, arm) for arm in arms)
    return Station(
        plant=plant,
        scene_graph=scene_graph,
        robots=robots,
        object_instances=object_instances,
        hands=hands,
        objects=objects,
        arm_bases=bases,
        scara=scara,
        arms=arms,
        grasp_half_sizes=tuple(o.grasp_half_size for o in scenario.task.objects),
        object_size=scenario.table.object_size,
        grasp_height=grasp_height,
        travel_height=TRAVEL_HEIGHT,
        hand_range=tuple(scenario.robot.workspace),
        hand_gap=scenario.robot.hand_gap,
        time_step=time_step,
        slide_time_constant=scenario.table.slide_time_constant,
        table=table_extent(scenario),
        arm_pairs=_arm_pairs(plant, arm_bodies, scene_graph),
        hand_object_pairs=tuple((g, box) for bodies in hand_bodies for body in bodies
                                for g in plant.GetCollisionGeometriesForBody(body)
                                for box in boxes),
    )


def _add_scara(plant: MultibodyPlant):
    """Our SCARA (``models/dual_scara.sdf``): its instance, hands and joints, before Finalize."""
    parser = Parser(plant)
    parser.package_map().AddMap(package_map())
    (robot,) = parser.AddModels(url=ROBOT_URL)
    joints = tuple(
        tuple(plant.GetJointByName(f"{arm}_{name}", robot) for name in JOINTS) for arm in ARM_SIDES
    )
    hands = tuple(plant.GetBodyByName(f"{arm}_hand", robot) for arm in ARM_SIDES)
    return (robot,), hands, joints


def _place_scara(plant: MultibodyPlant, joints, scenario: Scenario) -> tuple[Scara, np.ndarray]:
    """The SCARA's geometry read from the finalized model and checked against the scenario's;
    its default posture: the hands above ``hand_start`` at the travel height."""
    bases, lengths = _arm_geometry(plant, joints)
    if not np.allclose(bases, np.asarray(scenario.robot.arm_bases, float), atol=1e-9):
        raise ValueError(
            f"arm_bases: the scenario has {scenario.robot.arm_bases}, the robot model "
            f"{bases.tolist()} (models/dual_scara.sdf is the source of the robot)"
        )
    if not (np.allclose(bases, ROBOT_ARM_BASES, atol=1e-9) and
            np.allclose(lengths, ROBOT_LINKS, atol=1e-9)):
        raise ValueError(f"model: bases {bases.tolist()} and links {lengths} differ from "
                         "scenario.ROBOT_ARM_BASES and ROBOT_LINKS, which validate scenarios")
    for i, (shoulder, elbow, z) in enumerate(joints):
        q1, q2 = scara_ik(scenario.robot.hand_start[i], bases[i], lengths, ELBOW_SIGNS[i])
        shoulder.set_default_angle(q1)
        elbow.set_default_angle(q2)
        z.set_default_translation(TRAVEL_HEIGHT)
    canonical = [joint for arm in joints for joint in arm]
    robot = canonical[0].model_instance()
    actuated = [
        plant.get_joint_actuator(a).joint().index() for a in plant.GetJointActuatorIndices(robot)
    ]
    actuator_order = tuple([j.index() for j in canonical].index(a) for a in actuated)
    if sorted(actuator_order) != list(range(6)):
        raise ValueError(f"model: expected the 6 arm joints to be actuated, got {actuated}")
    return Scara(joints, lengths, ELBOW_SIGNS, tuple(j.position_start() for j in canonical),
                 actuator_order), bases


@dataclass(frozen=True)
class ControlStack:
    """The low-level systems :func:`AddControlStack` added. Left open for the caller:
    ``interpolator.get_plan_input_port()`` (a TimedTrajectory) and
    ``estimator.get_measured_state_output_port()``."""

    interpolator: Interpolator
    controller: Controller | DifferentialIkController
    gripper: Gripper
    estimator: StateEstimator


def AddControlStack(builder: DiagramBuilder, station: Station) -> ControlStack:
    """Adds and connects Interpolator → Controller → plant, Gripper ↔ plant, StateEstimator.

    ::

        plan ─▶ Interpolator ─hand_reference─▶ Controller ─desired_state─▶ plant
                     │ grasp_command               ▲ plant_state             │
                     ▼                             └─────────────────────────┤
                  Gripper ◀─ body_poses, body_spatial_velocities ────────────┤
                     │ spatial_forces ─▶ plant (applied_spatial_force)       │
                     │ grasp                                                  │
                     ▼                                                        │
               StateEstimator ◀─ body_poses, body_spatial_velocities ────────┘
                     │
                     ▼ measured_state
    """
    plant = station.plant
    interpolator = builder.AddNamedSystem(
        "interpolator",
        Interpolator(station.n_objects, station.grasp_height, station.travel_height,
                     limits=Limits(station.hand_range, station.hand_gap)),
    )
    controller = _add_controller(builder, station)
    gripper = builder.AddNamedSystem(
        "gripper",
        Gripper(plant, station.hands, station.objects, station.grasp_half_sizes, station.time_step,
                hold_height=station.grasp_height - station.object_size / 2,
                slide_time_constant=station.slide_time_constant),
    )
    estimator = builder.AddNamedSystem(
        "state_estimator", StateEstimator(station.hands, station.objects)
    )
    builder.Connect(
        interpolator.get_hand_reference_output_port(), controller.get_hand_reference_input_port()
    )
    builder.Connect(
        interpolator.get_grasp_command_output_port(), gripper.get_grasp_command_input_port()
    )
    for system in (gripper, estimator):
        builder.Connect(plant.get_body_poses_output_port(), system.get_body_poses_input_port())
        builder.Connect(
            plant.get_body_spatial_velocities_output_port(),
            system.get_body_spatial_velocities_input_port(),
        )
    builder.Connect(
        gripper.get_spatial_forces_output_port(), plant.get_applied_spatial_force_input_port()
    )
    builder.Connect(gripper.get_grasp_output_port(), estimator.get_grasp_input_port())
    return ControlStack(interpolator, controller, gripper, estimator)


def _add_controller(builder: DiagramBuilder, station: Station
                    ) -> Controller | DifferentialIkController:
    """The SCARA's closed-form controller, or the differential IK of a robot model, wired to
    the plant's desired-state inputs (the hand reference is the caller's)."""
    plant, scara = station.plant, station.scara
    if scara is not None:
        controller = builder.AddNamedSystem("controller", Controller(
            station.arm_bases, scara.link_lengths, scara.position_indices, scara.actuator_order,
            plant.num_multibody_states(), scara.elbow_signs, hand_gap=station.hand_gap))
        builder.Connect(plant.get_state_output_port(), controller.get_plant_state_input_port())
        builder.Connect(controller.get_desired_state_output_port(),
                        plant.get_desired_state_input_port(station.robots[0]))
        return controller
    arms = station.arms
    outputs = []
    for instance in station.robots:
        names = []
        for a in plant.GetJointActuatorIndices(instance):
            name = plant.get_joint_actuator(a).joint().name()
            owner = [i for i, arm in enumerate(arms) if arm.instance == instance and
                     name in {j.name() for j in arm.joints}]
            names.append((owner[0] if owner else
                          next(i for i, arm in enumerate(arms) if arm.instance == instance),
                          name))
        outputs.append(names)
    controller = builder.AddNamedSystem("controller", DifferentialIkController(
        [arm.control for arm in arms], outputs))
    for k, instance in enumerate(station.robots):
        builder.Connect(controller.GetOutputPort(f"desired_state_{k}"),
                        plant.get_desired_state_input_port(instance))
    return controller
