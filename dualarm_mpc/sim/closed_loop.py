"""Closed-loop simulation of a scenario: the Diagram run in time, environment events, summary JSON.

Progress is reported per replan (sim time, objects delivered, solve wall time). The simulation
advances from one environment event to the next (``AdvanceTo``) and applies each between the
segments; a ``Simulator`` monitor only looks: it records the replans and ends the run when every
object rests (plus a short settle) after the planner is done; or the run stops at ``duration``.

Lockstep (the default, docs/drake.md): the same scenario gives the same run, summary and replay
on any machine under any load. The wall-clock figures (``Summary.wall_clock``) depend on the
machine; the summary JSON carries them only in real time (``solver.realtime``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator, SimulatorStatus
from pydrake.systems.framework import Context, EventStatus

from dualarm_mpc.base import outputs
from dualarm_mpc.model.mld import REST_SPEED, at_rest, delivered_objects
from dualarm_mpc.model.scenario import Event, Scenario, ScenarioError, seconds_problem
from dualarm_mpc.planning.mpc import Replan, Solve
from dualarm_mpc.sim import recording
from dualarm_mpc.sim.diagram import DualArm, MakeDiagram
from dualarm_mpc.sim.disturbances import Disturbance, World, knock, move_goal

log = logging.getLogger(__name__)

SETTLE_S = 1.0  # simulated seconds everything stays at rest before the run ends
# Simulated seconds between two samples of the grasps and of the arms' clearance (``RunLog``): as
# ``CLEARANCE_PERIOD_S``; each sample costs about 0.1 ms.
SAMPLE_S = 0.02


@dataclass(frozen=True)
class Summary:
    """A closed-loop run as its summary JSON keeps it (``--summary``, docs/formats.md): where
    every object ended and when it was delivered, every replan, the clearances and contacts
    sampled over the run. :meth:`save` writes it."""

    mode: str  # "lockstep" or "realtime" (``solver.realtime``)
    replan_latency_s: float  # simulated time from a replan to its plan in force
    goals: dict[str, list[float]]
    objects: list[dict]
    final_object_pos: list[list[float]]
    final_object_speed: list[float]
    delivered_time_s: list[float | None]
    replans: list[dict]
    sim_time_s: float
    all_delivered: bool
    events: list[dict]
    # Real time: replans that reached their wall-time budget, the robot following the plan in
    # force (or waiting at rest) while the search went on. Their times, as in ``replans``.
    replans_over_budget: list[float] = field(default_factory=list)
    interrupted: bool = False  # stopped by Ctrl-C at ``sim_time_s``
    # Seconds the robot stood at rest waiting for a search (Δt per "searching" replan).
    waiting_s: float = 0.0
    # The least distance between the two arms' collision geometries over the run, sampled every
    # 20 ms by SceneGraph (systems/clearance.py); None if the run took no sample.
    min_arm_clearance_m: float | None = None
    # The deepest any hand geometry (tip, quill) reached into any object's box over the run,
    # sampled as ``min_arm_clearance_m`` (0 if none ever did); None if the run took no sample.
    max_hand_penetration_m: float | None = None
    # Pairs of objects that touched while one of them moved (a box shoved by another), from the
    # plant's contact results sampled as the clearances (systems/object_contacts.py), by when
    # they first did: {objects: [name, name], t: first sample, samples: how many found it}.
    object_contacts: list[dict] = field(default_factory=list)
    # The largest horizontal distance from a hand to the centre of the box it held, sampled as
    # ``holds`` (``grasp_tolerance`` bounds it in the plan); None if nothing was ever held.
    max_held_offset_m: float | None = None
    # Which object each hand held over the run, from the gripper's grasps sampled every
    # ``SAMPLE_S`` (``RunLog``): {arm: 1 (right) or 2 (left), object: name, from, to: s}, by
    # ``from``; a hold the run's end cut short ends at ``sim_time_s``.
    holds: list[dict] = field(default_factory=list)
    # The arms' clearance over the run: [t, m] at each replan's time t, m the least distance
    # between the two arms' collision geometries (floored to 0.1 mm) at the samples since the
    # replan before, every ``SAMPLE_S``; ``min_arm_clearance_m`` is the least over the run.
    clearance: list[list[float]] = field(default_factory=list)
    # What the run took on this machine, which depends on its speed and load: ``wall_time_s``,
    # ``realtime_factor`` (simulated / wall time) and ``replan_wall_s`` (one per replan, as in
    # ``replans``). In the JSON only in real time, where it explains the run; in lockstep the
    # JSON is the same on every machine, and the command prints these instead.
    wall_clock: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        data = dict(self.__dict__)
        if self.mode == "lockstep":
            del data["wall_clock"]
        return data

    def save(self, path: str | Path) -> None:
        """Write the summary JSON, whole or not at all."""
        outputs.write(path, outputs.json_text(self.to_json()))


def default_duration(scenario: Scenario) -> float:
    """Long enough for the sequential steps with room for replanning."""
    return 30.0 + 15.0 * scenario.n_objects * scenario.robot.dt


def _apply(event: Event, scenario: Scenario, dual, context, meshcat) -> None:
    """An environment change: knock an object to a new place, or move a goal."""
    if event.kind == "move_object":
        j = [o.name for o in scenario.task.objects].index(event.target)
        knock(dual, context, j, event.position)
    else:
        move_goal(dual, context, event.target, event.box)
        if meshcat is not None:
            recording.show_goal(meshcat, event.target, event.box, context.get_time())


def check_events(scenario: Scenario, duration: float | None = None) -> None:
    """An event at or after the run's end would never happen: a bad input (``ScenarioError``,
    naming the event's field and the duration)."""
    duration = default_duration(scenario) if duration is None else duration
    for e, event in enumerate(scenario.events):
        if event.time >= duration:
            raise ScenarioError(f"events[{e}].time: {event.time:g} s is not before the run's end "
                                f"(duration {duration:g} s; set --duration)")


class _Events:
    """The run's environment events, the scenario's and the disturbance's, in time order: the
    simulation advances to :meth:`next_time` and calls :meth:`apply_due` between ``AdvanceTo``
    segments (events at one time: the scenario's in the file's order, then the disturbance's)."""

    def __init__(self, scenario: Scenario, dual, meshcat, disturb) -> None:
        self.scenario, self.dual, self.meshcat, self.disturb = scenario, dual, meshcat, disturb
        self.fixed = sorted(scenario.events, key=lambda e: e.time)
        self.next = 0
        self.applied: list[Event] = []  # the disturbance's events

    def next_time(self) -> float | None:
        """When the next event is due; None when none is left."""
        times = [self.fixed[self.next].time] if self.next < len(self.fixed) else []
        look = None if self.disturb is None else self.disturb.next_time()
        return min(times + ([] if look is None else [look]), default=None)

    def apply_due(self, context) -> None:
        t = context.get_time()
        while self.next < len(self.fixed) and self.fixed[self.next].time <= t:
            _apply(self.fixed[self.next], self.scenario, self.dual, context, self.meshcat)
            self.next += 1
        d = self.disturb
        while d is not None and (look := d.next_time()) is not None and look <= t:
            for e in d(World.observe(self.dual, context)):
                _apply(e, self.scenario, self.dual, context, self.meshcat)
                self.applied.append(e)
            after = d.next_time()
            if after is not None and after <= look:
                raise ValueError(f"disturb: next_time() stayed at {after} after a call")


class _Pace:
    """A live run's pace: the real-time rate this machine keeps, measured over ``WINDOW_S`` of
    simulated time. Where it falls behind real time the run is paced at what it keeps (one line
    says so) and a replan's wall-time budget stretches with it, so that the robot moves at a
    steady, slower pace instead of replans running over a budget meant for full speed."""

    WINDOW_S = 5.0  # simulated seconds a rate is measured over
    KEEP = 0.9  # a rate below this share of the target is falling behind

    def __init__(self, simulator: Simulator, dual: DualArm) -> None:
        self.simulator, self.dual = simulator, dual
        self.rate = 1.0
        self.since: tuple[float, float] | None = None  # (simulated, wall) time of the window

    def check(self, t: float) -> None:
        now = time.perf_counter()
        if self.since is None or t - self.since[0] < self.WINDOW_S:
            self.since = self.since or (t, now)
            return
        kept = (t - self.since[0]) / max(now - self.since[1], 1e-9)
        self.since = (t, now)
        if kept < self.KEEP * self.rate:
            self.rate = max(0.1, math.floor(10 * kept) / 10)
            self.simulator.set_target_realtime_rate(self.rate)
            self.dual.planner.pace(self.rate)
            log.warning("this machine keeps %.2f× real time: the live run goes on at %g× "
                        "(a replan's wall-time budget stretches with it)", kept, self.rate)


class RunLog(Sequence):
    """What a closed-loop run of a :class:`~dualarm_mpc.sim.diagram.DualArm` does, as its
    summary records it, by looking only: every replan (the planner's ``replan`` output; the log
    is the sequence of them), which object each hand holds (the gripper's ``grasp`` output) and
    the least distance between the arms, these two sampled every ``SAMPLE_S`` of simulated time.
    Call it after every simulator step (from the ``Simulator``'s monitor, as :func:`simulate`
    does; ``progress`` hears of each new replan); :meth:`summary` is the run's
    :class:`Summary` so far, for a Diagram run by hand too (``examples/disturbance.py``)."""

    def __init__(self, dual: DualArm, progress: Callable[[Replan], None] | None = None) -> None:
        self.dual, self.progress = dual, progress
        self._replans: list[Replan] = []
        self._held: dict[tuple[int, int], float] = {}  # (arm, object) held now: since when
        self._holds: list[tuple[int, int, float, float]] = []  # (arm, object, from, to)
        self._least = math.inf  # the arms' least distance sampled since the last replan
        self._offset: float | None = None  # the largest hand-to-held-box distance sampled
        self._clearance: list[list[float]] = []
        self._next = 0.0  # when the next sample is due
        self._wall0 = time.perf_counter()

    def __getitem__(self, k):
        return self._replans[k]

    def __len__(self) -> int:
        return len(self._replans)

    def __call__(self, context: Context) -> bool:
        """Sample the run if a sample is due, and record the planner's latest replan; whether it
        is new. ``context``: the root context."""
        t = context.get_time()
        if t >= self._next - 1e-9:
            self._sample(context, t)
            self._next = (math.floor(t / SAMPLE_S + 1e-6) + 1) * SAMPLE_S
        planner = self.dual.planner
        r = planner.get_replan_output_port().Eval(planner.GetMyContextFromRoot(context))
        if r is None or (self._replans and r.t <= self._replans[-1].t):
            return False
        self._replans.append(r)
        if math.isfinite(self._least):
            self._clearance.append([round(r.t, 3), math.floor(self._least * 1e4) / 1e4])
        self._least = math.inf
        if self.progress:
            self.progress(r)
        return True

    def _sample(self, context: Context, t: float) -> None:
        dual = self.dual
        gripper = dual.stack.gripper
        grasp = gripper.get_grasp_output_port().Eval(gripper.GetMyContextFromRoot(context))
        n = dual.station.n_objects
        now = {(i, j) for i in range(2) for j in range(n) if grasp[i * n + j] > 0.5}
        for pair in now - self._held.keys():
            self._held[pair] = t
        for pair in self._held.keys() - now:
            self._holds.append((*pair, self._held.pop(pair), t))
        if now:
            station = dual.station
            pc = station.plant.GetMyContextFromRoot(context)
            for i, j in now:
                d = (station.plant.EvalBodyPoseInWorld(pc, station.hands[i]).translation() -
                     station.plant.EvalBodyPoseInWorld(pc, station.objects[j]).translation())
                self._offset = max(self._offset or 0.0, math.hypot(d[0], d[1]))
        graph = dual.station.scene_graph
        query = graph.get_query_output_port().Eval(graph.GetMyContextFromRoot(context))
        self._least = min(self._least, dual.clearance.clearance(query))

    def holds(self, t: float) -> list[dict]:
        """The summary's ``holds``, those not yet ended ending at ``t``."""
        names = [o.name for o in self.dual.scenario.task.objects]
        ended = [*self._holds, *((i, j, since, t) for (i, j), since in self._held.items())]
        return [{"arm": i + 1, "object": names[j], "from": round(a, 3), "to": round(b, 3)}
                for i, j, a, b in sorted(ended, key=lambda h: (h[2], h[0], h[1]))]

    @property
    def held_offset(self) -> float | None:
        """The summary's ``max_held_offset_m`` (to 0.1 mm, rounded up)."""
        return None if self._offset is None else math.ceil(self._offset * 1e4) / 1e4

    @property
    def clearance(self) -> list[list[float]]:
        """The summary's ``clearance``: [t, m] per replan."""
        return list(self._clearance)

    def summary(self, context: Context, events: Sequence[Event | dict] = (),
                interrupted: bool = False, wall_s: float | None = None) -> Summary:
        """The run's :class:`Summary` at the root ``context``'s time. ``events``: the
        environment changes made during the run (each an ``Event`` or its fields as a dict:
        ``{"time", "kind", "target", "position"}`` or ``"box"``), listed after the scenario's;
        ``wall_s``: the run's wall time (by default, since this log was made)."""
        wall = time.perf_counter() - self._wall0 if wall_s is None else wall_s
        return _summary(self.dual.scenario, self.dual, context, context.get_time(), wall, self,
                        events, interrupted)


class _Monitor:
    """The run's ``Simulator`` monitor, called after every simulator step (the plant steps every
    2 ms; nothing changes in between). It only looks: records every replan from the planner's
    ``replan`` output (and tells ``progress``), lets ``observe`` look, and ends the run
    (``EventStatus.ReachedTermination``) once the replans have said ``done`` or ``stuck`` for
    ``SETTLE_S``, with every object at rest and no event pending. That end is judged at the first
    simulator step after each replan, on the state the replan saw: judged at the replan's own
    time, the last replan is Δt old, and an object that crept out of its goal since ended the
    run outside it (measured: 0.4 mm past a goal's edge at 2.5 mm/s)."""

    def __init__(self, dual, events: _Events, progress, observe,
                 pace: _Pace | None = None) -> None:
        self.dual, self.events, self.progress, self.observe = dual, events, progress, observe
        self.pace = pace
        self.replans = RunLog(dual, progress)
        self.finished_at: float | None = None

    def record(self, context) -> bool:
        """Record the planner's latest replan, and sample the run (:class:`RunLog`); whether
        the replan is new."""
        return self.replans(context)

    def __call__(self, context) -> EventStatus:
        replanned = self.record(context)
        if self.observe is not None:
            self.observe(self.dual, context)
        if not replanned:
            return EventStatus.Succeeded()
        last = self.replans[-1]
        if self.pace is not None:
            self.pace.check(last.t)
        pending = self.events.next_time() is not None
        if last.status in ("done", "stuck") and not pending and _all_at_rest(self.dual, context):
            self.finished_at = last.t if self.finished_at is None else self.finished_at
            if last.t - self.finished_at >= SETTLE_S - 1e-9:
                return EventStatus.ReachedTermination(None, "every object at rest")
        else:
            self.finished_at = None
        return EventStatus.Succeeded()


def simulate(scenario: Scenario, duration: float | None = None, html: str | Path | None = None,
             progress: Callable[[Replan], None] | None = None,
             disturb: Disturbance | None = None, meshcat: Meshcat | None = None, *,
             observe: Callable[[DualArm, Context], None] | None = None,
             solve: Solve | None = None, record_contacts: bool = False) -> Summary:
    """Run the closed loop; write the Meshcat replay to ``html`` if given. ``disturb`` adds
    events decided during the run; the summary lists them after the scenario's. ``meshcat``: a
    live server to draw the run in as it goes, at real time, and to replay it at the end.
    ``observe(dual, root_context)`` is called after every simulator step (to look, not to
    change anything); ``solve`` replaces the planner's solve of one horizon (``MakeDiagram``).
    ``record_contacts``: draw and record the contact forces and the proximity and inertia
    geometry too (by default only what a person sees).
    An event at or after the end is a ``ScenarioError`` (:func:`check_events`)."""
    problem = None if duration is None else seconds_problem(duration)
    if problem:
        raise ScenarioError(f"duration: {problem}")
    scenario.validate()
    duration = default_duration(scenario) if duration is None else duration
    check_events(scenario, duration)
    live = meshcat is not None
    if not live and html:
        meshcat = recording.start_meshcat()
    dual = MakeDiagram(scenario, meshcat, solve=solve, contacts=record_contacts)
    simulator = Simulator(dual.diagram)
    context = simulator.get_mutable_context()
    if live:
        simulator.set_target_realtime_rate(1.0)  # at the speed a person watches
    events = _Events(scenario, dual, meshcat, disturb)
    notes = None if meshcat is None else recording.Notes(meshcat, scenario, dual)
    monitor = _Monitor(dual, events, progress, recording.both(observe, notes),
                       _Pace(simulator, dual) if live else None)
    simulator.set_monitor(monitor)
    wall0 = time.perf_counter()
    interrupted = False
    try:
        simulator.Initialize()
        if meshcat is not None:  # after: the page shows the scene at t = 0 while the replay loads
            recording.show_the_work(meshcat, dual.station)
            recording.start_recording(meshcat, live)
            notes.start()
        while True:  # from one event to the next, each applied between the segments
            due = events.next_time()
            until = duration if due is None else min(max(due, context.get_time()), duration)
            status = simulator.AdvanceTo(until)
            if until >= duration or (status.reason()
                                     == SimulatorStatus.ReturnReason.kReachedTerminationCondition):
                break
            events.apply_due(context)
    except KeyboardInterrupt:  # Ctrl-C: the run so far is kept, summary and replay included
        interrupted = True
    t = context.get_time()
    monitor.record(context)  # a replan of the step Ctrl-C cut short
    wall = time.perf_counter() - wall0
    dual.planner.close()
    summary = _summary(scenario, dual, context, t, wall, monitor.replans, events.applied,
                       interrupted)
    if meshcat is not None:
        recording.save_recording(meshcat, html, notes.overlay(summary))
    if live:
        recording.end_live(meshcat, dual.station, t)
    return summary


def _object_velocities(dual, context) -> np.ndarray:
    plant = dual.station.plant
    pc = plant.GetMyContextFromRoot(context)
    return np.array([plant.EvalBodySpatialVelocityInWorld(pc, b).translational()
                     for b in dual.station.objects])


def _all_at_rest(dual, context) -> bool:
    return bool(at_rest(_object_velocities(dual, context), REST_SPEED).all())


def _summary(scenario: Scenario, dual, context, t: float, wall: float, replans: RunLog,
             applied: Sequence[Event | dict] = (), interrupted: bool = False) -> Summary:
    plant = dual.station.plant
    pc = plant.GetMyContextFromRoot(context)
    s = dual.planner.latest_state(dual.planner.GetMyContextFromRoot(context))
    goals = dual.goals.goals(dual.goals.GetMyContextFromRoot(context))
    pos = np.array([plant.EvalBodyPoseInWorld(pc, b).translation() for b in dual.station.objects])
    vel = _object_velocities(dual, context)
    speed = [float(np.linalg.norm(v)) for v in vel]
    resting = delivered_objects(scenario, pos[:, :2], vel, REST_SPEED, goals)
    realtime = dual.planner.realtime
    return Summary(
        mode="realtime" if realtime else "lockstep",
        replan_latency_s=dual.planner.latency_s,
        goals={k: list(v) for k, v in goals.items()},
        objects=[{"name": o.name, "goal": o.goal} for o in scenario.task.objects],
        final_object_pos=np.round(pos, 6).tolist(),
        final_object_speed=[round(v, 6) for v in speed],
        delivered_time_s=[None if d is None else round(d, 3) for d in s.delivered_time],
        replans=[{"t": round(r.t, 3), "start": round(r.start, 3), "status": r.status,
                  "adopted": r.adopted, "cost": r.cost, "horizon": r.horizon,
                  "objects": [scenario.task.objects[j].name for j in r.objects],
                  "delivered": r.n_delivered, "note": r.note} for r in replans],
        sim_time_s=round(t, 3),
        all_delivered=all(resting),
        events=[e if isinstance(e, dict) else dict(e.__dict__)
                for e in [*scenario.events, *applied]],
        replans_over_budget=[round(r.t, 3) for r in replans
                             if r.status in ("searching", "over_budget")],
        waiting_s=round(scenario.robot.dt * sum(r.status == "searching" for r in replans), 3),
        interrupted=interrupted,
        min_arm_clearance_m=_least(dual.clearance, context),
        max_hand_penetration_m=_penetration(_least(dual.hand_clearance, context)),
        object_contacts=_object_contacts(scenario, dual, context),
        holds=replans.holds(t),
        max_held_offset_m=replans.held_offset,
        clearance=replans.clearance,
        wall_clock={"wall_time_s": round(wall, 3),
                    "realtime_factor": round(t / wall, 4) if wall > 0 else float("inf"),
                    "replan_wall_s": [round(r.wall_s, 4) for r in replans],
                    **_percentiles([r.wall_s for r in replans])},
    )


def _percentiles(wall_s: list[float]) -> dict:
    """A replan's wall time at the median, the 95th percentile and the most."""
    if not wall_s:
        return {}
    p50, p95 = np.percentile(wall_s, [50, 95])
    return {"replan_wall_p50_s": round(float(p50), 4), "replan_wall_p95_s": round(float(p95), 4),
            "replan_wall_max_s": round(max(wall_s), 4)}


def _least(clearance, context) -> float | None:
    """The least distance ``clearance`` measured, floored to 0.1 mm: a clearance reported is
    never more than measured, a penetration never less."""
    least = clearance.get_min_clearance_output_port().Eval(
        clearance.GetMyContextFromRoot(context))[0]
    if not np.isfinite(least):
        return None
    return math.floor(least * 1e4) / 1e4


def _object_contacts(scenario: Scenario, dual, context) -> list[dict]:
    seen = dual.object_contacts
    own = seen.GetMyContextFromRoot(context)
    first = seen.get_first_contact_output_port().Eval(own)
    samples = seen.get_contact_samples_output_port().Eval(own)
    names = [o.name for o in scenario.task.objects]
    touched = [{"objects": [names[a], names[b]], "t": round(float(first[k]), 3),
                "samples": int(samples[k])}
               for k, (a, b) in enumerate(seen.pairs()) if np.isfinite(first[k])]
    return sorted(touched, key=lambda c: (c["t"], c["objects"]))


def _penetration(least: float | None) -> float | None:
    return None if least is None else max(0.0, -least)
