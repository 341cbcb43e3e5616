"""Disturbances of the closed loop: what a disturbance sees, the knock and the goal move, and
seeded random disturbances with the model's verdict on the objects they leave stuck.

A :class:`Disturbance` decides environment events while the run goes on (``closed_loop.simulate``
calls it at its ``next_time()`` with the :class:`World` it sees); :func:`knock` and
:func:`move_goal` change the simulation for an event, the scenario's and a disturbance's alike.

:class:`RandomDisturbances` draws the robustness bench's disturbances (``bench/robustness.py``),
``per_kind`` of each kind:

* ``held`` — an object is knocked out of the hand that carries it (the gripper lets go);
* ``delivered`` — an object resting in its goal is knocked out of it;
* ``table`` — any object is knocked to a uniformly random place on the table top;
* ``goal`` — a goal is moved to a random free place inside the hands' range (same size).

Each is due at a random time in its ``WINDOW``; ``held`` and ``delivered`` then wait (looking
every ``LOOK_EVERY``) until an object is held / rests in its goal, and are skipped (and logged)
if none is within ``PATIENCE``. Knocks move an object by ``KNOCK_DISTANCE`` in a random direction
(``held``, ``delivered``; out of its goal for the latter) or anywhere on the table (``table``);
every knock lands on the table top, ``CLEARANCE`` clear of every other object and of both hands'
grasp boxes, and leaves the object at rest. A moved goal stays inside the hand range and the
table, ``CLEARANCE`` clear of the other goals, covers no object of another goal and moves by at
least ``GOAL_SHIFT``.

Randomness: ``numpy.random.SeedSequence([DISTURBANCE_KEY, seed])`` (apart from the objects' own
draw from ``seed``); each disturbance draws from its own child of it, so one disturbance's draws
never shift another's, and both rules of a seed get the same disturbances. Which object a knock
hits is read from the simulated state when it fires: the same on any machine in lockstep.

**Stuck** (:func:`stuck_reason`, from the model's bounds, never from how a run ended): an object
is stuck when, where it lies, no plan within the model can deliver it and it is not in its goal:
no hand can grasp it (outside the hand range — per hand, with eq. (16)'s gap — widened by its
grasp half-size H_ij); or, under rule 1 (no-throw: no release outside the goal, hence no regrasp
and no hand-over), no single grasp carries it into its target box: the object moves rigidly with
the hand, so from a grasp at offset o it can only reach o + hand range.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialVelocity
from pydrake.systems.framework import Context

from dualarm_mpc.model.mld import REST_SPEED, Rect, State, delivered_objects, in_goal, target_box
from dualarm_mpc.model.scenario import Event, Scenario
from dualarm_mpc.sim.diagram import DualArm
from dualarm_mpc.sim.station import table_extent

# --- what a disturbance sees, and what it may do ---------------------------------------------


@dataclass(frozen=True)
class World:
    """What a :class:`Disturbance` sees when it looks: the measured state (hands, objects, what
    the gripper holds now), and the goals and deliveries as the planner last counted them."""

    t: float
    state: State  # measured
    goals: dict[str, list[float]]
    delivered: np.ndarray  # (N,) bool: resting in its goal at the planner's last replan

    @classmethod
    def observe(cls, dual: DualArm, context: Context) -> World:
        """The world of the run ``dual`` at the root ``context``'s time."""
        estimator = dual.stack.estimator
        measured = State.from_vector(estimator.get_measured_state_output_port().Eval(
            estimator.GetMyContextFromRoot(context)), dual.station.n_objects)
        s = dual.planner.latest_state(dual.planner.GetMyContextFromRoot(context))
        goals = dual.goals.goals(dual.goals.GetMyContextFromRoot(context))
        return cls(t=context.get_time(), state=measured,
                   goals={k: list(v) for k, v in goals.items()},
                   delivered=np.array([d is not None for d in s.delivered_time], bool))


class Disturbance(Protocol):
    """Environment events decided while the run goes on (e.g. "knock the object in the hand"),
    next to the scenario's fixed ``events``. The simulation looks at ``next_time()`` (None: no
    more) and calls the disturbance there; each call must move ``next_time()`` on."""

    def next_time(self) -> float | None: ...

    def __call__(self, world: World) -> list[Event]: ...


def knock(dual: DualArm, context: Context, j: int, position: list[float]) -> None:
    """Put object ``j`` at ``position`` (x, y; its height kept) at rest, out of the hand: else
    the grip pulls it straight back."""
    plant, body = dual.station.plant, dual.station.objects[j]
    pc = plant.GetMyMutableContextFromRoot(context)
    z = plant.EvalBodyPoseInWorld(pc, body).translation()[2]
    plant.SetFreeBodyPose(pc, body, RigidTransform([*position, z]))
    plant.SetFreeBodySpatialVelocity(pc, body, SpatialVelocity.Zero())
    gripper = dual.stack.gripper
    gripper.detach(gripper.GetMyMutableContextFromRoot(context), j)


def move_goal(dual: DualArm, context: Context, name: str, box: list[float]) -> None:
    """Move goal ``name`` to ``box`` [x0, x1, y0, y1]; the planner sees it at its next replan."""
    dual.goals.set_goal(dual.goals.GetMyMutableContextFromRoot(context), name, box)


# --- the model's bounds: where an object can be delivered from --------------------------------


def hand_ranges(scenario: Scenario) -> tuple[Rect, Rect]:
    """The range of hand 1 (right) and hand 2 (left): the workspace, less eq. (16)'s gap on the
    side of the other hand (x_arm2 + gap <= x_arm1, both inside the workspace)."""
    ws = Rect.of(scenario.robot.workspace)
    gap = scenario.robot.hand_gap
    right = Rect(ws.lo + [gap, 0.0], ws.hi.copy())
    left = Rect(ws.lo.copy(), ws.hi - [gap, 0.0])
    return right, left


def stuck_reason(scenario: Scenario, goals: dict[str, list[float]], j: int,
                 p: np.ndarray) -> str | None:
    """Why no plan within the model can deliver object j from ``p`` with ``goals`` (None: it can,
    or it is in its goal already). From the model's bounds only (module docstring)."""
    p = np.asarray(p, float)[:2]
    sc = replace(scenario, task=replace(scenario.task, goals=goals))
    obj = sc.task.objects[j]
    if in_goal(p, goals[obj.goal]):
        return None
    half = obj.grasp_half_size
    target = target_box(sc, j)
    graspable = False
    for hand in hand_ranges(sc):
        lo = np.maximum(hand.lo, p - half)  # where this hand can be while it grasps
        hi = np.minimum(hand.hi, p + half)
        if np.any(lo > hi + 1e-12):
            continue
        graspable = True
        if sc.task.rule != 1:
            return None  # rule 2: put down and pick up again, or throw: any graspable object
        # Rule 1: one grasp, offset o = p - h (h in [lo, hi]); the object reaches o + range.
        reach_lo = p - hi + hand.lo
        reach_hi = p - lo + hand.hi
        if np.all(reach_lo <= target.hi + 1e-12) and np.all(target.lo <= reach_hi + 1e-12):
            return None
    if not graspable:
        return "beyond the hands' grasp range"
    return "rule 1: no single grasp carries it into its goal"


# --- seeded random disturbances ----------------------------------------------------------------

KINDS = ("held", "delivered", "table", "goal")
DISTURBANCE_KEY = 7  # SeedSequence([KEY, seed]): the disturbances' stream, apart from the objects'
# When each kind is due (s of simulated time): ``held`` early (the robot carries most then),
# ``delivered`` once deliveries have begun.
WINDOW = {"held": (3.0, 40.0), "delivered": (15.0, 70.0), "table": (3.0, 70.0),
          "goal": (3.0, 70.0)}
LOOK_EVERY = 0.5  # s: a disturbance waiting for its condition looks again
PATIENCE = 40.0  # s: ... and gives up after
KNOCK_DISTANCE = (0.10, 0.35)  # m: how far a held / delivered object is knocked
CLEARANCE = 0.02  # m: between a knocked object and other objects / hands' grasp boxes / goals
GOAL_SHIFT = 0.2  # m: a moved goal's centre moves at least this far
TRIES = 2000  # random draws for a free place before a disturbance is skipped


@dataclass
class Scheduled:
    """One disturbance: its kind, when it is due, its own RNG."""

    kind: str
    due: float
    rng: np.random.Generator
    give_up: float = 0.0
    next_look: float = 0.0


@dataclass
class RandomDisturbances:
    """Seeded random disturbances of one run, a :class:`Disturbance` (module docstring).

    ``log`` records every disturbance fired or skipped: kind, time, target, from/to (or the goal
    boxes), and, for knocks and goal moves, the objects it left stuck (:func:`stuck_reason`)."""

    scenario: Scenario
    seed: int
    per_kind: int = 1
    kinds: tuple[str, ...] = KINDS
    schedule: list[Scheduled] = field(init=False)
    log: list[dict] = field(default_factory=list, init=False)
    stuck: dict[int, str] = field(default_factory=dict, init=False)  # object → reason, now

    def __post_init__(self) -> None:
        kinds = [k for k in self.kinds for _ in range(self.per_kind)]
        children = np.random.SeedSequence([DISTURBANCE_KEY, self.seed]).spawn(len(kinds))
        self.schedule = []
        for kind, child in zip(kinds, children, strict=True):
            rng = np.random.default_rng(child)
            due = float(np.round(rng.uniform(*WINDOW[kind]), 3))
            self.schedule.append(Scheduled(kind, due, rng, give_up=due + PATIENCE, next_look=due))
        self.schedule.sort(key=lambda d: d.due)
        sc = self.scenario
        table = Rect.of(table_extent(sc)).shrink(sc.table.object_size / 2)
        self.table = table  # where an object's centre may be: the whole box on the table top
        self.initial_stuck = {j: r for j, o in enumerate(sc.task.objects)
                              if (r := stuck_reason(sc, sc.task.goals, j, o.position))}
        self.stuck = dict(self.initial_stuck)

    # the Disturbance protocol

    def next_time(self) -> float | None:
        return min((d.next_look for d in self.schedule), default=None)

    def __call__(self, world: World) -> list[Event]:
        d = min(self.schedule, key=lambda d: d.next_look)
        event, entry = getattr(self, f"_{d.kind}")(d, world)
        if event is None and world.t + LOOK_EVERY <= d.give_up and entry is None:
            d.next_look = world.t + LOOK_EVERY  # its condition does not hold yet: look again
            return []
        self.schedule.remove(d)
        entry = {"kind": d.kind, "due": d.due, "t": round(world.t, 3), **(entry or {})}
        if event is None:
            wanted = "held" if d.kind == "held" else "resting in its goal"
            entry.setdefault("skipped", f"no object {wanted} within {PATIENCE:g} s of its time")
        else:
            entry.update(self.judge(event, world))
        self.log.append(entry)
        return [] if event is None else [event]

    def judge(self, event: Event, world: World) -> dict:
        """Re-decide stuck for the objects ``event`` touches in ``world``; the log entry's
        fields."""
        sc = self.scenario
        names = [o.name for o in sc.task.objects]
        if event.kind == "move_object":
            j = names.index(event.target)
            reason = stuck_reason(sc, world.goals, j, event.position)
            self._set_stuck(j, reason)
            return {"from": [round(float(v), 4) for v in world.state.object_pos[j]],
                    "to": event.position, "was_held": bool(world.state.grasp[:, j].any()),
                    "stuck": reason}
        goals = {**world.goals, event.target: event.box}
        stuck = {}
        for j, o in enumerate(sc.task.objects):
            if o.goal == event.target:
                reason = stuck_reason(sc, goals, j, world.state.object_pos[j])
                self._set_stuck(j, reason)
                if reason:
                    stuck[o.name] = reason
        return {"stuck": stuck or None}

    # one per kind: (event, log entry) — (None, None) to wait, (None, entry) to skip

    def _held(self, d: Scheduled, world: World):
        held = np.flatnonzero(world.state.grasp.any(axis=0))
        if held.size == 0:
            return None, None
        j = int(d.rng.choice(held))
        return self._knock(d, world, j, lambda p: True)

    def _delivered(self, d: Scheduled, world: World):
        resting = self._resting(world)
        if resting.size == 0:
            return None, None
        j = int(d.rng.choice(resting))
        goal = Rect.of(world.goals[self.scenario.task.objects[j].goal])
        margin = self.scenario.table.object_size / 2  # the whole box out of the goal
        return self._knock(d, world, j, lambda p: not goal.contains(p, tol=margin))

    def _table(self, d: Scheduled, world: World):
        j = int(d.rng.integers(self.scenario.n_objects))
        for _ in range(TRIES):
            p = d.rng.uniform(self.table.lo, self.table.hi)
            if self._free(p, j, world):
                return self._move(world, j, p), {"target": self.scenario.task.objects[j].name}
        return None, {"target": self.scenario.task.objects[j].name, "skipped": "no free place"}

    def _goal(self, d: Scheduled, world: World):
        sc = self.scenario
        names = sorted(world.goals)
        name = names[int(d.rng.integers(len(names)))]
        old = Rect.of(world.goals[name])
        size = old.hi - old.lo
        ws = Rect.of(sc.robot.workspace)
        region = Rect(np.maximum(ws.lo, self.table.lo), np.minimum(ws.hi, self.table.hi) - size)
        others = [Rect.of(b) for g, b in world.goals.items() if g != name]
        strangers = [j for j, o in enumerate(sc.task.objects) if o.goal != name]
        for _ in range(TRIES):
            lo = d.rng.uniform(region.lo, region.hi)
            new = Rect(lo, lo + size)
            if np.abs((new.lo + new.hi) / 2 - (old.lo + old.hi) / 2).max() < GOAL_SHIFT:
                continue
            if any(overlap(new, b, CLEARANCE) for b in others):
                continue
            if new.contains(world.state.object_pos[strangers], tol=sc.table.object_size / 2).any():
                continue
            box = [round(float(v), 4) for v in new.bounds()]
            return Event(time=round(world.t, 3), kind="move_goal", target=name, box=box), {
                "target": name, "from": world.goals[name], "to": box}
        return None, {"target": name, "skipped": "no free place"}

    # helpers

    def _resting(self, world: World) -> np.ndarray:
        x = world.state
        resting = delivered_objects(self.scenario, x.object_pos, x.object_vel, REST_SPEED,
                                    world.goals)
        return np.flatnonzero(resting & ~x.grasp.any(axis=0))

    def _knock(self, d: Scheduled, world: World, j: int, accept: Callable[[np.ndarray], bool]):
        name = self.scenario.task.objects[j].name
        for _ in range(TRIES):
            angle = d.rng.uniform(0.0, 2 * math.pi)
            distance = d.rng.uniform(*KNOCK_DISTANCE)
            p = world.state.object_pos[j] + distance * np.array([math.cos(angle), math.sin(angle)])
            if accept(p) and self._free(p, j, world):
                return self._move(world, j, p), {"target": name}
        return None, {"target": name, "skipped": "no free place"}

    def _free(self, p: np.ndarray, j: int, world: World) -> bool:
        """On the table top, clear of every other object and of both hands' grasp boxes."""
        sc = self.scenario
        if not self.table.contains(p):
            return False
        others = np.delete(world.state.object_pos, j, axis=0)
        size = sc.table.object_size
        if others.size and (np.abs(others - p).max(axis=1) < size + CLEARANCE).any():
            return False
        reach = sc.task.objects[j].grasp_half_size + size / 2 + CLEARANCE
        return not (np.abs(world.state.hand_pos - p).max(axis=1) < reach).any()

    def _move(self, world: World, j: int, p: np.ndarray) -> Event:
        position = [round(float(v), 4) for v in p]
        return Event(time=round(world.t, 3), kind="move_object",
                     target=self.scenario.task.objects[j].name, position=position)

    def _set_stuck(self, j: int, reason: str | None) -> None:
        if reason:
            self.stuck[j] = reason
        else:
            self.stuck.pop(j, None)


def overlap(a: Rect, b: Rect, gap: float) -> bool:
    """Whether boxes ``a`` and ``b`` come closer than ``gap`` on both axes."""
    return bool(np.all(a.lo < b.hi + gap) and np.all(b.lo < a.hi + gap))
