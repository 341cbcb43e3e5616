"""Tests of the Drake side: robot model, station, and the low-level systems (docs/drake.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource

from dualarm_mpc.base.palette import goal_colour
from dualarm_mpc.model.mld import State
from dualarm_mpc.model.plan import TimedTrajectory, Trajectory
from dualarm_mpc.model.scenario import ObjectSpec, Scenario, Table, Task, load_scenario
from dualarm_mpc.sim.resources import ROBOT_URL, models_dir, package_map
from dualarm_mpc.sim.station import AddControlStack, AddStation, Station
from dualarm_mpc.systems.clearance import Clearance
from dualarm_mpc.systems.controller import (
    GAP_SLACK,
    Controller,
    scara_fk,
    scara_ik,
    scara_jacobian,
    scara_joint_velocity,
)
from dualarm_mpc.systems.gripper import REST_NOISE, Gripper
from dualarm_mpc.systems.interpolator import (
    TRAVEL_HEIGHT,
    Interpolator,
    Limits,
    empty_plan,
    node_velocities,
    sample_grasp,
    sample_hands,
)
from dualarm_mpc.systems.object_contacts import ObjectContacts
from dualarm_mpc.systems.state_estimator import StateEstimator
from dualarm_mpc.systems.trajectories import plan_trajectories

G = 9.81
GRASP_HEIGHT = 0.025


def one_object_scenario(friction: float = 0.02, slide_time_constant: float | None = None
                        ) -> Scenario:
    return Scenario(
        table=Table(friction=friction, slide_time_constant=slide_time_constant),
        task=Task(goals={"red": [0.2, 0.4, 0.5, 0.7]},
                  objects=[ObjectSpec(name="box", position=[0.1, 0.1], goal="red")]),
    )


def right_hand_plan(nodes, grasps, t0: float = 0.0, n: int = 1) -> TimedTrajectory:
    """The right hand visits ``nodes`` [(p, v)] and holds the first of ``n`` objects where
    ``grasps``; the left rests at (−0.1, 0)."""
    k = len(nodes) - 1
    hand_pos = np.array([[p, [-0.1, 0.0]] for p, _ in nodes], dtype=float)
    hand_vel = np.array([[v, [0.0, 0.0]] for _, v in nodes], dtype=float)
    grasp = np.zeros((k + 1, 2, n), dtype=int)
    grasp[:, 0, 0] = grasps
    trajectory = Trajectory(
        hand_pos=hand_pos,
        hand_vel=hand_vel,
        force=np.zeros((k, 2, 2)),
        object_pos=np.zeros((k + 1, n, 2)),
        object_vel=np.zeros((k + 1, n, 2)),
        grasp=grasp,
    )
    return TimedTrajectory(t0=t0, dt=1.0, trajectory=trajectory)


class Rig:
    """Station + control stack fed by a constant plan, ready to simulate; with ``contacts``, an
    ObjectContacts on the plant's contact results."""

    def __init__(self, scenario: Scenario, plan: TimedTrajectory, contacts: bool = False):
        builder = DiagramBuilder()
        self.station = AddStation(builder, scenario)
        self.stack = AddControlStack(builder, self.station)
        source = builder.AddSystem(ConstantValueSource(AbstractValue.Make(plan)))
        builder.Connect(source.get_output_port(), self.stack.interpolator.get_plan_input_port())
        if contacts:
            plant = self.station.plant
            self.contacts = builder.AddSystem(ObjectContacts(plant, self.station.objects))
            builder.Connect(plant.get_contact_results_output_port(),
                            self.contacts.get_contact_results_input_port())
            builder.Connect(plant.get_body_spatial_velocities_output_port(),
                            self.contacts.get_body_spatial_velocities_input_port())
        self.diagram = builder.Build()
        self.simulator = Simulator(self.diagram)
        self.simulator.Initialize()
        self.n = scenario.n_objects

    def measured(self) -> State:
        estimator = self.stack.estimator
        context = estimator.GetMyContextFromRoot(self.simulator.get_context())
        x = estimator.get_measured_state_output_port().Eval(context)
        return State.from_vector(x, self.n)

    def advance(self, t: float) -> State:
        self.simulator.AdvanceTo(t)
        return self.measured()


# --- model and resources -----------------------------------------------------------------------


def test_model_loads_from_installed_package():
    assert (models_dir() / "package.xml").is_file()
    assert package_map().GetPath("dualarm_mpc") == str(models_dir())
    plant = MultibodyPlant(2e-3)
    parser = Parser(plant)
    parser.package_map().AddMap(package_map())
    (robot,) = parser.AddModels(url=ROBOT_URL)
    plant.Finalize()
    actuators = [plant.get_joint_actuator(a) for a in plant.GetJointActuatorIndices(robot)]
    assert sorted(a.joint().name() for a in actuators) == sorted(
        f"{arm}_{j}" for arm in ("right", "left") for j in ("shoulder", "elbow", "z")
    )
    assert all(a.get_controller_gains().p > 0 and a.get_controller_gains().d > 0 for a in actuators)
    assert plant.get_desired_state_input_port(robot).size() == 12
    assert plant.HasBodyNamed("right_hand", robot) and plant.HasBodyNamed("left_hand", robot)


def test_station_reads_the_model_and_places_objects():
    scenario = load_scenario("table1_vc")
    station = AddStation(DiagramBuilder(), scenario)
    np.testing.assert_allclose(station.arm_bases, [[0.3, -0.8], [-0.3, -0.8]])
    assert station.scara.link_lengths == pytest.approx((0.9, 1.3))
    assert [b.name() for b in station.objects] == [o.name for o in scenario.task.objects]
    assert station.plant.time_step() == pytest.approx(2e-3)
    context = station.plant.CreateDefaultContext()
    for body, spec in zip(station.objects, scenario.task.objects, strict=True):
        p = station.plant.EvalBodyPoseInWorld(context, body).translation()
        np.testing.assert_allclose(p, [*spec.position, scenario.table.object_size / 2], atol=1e-12)
    for hand, start in zip(station.hands, scenario.robot.hand_start, strict=True):
        p = station.plant.EvalBodyPoseInWorld(context, hand).translation()
        np.testing.assert_allclose(p, [*start, TRAVEL_HEIGHT], atol=1e-12)
    assert goal_colour("red") != goal_colour("green") != goal_colour("blue")
    assert goal_colour("purple") == goal_colour("anything else")


def test_station_rejects_arm_bases_that_differ_from_the_model():
    scenario = one_object_scenario()
    scenario.robot.arm_bases = [[0.4, 0.3], [-0.3, 0.3]]
    with pytest.raises(ValueError, match="arm_bases"):
        AddStation(DiagramBuilder(), scenario)


def test_ik_round_trip_through_the_plant_over_the_workspace():
    """FK(IK(p)) == p with the plant's own kinematics, for both arms, on a grid of the hand
    range [-0.9, 0.9] × [-0.3, 0.9]; the elbows are on opposite sides."""
    station = AddStation(DiagramBuilder(), one_object_scenario())
    plant = station.plant
    context = plant.CreateDefaultContext()
    q = plant.GetPositions(context)
    grid = [(x, y) for x in np.linspace(-0.9, 0.9, 13) for y in np.linspace(-0.3, 0.9, 9)]
    scara = station.scara
    for i, hand in enumerate(station.hands):
        base = station.arm_bases[i]
        for p in grid:
            angles = scara_ik(p, base, scara.link_lengths, scara.elbow_signs[i])
            assert np.sign(angles[1]) in (0, scara.elbow_signs[i])
            np.testing.assert_allclose(scara_fk(angles, base, scara.link_lengths), p, atol=1e-9)
            q[list(scara.position_indices[3 * i : 3 * i + 3])] = [*angles, 0.07]
            plant.SetPositions(context, q)
            x = plant.EvalBodyPoseInWorld(context, hand).translation()
            np.testing.assert_allclose(x, [*p, 0.07], atol=1e-9)


# --- arms that keep clear ------------------------------------------------------------------------


def arm_bodies(station: Station, arm: str) -> list:
    plant = station.plant
    return [plant.get_body(b) for b in plant.GetBodyIndices(station.robots[0])
            if plant.get_body(b).name().startswith(f"{arm}_")]


def collision_geometries(station: Station, bodies) -> set:
    return {g for b in bodies for g in station.plant.GetCollisionGeometriesForBody(b)}


def test_the_arms_collide_with_each_other_only():
    """Every visual of the arms has its collision geometry; contact within an arm and between an
    arm and the table or an object is filtered out; the pairs measured are every other pair of
    one geometry of each arm."""
    station = AddStation(DiagramBuilder(), one_object_scenario())
    inspector = station.scene_graph.model_inspector()
    right, left = (collision_geometries(station, arm_bodies(station, arm))
                   for arm in ("right", "left"))
    assert len(right) == len(left) == 7  # column, 2 beams, 2 hubs, tip, quill
    world = collision_geometries(station, [station.plant.world_body(), *station.objects])
    assert len(world) == 6  # the table; the object's box and the four spheres it stands on
    for arm in (right, left):
        assert all(inspector.CollisionFiltered(a, b) for a in arm for b in arm if a != b)
        assert all(inspector.CollisionFiltered(a, w) for a in arm for w in world)
    assert set(station.arm_pairs) == {(a, b) for a in right for b in left
                                      if not inspector.CollisionFiltered(a, b)}
    assert len(station.arm_pairs) == 7 * 7 - 1  # the two columns, both welded, are not


class ArmPoser:
    """The station alone, its arms posed by inverse kinematics; SceneGraph measures them."""

    def __init__(self):
        builder = DiagramBuilder()
        self.station = AddStation(builder, one_object_scenario())
        self.clearance = builder.AddSystem(Clearance(self.station.arm_pairs))
        builder.Connect(self.station.scene_graph.get_query_output_port(),
                        self.clearance.get_geometry_query_input_port())
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()

    def pose(self, context, hands, heights=(TRAVEL_HEIGHT, TRAVEL_HEIGHT)) -> None:
        station = self.station
        pc = station.plant.GetMyMutableContextFromRoot(context)
        for i, (shoulder, elbow, z) in enumerate(station.scara.arm_joints):
            q1, q2 = scara_ik(hands[i], station.arm_bases[i], station.scara.link_lengths,
                              station.scara.elbow_signs[i])
            shoulder.set_angle(pc, q1)
            elbow.set_angle(pc, q2)
            z.set_translation(pc, heights[i])

    def clearance_at(self, hands, heights=(TRAVEL_HEIGHT, TRAVEL_HEIGHT)) -> float:
        self.pose(self.context, hands, heights)
        sg = self.station.scene_graph
        return self.clearance.clearance(
            sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(self.context)))


def test_every_pair_of_hand_positions_eq_16_allows_keeps_the_arms_apart():
    """The robot stands in front of the hand range: wherever eq. (16) lets the hands go in the
    §V-D range (which holds §V-C's), hands at the travel or the grasp height, SceneGraph finds the
    arms at least 5 cm apart (1 cm is the goal; the rest is room for the controller)."""
    poser = ArmPoser()
    gap = one_object_scenario().robot.hand_gap
    xs, ys = np.arange(-0.9, 0.901, 0.15), np.arange(-0.3, 0.901, 0.15)
    least, k = np.inf, 0
    for xl in xs:
        for y_left in ys:
            for xr in [xl + gap, *xs[xs > xl + gap]]:
                for y_right in ys:
                    if xr > 0.9 + 1e-9:
                        continue
                    heights = (TRAVEL_HEIGHT, GRASP_HEIGHT)[::1 if k % 2 else -1]
                    least = min(least, poser.clearance_at([(xr, y_right), (xl, y_left)], heights))
                    k += 1
    assert k > 5000
    assert least >= 0.05


def test_crossed_arms_overlap_and_the_least_clearance_is_kept():
    """ArmClearance samples from t = 0 and keeps the least distance seen: hands crossed
    (the left one right of the right one) make it negative, and so it stays."""
    poser = ArmPoser()
    assert poser.clearance_at([(-0.2, 0.3), (0.2, 0.3)]) < 0  # crossed: links through links
    simulator = Simulator(poser.diagram)
    context = simulator.get_mutable_context()
    port = poser.clearance.get_min_clearance_output_port()
    clearance_context = poser.clearance.GetMyContextFromRoot(context)
    assert port.Eval(clearance_context)[0] == np.inf  # no sample yet
    poser.pose(context, [(-0.2, 0.3), (0.2, 0.3)])
    simulator.AdvanceTo(0.005)
    crossed = port.Eval(clearance_context)[0]
    assert crossed < 0
    poser.pose(context, [(0.3, 0.3), (-0.3, 0.3)])
    simulator.AdvanceTo(0.05)
    assert port.Eval(clearance_context)[0] == crossed
    assert poser.clearance_at([(0.3, 0.3), (-0.3, 0.3)]) > 0.1


def test_joint_velocity_inverts_the_jacobian():
    q = np.array([0.3, -1.2])
    v = np.array([0.2, -0.1])
    qd = scara_joint_velocity(q, v, (0.7, 0.7))
    np.testing.assert_allclose(scara_jacobian(q, (0.7, 0.7)) @ qd, v, atol=1e-5)


# --- shapes --------------------------------------------------------------------------------------


def test_interpolator_shape():
    system = Interpolator(n_objects=3, grasp_height=GRASP_HEIGHT)
    assert system.get_plan_input_port().get_name() == "plan"
    assert system.get_hand_reference_output_port().get_name() == "hand_reference"
    assert system.get_hand_reference_output_port().size() == 12
    assert system.get_grasp_command_output_port().get_name() == "grasp_command"
    assert system.get_grasp_command_output_port().size() == 6
    assert system.num_input_ports() == 1 and system.num_output_ports() == 2
    with pytest.raises(ValueError, match="grasp_height"):
        Interpolator(n_objects=3, grasp_height=0.2, travel_height=0.1)


def test_controller_shape():
    system = Controller([[0.3, 0.3], [-0.3, 0.3]], (0.7, 0.7), range(6), range(6), 20)
    assert system.get_hand_reference_input_port().get_name() == "hand_reference"
    assert system.get_hand_reference_input_port().size() == 12
    assert system.get_plant_state_input_port().get_name() == "plant_state"
    assert system.get_plant_state_input_port().size() == 20
    assert system.get_desired_state_output_port().get_name() == "desired_state"
    assert system.get_desired_state_output_port().size() == 12
    with pytest.raises(ValueError, match="actuator_order"):
        Controller([[0.3, 0.3], [-0.3, 0.3]], (0.7, 0.7), range(6), [0, 0, 1, 2, 3, 4], 20)


def test_gripper_and_estimator_shapes():
    station = AddStation(DiagramBuilder(), load_scenario("table1_vc"))
    n = station.n_objects
    gripper = Gripper(station.plant, station.hands, station.objects, station.grasp_half_sizes, 2e-3)
    assert gripper.get_grasp_command_input_port().get_name() == "grasp_command"
    assert gripper.get_grasp_command_input_port().size() == 2 * n
    assert gripper.get_body_poses_input_port().get_name() == "body_poses"
    assert gripper.get_body_spatial_velocities_input_port().get_name() == "body_spatial_velocities"
    assert gripper.get_spatial_forces_output_port().get_name() == "spatial_forces"
    assert gripper.get_grasp_output_port().get_name() == "grasp"
    assert gripper.get_grasp_output_port().size() == 2 * n
    assert gripper.CreateDefaultContext().num_discrete_state_groups() == 1

    estimator = StateEstimator(station.hands, station.objects)
    assert estimator.get_body_poses_input_port().get_name() == "body_poses"
    assert estimator.get_grasp_input_port().size() == 2 * n
    assert estimator.get_measured_state_output_port().get_name() == "measured_state"
    assert estimator.get_measured_state_output_port().size() == State.size(n) == 8 + 6 * n


# --- interpolator and controller semantics -----------------------------------------------------


def test_interpolator_follows_the_plan_and_the_height_profile():
    a, b = np.array([0.1, 0.1]), np.array([0.3, 0.6])
    nodes = [([0.1, 0.0], [0, 0]), (a, [0, 0]), ((a + b) / 2, 0.75 * (b - a)), (b, [0, 0])]
    plan = right_hand_plan([*nodes, (b, [0, 0]), (b, [0, 0])], [0, 1, 1, 1, 0, 0], t0=2.0)
    traj = plan.trajectory
    for k in range(6):
        ref = sample_hands(plan, 2.0 + k, TRAVEL_HEIGHT, GRASP_HEIGHT).reshape(2, 6)
        np.testing.assert_allclose(ref[:, 0:2], traj.hand_pos[k], atol=1e-12)
        if k < 5:
            np.testing.assert_allclose(ref[:, 3:5], traj.hand_vel[k], atol=1e-12)
        np.testing.assert_array_equal(sample_grasp(plan, 2.0 + k + 0.5), traj.grasp[k].reshape(-1))
    z = [sample_hands(plan, 2.0 + k, TRAVEL_HEIGHT, GRASP_HEIGHT)[2] for k in range(7)]
    # down for the grasp at k = 1 (descends during step 0), up again after the release at k = 4
    assert z == pytest.approx([0.1, 0.025, 0.025, 0.025, 0.025, 0.1, 0.1])
    assert sample_hands(plan, 2.5, TRAVEL_HEIGHT, GRASP_HEIGHT)[5] < 0  # descending
    assert sample_hands(plan, 6.5, TRAVEL_HEIGHT, GRASP_HEIGHT)[5] > 0  # rising
    # before t0 and after the end: hold the first / last position at rest, grasp[0] / grasp[K]
    np.testing.assert_allclose(sample_hands(plan, 0.0, 0.1, 0.025)[[0, 1, 3, 4]], [0.1, 0, 0, 0])
    np.testing.assert_allclose(sample_hands(plan, 99.0, 0.1, 0.025)[[0, 1, 3, 4]], [*b, 0, 0])
    np.testing.assert_array_equal(sample_grasp(plan, 99.0), [0, 0])
    np.testing.assert_array_equal(sample_grasp(plan, 3.0), [1, 0])  # step boundary belongs to k


def test_interpolator_releases_with_the_velocity_of_the_step_before():
    nodes = [([0.1, 0.1], [0, 0.3]), ([0.1, 0.4], [0, 0]), ([0.1, 0.4], [0, 0])]
    held = right_hand_plan(nodes, [1, 1, 1])
    released = right_hand_plan(nodes, [1, 0, 0])
    assert sample_hands(held, 1.0, TRAVEL_HEIGHT, GRASP_HEIGHT)[4] == pytest.approx(0.0)
    assert sample_hands(released, 1.0, TRAVEL_HEIGHT, GRASP_HEIGHT)[4] == pytest.approx(0.3)
    np.testing.assert_allclose(node_velocities(released.trajectory, 1), [[0, 0.3], [0, 0]])
    for t in (0.0, 1.0, 2.0):  # positions at the steps are the plan's
        ref = sample_hands(released, t, TRAVEL_HEIGHT, GRASP_HEIGHT).reshape(2, 6)
        np.testing.assert_allclose(ref[:, :2], released.trajectory.hand_pos[int(t)], atol=1e-12)


def _turning_plan() -> TimedTrajectory:
    """From a §V-C run: both hands go left along the hand range's edge (y = 0.9), 0.1 apart as
    eq. (16) allows; at step 1 the right hand turns back at 0.34 m/s in x and down in y."""
    hand_pos = np.array([[[-0.193, 0.9], [-0.293, 0.9]], [[-0.287, 0.9], [-0.387, 0.9]],
                         [[-0.047, 0.66], [-0.471, 0.9]]])
    hand_vel = np.array([[[-0.094, 0.0], [-0.094, 0.0]], [[0.24, -0.24], [-0.084, 0.0]],
                         [[0.0, 0.0], [0.0, 0.0]]])
    return TimedTrajectory(27.0, 1.0, Trajectory(hand_pos, hand_vel, np.zeros((2, 2, 2)),
                                                 np.zeros((3, 0, 2)), np.zeros((3, 0, 2)),
                                                 np.zeros((3, 2, 0), int)))


def test_interpolator_keeps_the_reference_where_the_plan_keeps_the_hands():
    plan, limits = _turning_plan(), Limits((-0.9, 0.9, 0.0, 0.9), 0.1)
    times = np.linspace(27.0, 29.0, 201)
    free = np.array([sample_hands(plan, t, 0.1, 0.025) for t in times]).reshape(-1, 2, 6)
    kept = np.array([sample_hands(plan, t, 0.1, 0.025, limits) for t in times]).reshape(-1, 2, 6)
    # the spline alone turns past the node: out of the range and 5 cm too close in x
    assert free[:, 0, 1].max() > 0.93 and (free[:, 0, 0] - free[:, 1, 0]).min() < 0.055
    assert kept[:, :, 1].max() <= 0.9 and (kept[:, 0, 0] - kept[:, 1, 0]).min() >= 0.1 - 1e-12
    # where the gap holds the hands, they move together; at the nodes nothing changed
    tight = np.isclose(kept[:, 0, 0] - kept[:, 1, 0], 0.1) & (free[:, 0, 0] - free[:, 1, 0] < 0.1)
    assert tight.any() and np.allclose(kept[tight, 0, 3], kept[tight, 1, 3])
    for k in (0, 100, 200):
        np.testing.assert_allclose(kept[k], free[k], atol=1e-12)


def test_interpolator_system_matches_the_sampler():
    plan = right_hand_plan([([0.1, 0.0], [0, 0]), ([0.1, 0.1], [0, 0])], [0, 1])
    system = Interpolator(n_objects=1, grasp_height=GRASP_HEIGHT)
    context = system.CreateDefaultContext()
    system.get_plan_input_port().FixValue(context, AbstractValue.Make(plan))
    context.SetTime(0.3)
    np.testing.assert_allclose(
        system.get_hand_reference_output_port().Eval(context),
        sample_hands(plan, 0.3, TRAVEL_HEIGHT, GRASP_HEIGHT),
    )
    np.testing.assert_array_equal(system.get_grasp_command_output_port().Eval(context), [0, 0])
    system.get_plan_input_port().FixValue(context, AbstractValue.Make(empty_plan(2)))
    with pytest.raises(ValueError, match="2 objects"):
        system.get_grasp_command_output_port().Eval(context)


def test_controller_output_reaches_the_reference_and_unwraps():
    bases, lengths = [[0.3, 0.3], [-0.3, 0.3]], (0.7, 0.7)
    order = [3, 4, 5, 0, 1, 2]  # a permuted port, to check the bookkeeping
    system = Controller(bases, lengths, range(6), order, 12)
    context = system.CreateDefaultContext()
    ref = np.array([0.2, -0.1, 0.05, 0.1, 0.0, 0.02, -0.4, 0.5, 0.1, 0.0, -0.2, 0.0])
    system.get_hand_reference_input_port().FixValue(context, ref)
    measured = np.zeros(12)
    measured[0] = 4 * np.pi  # the right shoulder has turned twice
    system.get_plant_state_input_port().FixValue(context, measured)
    out = system.get_desired_state_output_port().Eval(context)
    q = np.empty(6)
    v = np.empty(6)
    q[order], v[order] = out[:6], out[6:]
    assert 3 * np.pi < q[0] < 5 * np.pi
    for i in range(2):
        np.testing.assert_allclose(
            scara_fk(q[3 * i : 3 * i + 2], bases[i], lengths), ref[6 * i : 6 * i + 2]
        )
        assert q[3 * i + 2] == ref[6 * i + 2] and v[3 * i + 2] == ref[6 * i + 5]
        J = scara_jacobian(q[3 * i : 3 * i + 2], lengths)
        np.testing.assert_allclose(J @ v[3 * i : 3 * i + 2], ref[6 * i + 3 : 6 * i + 5], atol=1e-5)
    assert q[4] < 0 < q[1]  # right elbow sign +1, left −1


def test_controller_keeps_each_hand_off_where_the_other_is_measured():
    """Measured on §V-D: the left hand blocked at x = 0.276 (a carried object against another),
    the right hand's reference 0.345, eq. (16)'s gap 0.1. The guard holds the right hand at
    0.276 + 0.1 − GAP_SLACK and leaves references a few millimetres off alone."""
    bases, lengths = [[0.3, -0.8], [-0.3, -0.8]], (0.9, 1.3)
    system = Controller(bases, lengths, range(6), range(6), 12, hand_gap=0.1)
    free = Controller(bases, lengths, range(6), range(6), 12)

    def measured_at(left_x: float) -> np.ndarray:
        q = np.zeros(6)
        q[0:2] = scara_ik((0.45, 0.62), bases[0], lengths, 1)
        q[3:5] = scara_ik((left_x, 0.62), bases[1], lengths, -1)
        return q

    ref = np.array([0.345, 0.616, 0.05, -0.2, -0.1, 0.0, 0.25, 0.642, 0.05, -0.2, 0.1, 0.0])
    out = system.joint_targets(ref, measured_at(0.276))
    hand = scara_fk(out[0:2], bases[0], lengths)
    assert hand[0] == pytest.approx(0.276 + 0.1 - GAP_SLACK) and hand[1] == pytest.approx(0.616)
    np.testing.assert_allclose(scara_jacobian(out[0:2], lengths) @ out[6:8], [0, -0.1], atol=1e-6)
    np.testing.assert_allclose(out[3:6], free.joint_targets(ref, measured_at(0.276))[3:6])
    # the left hand 2 mm behind its reference, as in normal tracking: nothing changes
    np.testing.assert_allclose(system.joint_targets(ref, measured_at(0.252)),
                               free.joint_targets(ref, measured_at(0.252)))


# --- physics -----------------------------------------------------------------------------------


def test_measured_state_at_rest_matches_the_scenario():
    scenario = load_scenario("table1_vc")
    rig = Rig(scenario, empty_plan(scenario.n_objects, np.array(scenario.robot.hand_start)))
    x = rig.advance(0.2)
    np.testing.assert_allclose(x.hand_pos, scenario.robot.hand_start, atol=1e-4)
    np.testing.assert_allclose(x.object_pos, [o.position for o in scenario.task.objects],
                               atol=1e-4)
    np.testing.assert_allclose(x.object_vel, 0.0, atol=1e-3)
    np.testing.assert_array_equal(x.grasp, 0.0)


@pytest.mark.slow  # seconds of plant simulation
def test_pick_drag_and_release_at_rest():
    """The right hand goes to the object at (0.1, 0.1), grasps it, drags it to (0.3, 0.6) and
    releases it at rest: the object stays there."""
    a, b = np.array([0.1, 0.1]), np.array([0.3, 0.6])
    nodes = [([0.1, 0.0], [0, 0]), (a, [0, 0]), ((a + b) / 2, 0.75 * (b - a)), (b, [0, 0])]
    plan = right_hand_plan([*nodes, (b, [0, 0]), (b, [0, 0])], [0, 1, 1, 1, 0, 0])
    rig = Rig(one_object_scenario(), plan)
    held = rig.advance(2.5)
    assert held.grasp[0, 0] == 1 and held.grasp[1, 0] == 0
    np.testing.assert_allclose(held.object_pos[0], held.hand_pos[0], atol=1e-3)
    x = rig.advance(6.5)
    assert x.grasp[0, 0] == 0
    np.testing.assert_allclose(x.object_pos[0], b, atol=0.01)
    np.testing.assert_allclose(x.object_vel[0], 0.0, atol=1e-3)


def _throw_plan(v: float, n: int = 1) -> TimedTrajectory:
    """A plan in the Euler model (p(k+1) = p(k) + v(k)): the hand drags the first of ``n``
    objects at v during step 2 and releases it at step 3, where the plan's own hand velocity is
    already 0; the object leaves at v (the model's v_obj(3) = v_hand(2))."""
    nodes = [
        ([0.1, 0.0], [0, 0.1]),
        ([0.1, 0.1], [0, 0.15]),  # grasp begins
        ([0.1, 0.25], [0, v]),
        ([0.1, 0.25 + v], [0, 0]),  # released here, at t = 3
        ([0.1, 0.25 + v], [0, 0]),
        ([0.1, 0.25 + v], [0, 0]),
    ]
    return right_hand_plan(nodes, [0, 1, 1, 0, 0, 0], n=n)


def _throw(scenario: Scenario, v: float, until: float = 8.0):
    """:func:`_throw_plan` run: (the state at the release, at ``until``)."""
    rig = Rig(scenario, _throw_plan(v))
    at_release = rig.advance(3.0)
    assert at_release.grasp[0, 0] == 1
    assert np.linalg.norm(at_release.object_vel[0]) == pytest.approx(v, rel=0.02)
    assert rig.advance(3.01).grasp[0, 0] == 0
    return at_release, rig.advance(until)


@pytest.mark.slow  # seconds of plant simulation
def test_throw_with_coulomb_friction_slides_v2_over_2_mu_g_and_stops():
    mu, v = 0.02, 0.3
    at_release, x = _throw(one_object_scenario(mu), v)
    slide = x.object_pos[0] - at_release.object_pos[0]
    assert slide[1] == pytest.approx(v**2 / (2 * mu * G), rel=0.05)
    assert abs(slide[0]) < 2e-3
    np.testing.assert_allclose(x.object_vel[0], 0.0, atol=1e-3)


@pytest.mark.slow  # seconds of plant simulation
@pytest.mark.parametrize("v", [0.2, 0.4])
def test_throw_on_the_viscous_table_slides_v_dt_at_any_speed(v):
    """The table's drag (τ = Δt = 1 s, no Coulomb friction): the slide is v·Δt, the planner's
    one-step slide, whatever the release speed (to 1 % once the object has come to rest)."""
    at_release, x = _throw(one_object_scenario(0.0, slide_time_constant=1.0), v)
    slide = x.object_pos[0] - at_release.object_pos[0]
    assert slide[1] == pytest.approx(v * 1.0, rel=0.01)
    assert abs(slide[0]) < 2e-3
    assert np.linalg.norm(x.object_vel[0]) < 0.01


@pytest.mark.slow  # seconds of plant simulation
def test_a_thrown_object_on_the_viscous_table_comes_to_rest_for_good():
    """The drag alone would slow it for ever (no Coulomb friction): below ``STOP_SPEED`` the
    gripper stops it, so 12 s after the throw it stands still, the slide still v·Δt."""
    v = 0.4
    at_release, x = _throw(one_object_scenario(0.0, slide_time_constant=1.0), v, until=15.0)
    assert np.linalg.norm(x.object_vel[0]) < REST_NOISE
    slide = x.object_pos[0] - at_release.object_pos[0]
    assert slide[1] == pytest.approx(v * 1.0, rel=0.01)


@pytest.mark.slow  # seconds of plant simulation
def test_object_contacts_finds_the_box_a_throw_shoves_and_when():
    """A box thrown at 0.3 m/s (released at t = 3 s) slides into one resting in its path and
    shoves it: ObjectContacts records that pair, from a sample after the release, and no other
    pair (two boxes 1 cm apart, never touched)."""
    scenario = Scenario(
        table=Table(friction=0.0, slide_time_constant=1.0),
        task=Task(goals={"red": [0.2, 0.4, 0.5, 0.7]},
                  objects=[ObjectSpec("thrown", [0.1, 0.1], "red"),
                           ObjectSpec("in_its_path", [0.1, 0.65], "red"),
                           ObjectSpec("c", [-0.4, 0.1], "red"),
                           ObjectSpec("d", [-0.34, 0.1], "red")]))
    rig = Rig(scenario, _throw_plan(0.3, n=4), contacts=True)
    x = rig.advance(8.0)
    assert x.object_pos[1][1] > 0.7  # shoved
    seen = rig.contacts
    context = seen.GetMyContextFromRoot(rig.simulator.get_context())
    first = seen.get_first_contact_output_port().Eval(context)
    samples = seen.get_contact_samples_output_port().Eval(context)
    touched = {pair: (t, s) for pair, t, s in zip(seen.pairs(), first, samples, strict=True)
               if np.isfinite(t)}
    assert list(touched) == [(0, 1)]
    t, s = touched[(0, 1)]
    assert 3.0 < t < 4.5 and s >= 1


def test_gripper_does_not_grab_an_object_out_of_reach():
    """Commanded to grasp while the hand is 10 cm away: nothing attaches, the object stays."""
    plan = right_hand_plan([([0.1, 0.0], [0, 0]), ([0.1, 0.0], [0, 0])], [1, 1])
    rig = Rig(one_object_scenario(), plan)
    x = rig.advance(1.0)
    np.testing.assert_array_equal(x.grasp, 0.0)
    np.testing.assert_allclose(x.object_pos[0], [0.1, 0.1], atol=1e-4)


# --- the closed loop, short (the one in make test-fast) ----------------------------------------


@pytest.mark.parametrize("latency", [1.0, 0.5])
def test_the_closed_loop_in_lockstep_applies_each_plan_one_latency_after_its_replan(latency):
    """One object on the robot for 1.6 s. The replan at t = 0 solves from rest; its plan takes
    over ``solver.replan_latency_s`` later (Δt = 1 s, or less), not before: until then the plan
    in force is the initial one (no step) and the hands hold still; from then on they follow
    the new plan. The summary JSON carries no wall-clock figure."""
    from dualarm_mpc.model.scenario import Robot, apply_overrides
    from dualarm_mpc.sim.closed_loop import simulate

    s = Scenario(name="short", robot=Robot(workspace=[-0.9, 0.9, -0.3, 0.9], max_speed=0.2,
                                           max_force=0.1),
                 task=Task(goals={"red": [0.225, 0.575, 0.65, 0.95]},
                           objects=[ObjectSpec("a", [0.1, 0.1], "red")]))
    sc = apply_overrides(s, {"delivery": "rest", "goal_margin": 0.03,
                             "solver": {"replan_latency_s": latency}})
    seen = []  # (t, steps of the plan in force, hand speed)

    def observe(dual, root) -> None:
        planner, estimator = dual.planner, dual.stack.estimator
        plan = planner.mpc_state(planner.GetMyContextFromRoot(root)).plan
        x = estimator.get_measured_state_output_port().Eval(estimator.GetMyContextFromRoot(root))
        speed = np.abs(State.from_vector(x, 1).hand_vel).max()
        seen.append((root.get_time(), plan.trajectory.steps, speed))

    summary = simulate(sc, duration=1.6, observe=observe)
    assert summary.mode == "lockstep" and summary.replan_latency_s == latency
    first = summary.replans[0]
    assert first["t"] == 0.0 and first["status"] in ("optimal", "feasible")
    before = [(steps, v) for t, steps, v in seen if t < latency - 1e-9]
    after = [(steps, v) for t, steps, v in seen if t >= latency + 0.3]
    assert before and after
    assert all(steps == 0 for steps, _ in before) and max(v for _, v in before) < 1e-3
    assert all(steps == first["horizon"] for steps, _ in after)
    assert max(v for _, v in after) > 0.02  # moving towards the object
    assert "wall" not in json.dumps(summary.to_json())


# --- Drake's own types at the ports (issue 48) ---------------------------------------------------


def _carry_and_throw() -> TimedTrajectory:
    """The right hand grasps object 1 at step 1, carries it and lets it go at step 3 at speed
    (it slides one step on); object 2 stays. t0 = 2 s, Δt = 1 s."""
    nodes = [([0.1, 0.0], [0, 0.1]), ([0.1, 0.1], [0, 0.2]), ([0.1, 0.3], [0, 0.3]),
             ([0.1, 0.6], [0, 0.1]), ([0.1, 0.7], [0, 0]), ([0.1, 0.7], [0, 0])]
    plan = right_hand_plan(nodes, [0, 1, 1, 0, 0, 0], t0=2.0, n=2)
    traj = plan.trajectory
    objects = np.array([[[0.12, 0.1], [-0.3, 0.2]]] * 6)
    objects[2:, 0, 1] = [0.3, 0.6, 0.9, 0.9]  # with the hand from step 1, sliding in step 3
    vel = np.diff(objects, axis=0, append=objects[-1:])
    return TimedTrajectory(plan.t0, plan.dt, Trajectory(traj.hand_pos, traj.hand_vel, traj.force,
                                                        objects, vel, traj.grasp))


def test_plan_trajectories_hold_the_plan_at_its_steps_and_the_interpolators_curve_between():
    plan = _carry_and_throw()
    traj, drake = plan.trajectory, plan_trajectories(plan)
    assert (drake.hand.rows(), drake.objects.rows(), drake.grasp.rows()) == (4, 4, 4)
    assert (drake.hand.start_time(), drake.hand.end_time()) == (2.0, 7.0)
    assert drake.objects.end_time() == 7.0 and drake.grasp.end_time() == 8.0
    velocity = drake.hand.derivative(1)
    for k in range(6):
        t = 2.0 + k
        np.testing.assert_allclose(drake.hand.value(t).ravel(), traj.hand_pos[k].ravel(),
                                   atol=1e-12)
        np.testing.assert_allclose(velocity.value(t).ravel(), node_velocities(traj, k).ravel(),
                                   atol=1e-12)  # at the release (k = 3) v(2), not v(3)
        np.testing.assert_allclose(drake.objects.value(t).ravel(), traj.object_pos[k].ravel(),
                                   atol=1e-12)
    for t in np.linspace(0.0, 9.0, 91):  # the hands' planar reference, the gripper's command
        reference = sample_hands(plan, t, TRAVEL_HEIGHT, GRASP_HEIGHT).reshape(2, 6)
        np.testing.assert_allclose(drake.hand.value(t).reshape(2, 2), reference[:, :2],
                                   atol=1e-12)
        if 2.0 <= t <= 7.0:
            np.testing.assert_allclose(velocity.value(t).reshape(2, 2), reference[:, 3:5],
                                       atol=1e-12)
        np.testing.assert_array_equal(drake.grasp.value(t).ravel(), sample_grasp(plan, t))
    # the objects as the plan's model moves them: v_obj(k) all through step k
    np.testing.assert_allclose(drake.objects.value(4.5).ravel(), [0.12, 0.45, -0.3, 0.2])
    np.testing.assert_allclose(drake.objects.derivative(1).value(5.5).ravel(), [0, 0.3, 0, 0])
    np.testing.assert_allclose(drake.objects.value(6.5).ravel(), [0.12, 0.9, -0.3, 0.2])


def test_a_plan_of_one_step_is_held_for_one_step():
    plan = TimedTrajectory(3.0, 0.5, empty_plan(1, np.array([[0.2, 0.1], [-0.2, 0.1]])).trajectory)
    drake = plan_trajectories(plan)
    for part in (drake.hand, drake.objects, drake.grasp):
        assert (part.start_time(), part.end_time()) == (3.0, 3.5)
    for t in (2.0, 3.0, 3.2, 9.0):
        np.testing.assert_allclose(drake.hand.value(t).ravel(), [0.2, 0.1, -0.2, 0.1])
        np.testing.assert_allclose(drake.hand.derivative(1).value(t).ravel(), 0.0)
        np.testing.assert_array_equal(drake.grasp.value(t).ravel(), [0, 0])


def test_the_estimators_named_ports_are_the_measured_states_parts():
    station = AddStation(DiagramBuilder(), one_object_scenario())
    estimator = StateEstimator(station.hands, station.objects)
    context = estimator.CreateDefaultContext()
    rng = np.random.default_rng(0)
    p, v = rng.uniform(-1, 1, (3, 3)), rng.uniform(-1, 1, (3, 3))
    poses = [RigidTransform()] * station.plant.num_bodies()
    velocities = [SpatialVelocity()] * station.plant.num_bodies()
    for body, pk, vk in zip((*station.hands, *station.objects), p, v, strict=True):
        poses[body.index()] = RigidTransform(pk)
        velocities[body.index()] = SpatialVelocity(np.zeros(3), vk)
    estimator.get_body_poses_input_port().FixValue(context, AbstractValue.Make(poses))
    estimator.get_body_spatial_velocities_input_port().FixValue(
        context, AbstractValue.Make(velocities))
    estimator.get_grasp_input_port().FixValue(context, [0.0, 1.0])
    measured = State.from_vector(estimator.get_measured_state_output_port().Eval(context), 1)

    def port(name):
        return estimator.GetOutputPort(name).Eval(context)

    np.testing.assert_array_equal(port("hand_positions"), p[:2, :2].ravel())
    np.testing.assert_array_equal(port("hand_velocities"), v[:2, :2].ravel())
    np.testing.assert_array_equal(port("object_positions"), p[2, :2])
    np.testing.assert_array_equal(port("object_velocities"), v[2, :2])
    np.testing.assert_array_equal(port("grasp_state"), [0, 1])
    for name, part in zip(StateEstimator.PARTS, ("hand_pos", "hand_vel", "object_pos",
                                                 "object_vel", "grasp"), strict=True):
        np.testing.assert_array_equal(port(name), getattr(measured, part).ravel())


def test_the_clearance_measures_only_pairs_its_bounds_leave_and_finds_the_same_least():
    """Pairs are skipped where their geometries' bounding balls are farther apart than the least
    distance found: over random poses of the arms (crossed among them), the least is every
    pair's, measured one by one."""
    poser = ArmPoser()
    sg = poser.station.scene_graph
    rng = np.random.default_rng(0)
    for _ in range(200):
        hands = rng.uniform([-0.9, -0.3], [0.9, 0.9], size=(2, 2))
        heights = rng.choice([TRAVEL_HEIGHT, GRASP_HEIGHT], size=2)
        least = poser.clearance_at(hands, heights)
        query = sg.get_query_output_port().Eval(sg.GetMyContextFromRoot(poser.context))
        every = min(query.ComputeSignedDistancePairClosestPoints(a, b).distance
                    for a, b in poser.station.arm_pairs)
        assert least == every
