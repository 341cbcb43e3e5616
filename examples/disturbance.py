"""Build the closed-loop Diagram yourself, disturb the robot while it works, and run it.

Two objects of §V-D on the robot. The simulation runs to t = 4 s, knocks object1 away there (out
of the hand if it holds it), runs to t = 8 s and moves the red goal: each change made to the
Context between two ``AdvanceTo`` calls, never inside the Simulator's monitor, which only looks
(here: it ends the run once every object rests in its goal). The MPC planner sees both at its
next replan and still delivers every object. Lockstep, as ``simulate`` runs by default: the run
is the same on any machine.

    python examples/disturbance.py
"""

from __future__ import annotations

from pydrake.systems.analysis import Simulator, SimulatorStatus
from pydrake.systems.framework import EventStatus

from dualarm_mpc.model.mld import REST_SPEED, delivered_objects
from dualarm_mpc.model.scenario import load_scenario, merge_overrides
from dualarm_mpc.sim.closed_loop import on_robot
from dualarm_mpc.sim.diagram import MakeDiagram
from dualarm_mpc.sim.disturbances import knock, move_goal

KNOCK_T, KNOCK_TO = 4.0, [-0.15, 0.05]  # s, m: object1 lands here
MOVE_T, RED = 8.0, [0.3, 0.6, 0.3, 0.6]  # s, the red goal's new box
END_T = 60.0


def main() -> None:
    task = {"seed": 2, "random_objects": {"count": 2}}
    base = load_scenario("table1_vd", task)
    overrides = on_robot(base)  # the robot's settings (at rest in the goal, a margin inside it)
    merge_overrides(overrides, task)
    scenario = load_scenario("table1_vd", overrides)
    dual = MakeDiagram(scenario)
    simulator = Simulator(dual.diagram)
    root = simulator.get_mutable_context()

    def knock_object1(context) -> None:  # out of the hand, if it holds it
        knock(dual, context, 0, KNOCK_TO)
        print(f"t = {context.get_time():4.1f} s: object1 knocked to {KNOCK_TO}")

    def move_red(context) -> None:
        move_goal(dual, context, "red", RED)
        print(f"t = {context.get_time():4.1f} s: the red goal moved to {RED}")

    def monitor(context) -> EventStatus:  # looks only
        if context.get_time() > MOVE_T and all(_delivered(scenario, dual, context)):
            return EventStatus.ReachedTermination(None, "every object at rest in its goal")
        return EventStatus.Succeeded()

    simulator.set_monitor(monitor)
    for t, change in ((KNOCK_T, knock_object1), (MOVE_T, move_red), (END_T, None)):
        status = simulator.AdvanceTo(t)
        if status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition:
            break
        if change is not None:
            change(root)
    dual.planner.close()
    t = root.get_time()
    names = [o.name for o in scenario.task.objects]
    ok = _delivered(scenario, dual, root)
    print(f"t = {t:4.1f} s: " + ", ".join(f"{n} {'in' if k else 'NOT in'} its goal"
                                          for n, k in zip(names, ok, strict=True)))
    if not all(ok):
        raise SystemExit(1)


def _delivered(scenario, dual, context) -> list[bool]:
    """Each object at rest (the robot's tolerance) inside its goal, as the goals are now."""
    plant = dual.station.plant
    pc = plant.GetMyContextFromRoot(context)
    boxes = dual.goals.goals(dual.goals.GetMyContextFromRoot(context))
    pos = [plant.EvalBodyPoseInWorld(pc, b).translation()[:2] for b in dual.station.objects]
    vel = [plant.EvalBodySpatialVelocityInWorld(pc, b).translational()
           for b in dual.station.objects]
    return delivered_objects(scenario, pos, vel, REST_SPEED, boxes).tolist()


if __name__ == "__main__":
    main()
