"""Reach: a robot model checked against the hand range before anything moves (docs/robots.md).

The planner sends each hand anywhere in the part of the hand range (``workspace``) that eq. (16)
lets it enter: arm 1 (right) to ``x ≥ x_min + hand_gap``, arm 2 (left) to ``x ≤ x_max − hand_gap``.
:func:`check_robot` asks Drake's ``InverseKinematics`` for each arm's posture at points of that
part (a grid, at the heights a hand holds and travels at), in the orientation the controller
keeps (:mod:`dualarm_mpc.sim.robot`), each from its neighbour's posture; and, with both hands
``hand_gap`` apart at the same y (their closest allowed approach), for the SceneGraph distance
between the arms. The first point an arm cannot reach, or the least ``hand_gap`` that keeps
``ARM_CLEARANCE`` between the arms, is a :class:`~dualarm_mpc.sim.robot_files.RobotError` in
one line.
The SCARA is checked in closed form by the scenario itself.
"""

from __future__ import annotations

import numpy as np
from pydrake.geometry import SceneGraph
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph, MultibodyPlant
from pydrake.systems.framework import DiagramBuilder

from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.sim.robot import AddArms, Arm, place_arms, solve_hand_ik
from dualarm_mpc.sim.robot_files import RobotError
from dualarm_mpc.systems.interpolator import TRAVEL_HEIGHT

ARM_CLEARANCE = 0.03  # m: what the arms keep apart at the hands' closest approach
GRID = 4  # points per side of the grid over each arm's part of the hand range
GAP_STEP = 0.01  # m: how finely the least hand_gap is sought


# The robots (their scenario keys) that passed in this process: the command line checks before
# planning, and the station again when it is built.
_PASSED: set[str] = set()


def check_robot(scenario: Scenario) -> None:
    """Raises RobotError if an arm of ``scenario.robot.robot_model`` cannot reach its part of
    the hand range with the tool down, or the arms come closer than ``ARM_CLEARANCE`` at
    eq. (16)'s closest approach."""
    key = repr((scenario.robot, scenario.table.object_size))
    if key in _PASSED:
        return
    _check(scenario)
    _PASSED.add(key)


def _check(scenario: Scenario) -> None:
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    arms = AddArms(plant, scenario)
    plant.Finalize()
    place_arms(plant, arms)
    pairs = _arm_pairs(plant, scene_graph, arms)
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    q = plant.GetPositions(plant.GetMyContextFromRoot(context))
    facings = [_orientation(arm) for arm in arms]
    robot = scenario.robot
    x0, x1, y0, y1 = robot.workspace
    heights = (scenario.table.object_size, TRAVEL_HEIGHT)
    ys = np.linspace(y0, y1, GRID)
    for i, arm in enumerate(arms):
        lo, hi = (x0 + robot.hand_gap, x1) if i == 0 else (x0, x1 - robot.hand_gap)
        guess = q
        for z in heights:
            for y in ys:
                for x in np.linspace(lo, hi, GRID):
                    found = _posture(plant, arm, [x, y, z], guess, facings[i])
                    if found is None:
                        raise RobotError(
                            f"robot_model: arm {i + 1} cannot reach {_point([x, y, z])} with its "
                            f"tool down (workspace {robot.workspace}, hand_gap {robot.hand_gap} "
                            f"by eq. (16)): move arm_bases or shrink the workspace")
                    guess = found
    least = _least_gap(plant, scene_graph, context, arms, facings, pairs, q, scenario)
    if least > robot.hand_gap + 1e-9:
        raise RobotError(
            f"hand_gap: the arms come within {ARM_CLEARANCE} m of each other with the hands "
            f"{robot.hand_gap} m apart; the least hand_gap that keeps them apart is "
            f"{least:.2f}")


def _point(p) -> str:
    return "[" + ", ".join(f"{v:.3g}" for v in p) + "]"


def _orientation(arm: Arm):
    """The hand's orientation in the nominal posture, which the controller keeps."""
    context = arm.control.plant.CreateDefaultContext()
    arm.control.plant.SetPositions(context, arm.control.nominal)
    return arm.control.hand.CalcPoseInWorld(context).rotation()


def _posture(plant: MultibodyPlant, arm: Arm, point, guess: np.ndarray,
             facing) -> np.ndarray | None:
    return solve_hand_ik(plant, arm.hand.body_frame(), arm.joints, point, guess, facing)


def _arm_pairs(plant: MultibodyPlant, scene_graph: SceneGraph, arms):
    geometries = [[g for body in arm.bodies for g in plant.GetCollisionGeometriesForBody(body)]
                  for arm in arms]
    return [(a, b) for a in geometries[0] for b in geometries[1]]


def _least_gap(plant, scene_graph, context, arms, facings, pairs, q,
               scenario: Scenario) -> float:
    """The least hand_gap, from eq. (16)'s own up in ``GAP_STEP``, at which both hands at the
    same y, that far apart along x, leave ``ARM_CLEARANCE`` between the arms everywhere."""
    robot = scenario.robot
    x0, x1, y0, y1 = robot.workspace
    gap = robot.hand_gap
    while gap <= x1 - x0:
        if _clear_at(plant, scene_graph, context, arms, facings, pairs, q, gap, scenario):
            return gap
        gap += GAP_STEP
    return gap


def _clear_at(plant, scene_graph, context, arms, facings, pairs, q, gap: float,
              scenario: Scenario) -> bool:
    x0, x1, y0, y1 = scenario.robot.workspace
    z = TRAVEL_HEIGHT
    guesses = [q, q]
    for y in np.linspace(y0, y1, GRID):
        for x_left in np.linspace(x0, x1 - gap, GRID):
            points = ([x_left + gap, y, z], [x_left, y, z])
            posture = q.copy()
            for i, arm in enumerate(arms):
                found = _posture(plant, arm, points[i], guesses[i], facings[i])
                if found is None:
                    return False
                guesses[i] = found
                for joint in arm.joints:
                    posture[joint.position_start()] = found[joint.position_start()]
            plant.SetPositions(plant.GetMyMutableContextFromRoot(context), posture)
            query = scene_graph.get_query_output_port().Eval(
                scene_graph.GetMyContextFromRoot(context))
            if min(query.ComputeSignedDistancePairClosestPoints(a, b).distance
                   for a, b in pairs) < ARM_CLEARANCE:
                return False
    return True
