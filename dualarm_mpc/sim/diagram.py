"""The closed-loop Diagram: station, control stack and MPC planner, built in one straight line.

::

    GoalSource ─goals─▶ MpcPlanner ─plan─▶ Interpolator ─▶ Controller ─▶ MultibodyPlant ◀─▶ Gripper
                            ▲                                                  │
                            └──────────── measured_state ◀── StateEstimator ◀──┘
                                  SceneGraph ─query─▶ Clearance ×2
                       plant ─contact_results─▶ ObjectContacts

The Diagram exports its outputs by name (:func:`!_export`; docs/drake.md, "Ports"), so that a
user connects stock systems (a ``VectorLogSink``, a ``TrajectorySource``) to
``diagram.GetOutputPort(name)`` without knowing the systems inside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.framework import Context, Diagram, DiagramBuilder
from pydrake.systems.primitives import Multiplexer

from dualarm_mpc.model.mld import REST_SPEED, delivered_objects
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.planning.mpc import Solve
from dualarm_mpc.sim.station import AddControlStack, AddStation, ControlStack, Station
from dualarm_mpc.systems.clearance import Clearance
from dualarm_mpc.systems.goals import GoalSource
from dualarm_mpc.systems.mpc_planner import MpcPlanner
from dualarm_mpc.systems.object_contacts import ObjectContacts
from dualarm_mpc.systems.state_estimator import StateEstimator


@dataclass(frozen=True)
class DualArm:
    """The built Diagram and the handles a simulation needs. A context manager: the ``with``
    block's end closes the planner (``MpcPlanner.close``)."""

    diagram: Diagram
    station: Station
    stack: ControlStack
    planner: MpcPlanner
    clearance: Clearance  # between the two arms
    hand_clearance: Clearance  # between the hands and the objects
    goals: GoalSource
    object_contacts: ObjectContacts  # pairs of objects that touched while one moved
    scenario: Scenario  # what it was built for

    def __enter__(self) -> DualArm:
        return self

    def __exit__(self, *exc) -> None:
        self.planner.close()

    def delivered(self, context: Context) -> np.ndarray:
        """(N,) bool: each object at rest on the plant (``REST_SPEED``) inside its goal as the
        goals are now (a moved goal counts), at the root ``context``'s time."""
        plant = self.station.plant
        pc = plant.GetMyContextFromRoot(context)
        pos = [plant.EvalBodyPoseInWorld(pc, b).translation()[:2] for b in self.station.objects]
        vel = [plant.EvalBodySpatialVelocityInWorld(pc, b).translational()
               for b in self.station.objects]
        boxes = self.goals.goals(self.goals.GetMyContextFromRoot(context))
        return delivered_objects(self.scenario, pos, vel, REST_SPEED, boxes)


def _export(builder: DiagramBuilder, station: Station, stack: ControlStack,
            planner: MpcPlanner) -> None:
    """The Diagram's output ports, each under its system's port name: the measured state and
    its named parts (StateEstimator), the robot's joint state ``robot_state`` (the plant's
    [q; v] of the robot model instance, or of each arm's, arm 1 first), and the plan in force
    as itself, as Drake trajectories, and the last replan (MpcPlanner)."""
    for name in ("measured_state", *StateEstimator.PARTS):
        builder.ExportOutput(stack.estimator.GetOutputPort(name), name)
    states = [station.plant.get_state_output_port(robot) for robot in station.robots]
    if len(states) > 1:  # a one-arm model loaded per arm: [x_arm1; x_arm2]
        mux = builder.AddNamedSystem("robot_state", Multiplexer([p.size() for p in states]))
        for k, port in enumerate(states):
            builder.Connect(port, mux.get_input_port(k))
        states = [mux.get_output_port(0)]
    builder.ExportOutput(states[0], "robot_state")
    for name in ("plan", "replan", "hand_trajectory", "object_trajectory", "grasp_schedule"):
        builder.ExportOutput(planner.GetOutputPort(name), name)


def MakeDiagram(scenario: Scenario, meshcat: Meshcat | None = None,
                time_step: float = 2e-3, solve: Solve | None = None,
                contacts: bool = False) -> DualArm:
    """Build the closed loop for ``scenario``; with ``meshcat``, visualize (and record) there
    what a person sees (the illustration geometry), and with ``contacts`` also the contact forces
    and the proximity and inertia geometry. ``solve`` replaces the planner's solve of one horizon
    (``MpcPlanner``). The Diagram's output ports are :func:`!_export`'s."""
    builder = DiagramBuilder()
    station = AddStation(builder, scenario, time_step)
    stack = AddControlStack(builder, station)
    planner = builder.AddNamedSystem("mpc_planner", MpcPlanner(scenario, solve=solve))
    goals = builder.AddNamedSystem("goals", GoalSource(scenario.task.goals))
    builder.Connect(goals.get_goals_output_port(), planner.get_goals_input_port())
    builder.Connect(stack.estimator.get_measured_state_output_port(),
                    planner.get_measured_state_input_port())
    builder.Connect(planner.get_plan_output_port(), stack.interpolator.get_plan_input_port())
    clearance = builder.AddNamedSystem("arm_clearance", Clearance(station.arm_pairs))
    hand_clearance = builder.AddNamedSystem("hand_clearance",
                                            Clearance(station.hand_object_pairs))
    for system in (clearance, hand_clearance):
        builder.Connect(station.scene_graph.get_query_output_port(),
                        system.get_geometry_query_input_port())
    plant = station.plant
    contacts_seen = builder.AddNamedSystem("object_contacts",
                                           ObjectContacts(plant, station.objects))
    builder.Connect(plant.get_contact_results_output_port(),
                    contacts_seen.get_contact_results_input_port())
    builder.Connect(plant.get_body_spatial_velocities_output_port(),
                    contacts_seen.get_body_spatial_velocities_input_port())
    if meshcat is not None:
        from pydrake.visualization import ApplyVisualizationConfig, VisualizationConfig

        # Drake's default publishes all four; the contact forces and the hidden geometry were
        # nine tenths of a replay's animation (docs/drake.md, "Recording and replay").
        config = VisualizationConfig(publish_proximity=contacts, publish_inertia=contacts,
                                     publish_contacts=contacts)
        ApplyVisualizationConfig(config, builder, meshcat=meshcat)
    _export(builder, station, stack, planner)
    diagram = builder.Build()
    diagram.set_name("dualarm_mpc")
    return DualArm(diagram, station, stack, planner, clearance, hand_clearance, goals,
                   contacts_seen, scenario)
