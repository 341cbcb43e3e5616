"""Build the closed-loop Diagram yourself, disturb the robot while it works, and run it.

Two objects of §V-D on the robot. The simulation runs to t = 4 s, knocks object1 away there (out
of the hand if it holds it), runs to t = 8 s and moves the red goal: each change made to the
Context between two ``AdvanceTo`` calls, never inside the Simulator's monitor, which only looks
(here: it ends the run once every object rests in its goal). The MPC planner sees both at its
next replan and still delivers every object. Lockstep, as ``simulate`` runs by default: the run
is the same on any machine.

A ``dm.RunLog``, called from the monitor, records what ``simulate``'s summary would (every
replan, which object each hand holds, the arms' clearance); its summary, with the two changes
added as events, draws the run's timeline (``dm.plot_timeline``): the knock and the goal move
as vertical lines, and the replans and holds around them.

    python examples/disturbance.py   (writes out/disturbance.html, its replay, and
                                      out/disturbance.png, its timeline)
"""

from __future__ import annotations

from pathlib import Path

from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator, SimulatorStatus
from pydrake.systems.framework import EventStatus

import dualarm_mpc as dm

KNOCK_T, KNOCK_TO = 4.0, [-0.35, 0.1]  # s, m: object1 lands here, out of the hand's reach
MOVE_T, RED = 8.0, [0.3, 0.6, 0.3, 0.6]  # s, the red goal's new box
END_T = 60.0
REPLAY = Path("out/disturbance.html")
TIMELINE = Path("out/disturbance.png")


def main() -> None:
    # the robot's settings (at rest in the goal, a margin inside it), then this task's
    scenario = dm.load_scenario("table1_vd", {"seed": 2, "random_objects": {"count": 2}},
                                on_robot=True)
    meshcat = Meshcat(MeshcatParams(port=0))  # no browser: the run is recorded for the replay
    events = []  # the changes made, as the summary lists events
    with dm.MakeDiagram(scenario, meshcat) as dual:
        simulator = Simulator(dual.diagram)
        root = simulator.get_mutable_context()
        log = dm.RunLog(dual)  # looks only, as the monitor does

        def knock_object1(context) -> None:  # out of the hand, if it holds it
            dm.knock(dual, context, 0, KNOCK_TO)
            events.append({"time": context.get_time(), "kind": "move_object",
                           "target": "object1", "position": KNOCK_TO})
            print(f"t = {context.get_time():4.1f} s: object1 knocked to {KNOCK_TO}")

        def move_red(context) -> None:
            dm.move_goal(dual, context, "red", RED)
            events.append({"time": context.get_time(), "kind": "move_goal", "target": "red",
                           "box": RED})
            print(f"t = {context.get_time():4.1f} s: the red goal moved to {RED}")

        def monitor(context) -> EventStatus:  # looks only
            log(context)
            # the end: every object at rest in its goal, and a replan since has seen them all
            # there (the summary's delivery times are the planner's)
            seen = len(log) > 0 and log[-1].n_delivered == scenario.n_objects
            if context.get_time() > MOVE_T and seen and dual.delivered(context).all():
                return EventStatus.ReachedTermination(None, "every object at rest in its goal")
            return EventStatus.Succeeded()

        simulator.set_monitor(monitor)
        simulator.Initialize()
        meshcat.StartRecording(frames_per_second=32.0, set_visualizations_while_recording=False)
        for t, change in ((KNOCK_T, knock_object1), (MOVE_T, move_red), (END_T, None)):
            status = simulator.AdvanceTo(t)
            if status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition:
                break
            if change is not None:
                change(root)
        meshcat.StopRecording()
        meshcat.PublishRecording()
        REPLAY.parent.mkdir(parents=True, exist_ok=True)
        REPLAY.write_text(meshcat.StaticHtml())
        ok = dual.delivered(root)
        summary = log.summary(root, events)
    dm.plot_timeline(summary.to_json(), TIMELINE, "examples/disturbance.py: object1 knocked at "
                     f"{KNOCK_T:g} s, the red goal moved at {MOVE_T:g} s")
    names = [o.name for o in scenario.task.objects]
    print(f"t = {root.get_time():4.1f} s: " + ", ".join(
        f"{n} {'in' if k else 'NOT in'} its goal" for n, k in zip(names, ok, strict=True)))
    print(f"wrote {REPLAY} (open it in a browser: it plays the run)")
    print(f"wrote {TIMELINE} (the run's timeline: what each hand held, the replans, the knock "
          "and the goal move)")
    if not ok.all():
        raise SystemExit(1)


if __name__ == "__main__":
    main()
