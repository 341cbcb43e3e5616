"""Delivery on the robot: which objects a replan counts delivered, and which it leaves out.

An object is *delivered* when it is at rest on the robot (``mld.REST_SPEED``) in its goal, unheld
(:func:`resting`; one still held counts once the plan in force has nothing left to do with it,
:func:`kept`). A thrown object still sliding into its goal needs nothing more from the robot
(:func:`arriving`); one that reachability proves can never reach its goal is *lost*
(:func:`lost`). ``state`` is the state a replan starts from (``mpc.Replanner``: the measured one,
committed to the plan in force), ``measured`` the robot's as measured.
"""

from __future__ import annotations

import numpy as np

from dualarm_mpc.model.mld import REST_SPEED, Model, State, at_rest, in_goal, reachability
from dualarm_mpc.model.plan import TimedTrajectory, step_at
from dualarm_mpc.model.scenario import Scenario

KEPT = 1e-3  # m: a plan that moves an object less than this to its end leaves it where it is


def lost(sc: Scenario, state: State) -> np.ndarray:
    """Objects that reachability proves can never reach their goals (e.g. knocked or thrown
    short beyond the hands' reach): left out so that the others still get delivered."""
    model = Model.from_scenario(sc)
    reach = reachability(model, state, sc.solver.max_horizon)
    return reach.first_goal > sc.solver.max_horizon


def stops_in_goal(sc: Scenario, pos: np.ndarray, vel: np.ndarray | float) -> np.ndarray:
    """(N,) whether each unheld object at ``pos`` moving at ``vel`` stops in its goal: the
    one-step slide carries it v·Δt on (docs/model.md; on the robot the table's drag)."""
    stop = np.asarray(pos, float) + sc.robot.dt * np.asarray(vel, float)
    return np.array([in_goal(stop[j], sc.task.goals[o.goal])
                     for j, o in enumerate(sc.task.objects)])


def arriving(sc: Scenario, state: State, measured: State) -> np.ndarray:
    """Unheld moving objects whose one-step slide ends in their goals, in the committed state
    or in the measured one: slower than ``mpc.Tolerances.still_speed`` the committed state has
    it at rest, and one sliding in from just outside would look undelivered for a replan
    (measured: "stuck" for one replan when its goal lay out of reach)."""
    arriving = np.zeros(sc.n_objects, bool)
    for pos, vel in ((state.object_pos, state.object_vel),
                     (measured.object_pos, measured.object_vel)):
        moving = np.linalg.norm(vel, axis=1) > 0
        arriving |= stops_in_goal(sc, pos, vel) & moving
    return arriving & ~state.grasp.any(axis=0)


def resting(sc: Scenario, state: State, released: np.ndarray, measured: State) -> np.ndarray:
    """Objects delivered on the robot (at rest to ``REST_SPEED`` in their goals); one still held
    counts where ``released`` (N,): the hand has nothing left to do with it and lets go when it
    moves on. Where the measured object stops counts too (before slow speeds are taken as
    noise): one creeping across its goal's edge is not delivered (measured: reported done, it
    ended 0.4 mm outside at 2.5 mm/s). That stop point is the measured position's, not the
    committed one's: a plan's slide ends at its nominal end point, and the drag's rest of it
    added there would count the slide twice."""
    inside = (stops_in_goal(sc, state.object_pos, 0.0)
              & stops_in_goal(sc, measured.object_pos, measured.object_vel))
    return inside & at_rest(state.object_vel, REST_SPEED) & (released | ~state.grasp.any(axis=0))


def kept(plan: TimedTrajectory, t: float) -> np.ndarray:
    """(N,) objects the plan in force leaves where they are from ``t`` to its end: a held one has
    nothing left to do. Without this, a plan that only holds an object still is replaced every
    Δt by another one as long, never ends, and the object is never counted delivered — measured:
    held at rest in its goal 1e-7 m short of its target box (a solver tolerance) with the hand at
    the edge of its range, the shortest feasible horizon stayed 2 for 185 s."""
    traj = plan.trajectory
    k, _ = step_at(plan, t)
    if not 0 <= k < len(traj.object_pos):
        return np.zeros(traj.object_pos.shape[1], bool)
    rest = traj.object_pos[k:]
    return np.abs(rest - rest[0]).max(axis=(0, 2)) < KEPT
