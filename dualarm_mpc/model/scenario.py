"""Scenario: the typed description of one table-top task (Table I of the paper), loaded from YAML.

A :class:`Scenario` groups its fields as :class:`Robot`, :class:`Table`, :class:`Task`,
:class:`SolverSettings` and a list of :class:`Event`, each checking its own values; the file keeps
them flat (``max_speed``, ``m_o``), and :data:`YAML_FIELDS` maps each key to its group's field.
A scenario file is read into these dataclasses; every field can then be overridden by a YAML
mapping (the CLI's ``--set``), whose keys may be paths in the form errors are reported in
(``solver.time_limit_s: 5``, ``objects[3].position: [0.1, 0.2]``). Any bad file or value raises
:class:`ScenarioError` naming the field, e.g. ``objects[3].position[1]: expected a number, got
'abc'``. Text is read by YAML 1.2's core schema (``yamlcore``). Every number field carries its
:class:`Range` (docs/scenarios.md lists them), checked before anything else; the caps
(``MAX_*``) bound the work a scenario can ask for.

Why one module of this length: the loader reads only through the dataclasses' own type hints,
ranges and :data:`YAML_FIELDS`; split, a field, its key, its range and its check would live in
two files that must change together.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import importlib.util
import math
import re
import reprlib
import types
import typing
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from dualarm_mpc.base import yamlcore
from dualarm_mpc.logic.parser import LTLSyntaxError, parse

BUILTIN = ("table1_vc", "table1_vd", "panda_vc", "panda_vd")
SOLVER_BACKENDS = ("highs", "scip", "gurobi", "cplex")  # solver.BACKENDS, without importing it

# Caps on the work a scenario can ask for (docs/scenarios.md, "Caps"), each checked on loading.
# Objects: `plan` of 200 objects takes 47 s on 2 cores ((m_o, n_o) = (2, 4)) and its consistency
# check 12 s, growing with the count; 2,000 would take the better part of an hour.
MAX_OBJECTS = 200
MAX_HORIZON = 1000  # solver.max_horizon: the per-object check builds a program at this horizon
# Any text (a rule, a name, a key): the paper's rules have 40 to 60 characters
MAX_TEXT_CHARS = 10_000
# task_form: subsets is a disjunction of C(n, m_o) conjunctions in every program of a step:
# C(12, 6) = 924 build a program of T = 40 in 0.27 s, C(16, 8) = 12,870 in 2.3 s (measured), and
# a step builds one per horizon tried, the search many more
MAX_TASK_SUBSETS = 1000
# The route bound of a step (model/route.py): m_o·2^m_o stages per hand and axis (m_o = 10:
# 21 s and 400 MB, measured; each object more doubles both), over C(n_o, m_o)·2^m_o choices of
# the objects delivered and the hand that first holds each (C(200, 2)·4 = 79,600)
MAX_STEP_DELIVERIES = 10
MAX_ROUTE_CHOICES = 100_000


def ortools_installed() -> bool:
    """Whether OR-Tools (the CP-SAT relaxation, ``cpsat.py``) is installed here."""
    return importlib.util.find_spec("ortools") is not None


class ScenarioError(ValueError):
    """A scenario file or override has a bad field; the message starts with the field's path."""


@dataclass(frozen=True)
class Range:
    """The values a number field takes: ``lo`` to ``hi``, each excluded if open (a number in a
    list or mapping field: each of them)."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False

    def check(self, value: float, path: str) -> None:
        if isinstance(value, float) and not math.isfinite(value):  # as a file's value is told
            raise ScenarioError(f"{path}: expected a finite number, got "
                                f"{_show(yamlcore.written(value))}")
        above = value > self.lo if self.lo_open else value >= self.lo
        below = value < self.hi if self.hi_open else value <= self.hi
        if not (above and below):
            raise ScenarioError(f"{path}: must be {self}, got {_show(value)}")

    def __str__(self) -> str:
        return (f"{'>' if self.lo_open else '>='} {_number(self.lo)} and "
                f"{'<' if self.hi_open else '<='} {_number(self.hi)}")


def _in(lo: float, hi: float, lo_open: bool = False, hi_open: bool = False) -> dict:
    """A field's metadata: its :class:`Range`."""
    return {"range": Range(lo, hi, lo_open, hi_open)}


# Coordinates on the table, metres: the arms reach 2.2 m from their bases (models/dual_scara.sdf)
COORDINATE = _in(-10.0, 10.0)
# The robot of models/dual_scara.sdf (station.py reads it from the model and checks these): each
# arm's base and its two links, metres. A hand reaches |l1 − l2| to l1 + l2 from its base.
ROBOT_ARM_BASES = [[0.3, -0.8], [-0.3, -0.8]]
ROBOT_LINKS = (0.9, 1.3)
# A grasp box's half size, metres: a few millimetres up to a hand range's half width
GRASP_HALF_SIZE = _in(0.0, 1.0, lo_open=True)


@dataclass
class ObjectSpec:
    """One object: where it starts, which goal it belongs to, the grasp box H_ij of eq. (11)."""

    name: str = ""
    position: list[float] = field(default_factory=list, metadata=COORDINATE)  # required
    goal: str = ""
    grasp_half_size: float = field(default=0.05, metadata=GRASP_HALF_SIZE)


@dataclass
class RandomObjects:
    """§V-D: ``count`` objects uniform in ``region`` from ``seed``; goals assigned round-robin."""

    count: int = field(default=10, metadata=_in(1, MAX_OBJECTS))
    region: list[float] = field(default_factory=lambda: [-0.25, 0.25, -0.25, 0.25],
                                metadata=COORDINATE)
    grasp_half_size: float = field(default=0.05, metadata=GRASP_HALF_SIZE)
    # Objects closer than this (per axis) are drawn again. 0 is the paper's plain uniform draw
    # (points, for planning); physical boxes need at least their size, or they start
    # interpenetrating and the simulation flings them apart.
    min_separation: float = field(default=0.0, metadata=_in(0.0, 1.0))

    def validate(self) -> None:
        _box(self.region, "random_objects.region")
        if self.min_separation > 0:  # how many points that far apart (per axis) fit the region
            fit = [(hi - lo) / self.min_separation for lo, hi in (self.region[:2],
                                                                  self.region[2:])]
            room = math.prod(math.floor(n) + 1 for n in fit) if all(map(math.isfinite, fit)) \
                else math.inf
            if self.count > room:
                raise ScenarioError(f"random_objects: {self.count} objects {self.min_separation} "
                                    f"m apart do not fit in {self.region} (at most {room})")


@dataclass
class SolverSettings:
    """The scenario's ``solver:`` settings (docs/scenarios.md): the backend, the limits, the
    search, the horizons, the closed loop's replans. ``horizon.solve_options`` makes the
    ``solver.SolveOptions`` of one solve from them."""

    backend: str = "highs"  # or "scip", "gurobi", "cplex" where installed (solver.py)
    time_limit_s: float = field(default=30.0, metadata=_in(0.0, 86_400.0, lo_open=True))
    mip_rel_gap: float = field(default=1e-4, metadata=_in(0.0, 1.0))
    threads: int = field(default=1, metadata=_in(1, 64))
    max_horizon: int = field(default=40, metadata=_in(1, MAX_HORIZON))
    # "skeleton": the exact search over which objects and which hand (search.py);
    # "monolithic": the whole step as one MILP, the reference.
    search: str = "skeleton"
    # Skeleton nodes where both hands may hold one object: "auto" only for objects that neither
    # hand can deliver alone, "always" (exact against the monolithic MILP), "never".
    handover: str = "auto"
    # How a step's horizon is chosen (sequential.plan_step): "witness", the no-throw witness
    # first and the horizons below it within one budget per step (skeleton search); "exact",
    # Algorithm 1 as the paper, every horizon from predictT up to the first plan.
    horizons: str = "witness"
    # The second prover of the horizons the search leaves undecided (sequential.py, cpsat.py):
    # "cpsat", OR-Tools' CP-SAT on a sound integer relaxation (the default where OR-Tools is
    # installed), or "none".
    prover: str = field(default_factory=lambda: "cpsat" if ortools_installed() else "none")
    # threads solving the skeleton search's independent programs at once
    workers: int = field(default=2, metadata=_in(1, 64))
    # Closed loop (docs/drake.md, "Lockstep and real time"). Lockstep by default: the
    # simulation waits for every replan, whose plan takes over ``replan_latency_s`` of
    # simulated time later (0 to Δt; unset: 0 in lockstep, Δt in real time, the time the
    # computer needs), planned from where the robot will be then; no search stops by wall time:
    # the run is the same on any machine. ``realtime`` (``simulate --realtime``, the default
    # with ``--meshcat``): a replan may hold the simulation for ``replan_budget_s`` of wall
    # time (default 0.4 Δt), past which the robot follows the plan in force while the search
    # goes on: what the robot does then depends on the machine's speed and load.
    realtime: bool = False
    replan_budget_s: float | None = field(default=None, metadata=_in(0.0, 3600.0))
    replan_latency_s: float | None = field(default=None, metadata=_in(0.0, 3600.0))
    # Lockstep: branch-and-bound nodes a replan's solve of one program may take (HiGHS), where
    # real time has a wall-time limit; reached, the program is undecided, as at a time limit.
    replan_node_limit: int = field(default=2000, metadata=_in(1, 10**9))
    # and programs a replan's skeleton search may solve, over all the horizons it tries
    replan_program_limit: int = field(default=300, metadata=_in(1, 10**9))

    def validate(self) -> None:
        if self.backend not in SOLVER_BACKENDS:
            raise ScenarioError(f"solver.backend: unknown solver {self.backend!r} (one of "
                                f"{', '.join(SOLVER_BACKENDS)})")
        if self.search not in ("skeleton", "monolithic"):
            raise ScenarioError(f"solver.search: expected 'skeleton' or 'monolithic', got "
                                f"{self.search!r}")
        if self.horizons not in ("witness", "exact"):
            raise ScenarioError(f"solver.horizons: expected 'witness' or 'exact', got "
                                f"{self.horizons!r}")
        if self.prover not in ("cpsat", "none"):
            raise ScenarioError(f"solver.prover: expected 'cpsat' or 'none', got {self.prover!r}")
        if self.prover == "cpsat" and not ortools_installed():
            raise ScenarioError("solver.prover: 'cpsat' needs OR-Tools, which is not installed "
                                "here (pip install 'dualarm_mpc[ortools]', or solver.prover: none)")
        if self.handover not in ("auto", "always", "never"):
            raise ScenarioError(f"solver.handover: expected 'auto', 'always' or 'never', got "
                                f"{self.handover!r}")


@dataclass
class Event:
    """An environment change in closed loop: at ``time`` move an object or a goal."""

    time: float = field(default=0.0, metadata=_in(0.0, 1e6))
    kind: str = "move_object"  # or "move_goal"
    target: str = ""  # object name or goal name
    # move_object: new [x, y]
    position: list[float] = field(default_factory=list, metadata=COORDINATE)
    # move_goal: new [xmin, xmax, ymin, ymax]
    box: list[float] = field(default_factory=list, metadata=COORDINATE)

    def validate(self, path: str, task: Task) -> None:
        """``path``: ``events[e]``; the target must be one of ``task``'s objects or goals, and
        the event gives its own kind's field only (the other would be ignored)."""
        unused = {"move_object": ("box", self.box), "move_goal": ("position", self.position)}
        name, value = unused.get(self.kind, ("", None))
        if value:
            raise ScenarioError(f"{path}.{name}: a {self.kind} event has no {name} (move_object "
                                "takes position, move_goal takes box)")
        if self.kind == "move_object":
            if self.target not in {o.name for o in task.objects}:
                raise ScenarioError(f"{path}.target: no object named {self.target!r}")
            _point(self.position, f"{path}.position")
        elif self.kind == "move_goal":
            if self.target not in task.goals:
                raise ScenarioError(f"{path}.target: no goal named {self.target!r}")
            _box(self.box, f"{path}.box")
        else:
            raise ScenarioError(f"{path}.kind: must be 'move_object' or 'move_goal'")


@dataclass
class Robot:
    """The two arms (Table I): Δt, the hands' range and start, the arm bases, the bounds on |v|
    and |u|, eq. (16)'s gap."""

    # A step spans at least five of the simulation's 2 ms steps
    dt: float = field(default=1.0, metadata=_in(0.01, 10.0))
    workspace: list[float] = field(default_factory=lambda: [-0.9, 0.9, 0.0, 0.9],
                                   metadata=COORDINATE)  # hand range
    hand_start: list[list[float]] = field(default_factory=lambda: [[0.1, 0.0], [-0.1, 0.0]],
                                          metadata=COORDINATE)
    # In front of the hand range, not at Table I's (±0.3, 0.3): see docs/drake.md. Each
    # [x, y], with an optional z and yaw (radians) for a robot model of one arm.
    arm_bases: list[list[float]] = field(default_factory=lambda: [[0.3, -0.8], [-0.3, -0.8]],
                                         metadata=COORDINATE)
    # The robot that carries the hands (docs/robots.md): a URDF or SDF file (a path, relative to
    # the scenario file, or a package:// URL); None: our SCARA, models/dual_scara.sdf.
    robot_model: str | None = None
    # The frame that holds objects: one (a one-arm model, loaded at each of arm_bases) or two
    # (one model with both arms); arm 1 = right.
    hand_frames: list[str] = field(default_factory=list)
    # [x, y, z, yaw] of a two-arm model; None: at the origin.
    robot_base: list[float] | None = field(default=None, metadata=COORDINATE)
    # The grasp box of eq. (11) shrunk to this half size (m) in the plan and the gripper: a
    # suction cup or gripper holds a box under the tool, not h_j beside it. None: the paper's
    # grasp box (``simulate`` sets it, docs/scenarios.md, "The on-robot overrides").
    grasp_tolerance: float | None = field(default=None, metadata=GRASP_HALF_SIZE)
    # |v| and |u| per component; every big-M derives from them, so that their ratio to the
    # table's size stays one a MILP solver's tolerances resolve (1 mm/s is no motion here)
    max_speed: float = field(default=0.2, metadata=_in(1e-3, 10.0))
    max_force: float = field(default=0.1, metadata=_in(1e-3, 10.0))
    hand_gap: float = field(default=0.1, metadata=_in(0.0, 2.0))  # eq. (16)

    def validate(self) -> None:
        _box(self.workspace, "workspace")
        for name, points in (("hand_start", self.hand_start), ("arm_bases", self.arm_bases)):
            if len(points) != 2:
                raise ScenarioError(f"{name}: expected two points (arm 1 = right, arm 2 = left)")
        for i, p in enumerate(self.hand_start):
            _point(p, f"hand_start[{i}]")
        for i, p in enumerate(self.arm_bases):
            if not 2 <= len(p) <= (2 if self.robot_model is None else 4):
                raise ScenarioError(f"arm_bases[{i}]: expected [x, y]" + (
                    "" if self.robot_model is None else ", [x, y, z] or [x, y, z, yaw]") +
                    f", got {p!r}")
        xmin, xmax, ymin, ymax = self.workspace
        for i, (x, y) in enumerate(self.hand_start):
            if not (xmin <= x <= xmax and ymin <= y <= ymax):
                raise ScenarioError(
                    f"hand_start[{i}]: {[x, y]} is outside workspace {self.workspace}")
        (x1, _), (x2, _) = self.hand_start
        if x2 + self.hand_gap > x1 + 1e-9:
            raise ScenarioError(
                f"hand_start: eq. (16) needs x_arm2 + hand_gap <= x_arm1 (arm 1 = right), got "
                f"x_arm1 = {x1}, x_arm2 = {x2}, hand_gap = {self.hand_gap}")
        if self.robot_model is None:
            if self.hand_frames or self.robot_base is not None:
                raise ScenarioError("hand_frames, robot_base: given without robot_model (the "
                                    "SCARA's hands are its own)")
            self._check_arms()
        else:
            self._check_model()

    def _check_model(self) -> None:
        """The keys of a robot model; whether its arms reach is the station's to check
        (:func:`dualarm_mpc.sim.reach.check_reach`), with the model loaded."""
        if not self.robot_model.strip():
            raise ScenarioError("robot_model: an empty name (a URDF or SDF path or URL)")
        if not 1 <= len(self.hand_frames) <= 2 or not all(
                isinstance(f, str) and f for f in self.hand_frames):
            raise ScenarioError(f"hand_frames: expected one frame name (a one-arm model) or two "
                                f"(arm 1 = right, arm 2 = left), got {self.hand_frames!r}")
        if len(self.hand_frames) == 1 and self.robot_base is not None:
            raise ScenarioError("robot_base: places a two-arm model; with one hand frame each "
                                "arm stands at its arm_bases entry")
        if self.robot_base is not None and len(self.robot_base) != 4:
            raise ScenarioError(f"robot_base: expected [x, y, z, yaw], got {self.robot_base!r}")

    def _check_arms(self) -> None:
        """The robot model's arms, and a hand range they reach everywhere (the simulation's
        inverse kinematics has no answer beyond)."""
        if not np.allclose(self.arm_bases, ROBOT_ARM_BASES, rtol=0, atol=1e-9):
            raise ScenarioError(f"arm_bases: {self.arm_bases} are not the robot model's "
                                f"{ROBOT_ARM_BASES} (models/dual_scara.sdf)")
        (l1, l2), (xmin, xmax, ymin, ymax) = ROBOT_LINKS, self.workspace
        inner, outer = abs(l1 - l2), l1 + l2
        for i, (bx, by) in enumerate(self.arm_bases):
            far = max(math.hypot(x - bx, y - by) for x in (xmin, xmax) for y in (ymin, ymax))
            near = math.hypot(min(max(bx, xmin), xmax) - bx, min(max(by, ymin), ymax) - by)
            if far > outer or near < inner:
                raise ScenarioError(
                    f"workspace: {self.workspace} is not all within reach of arm {i + 1}, "
                    f"{inner:g} to {outer:g} m from its base {[bx, by]} (models/dual_scara.sdf)")


@dataclass
class Table:
    """The simulated table and boxes (Drake only, but the boxes' size for the planner's
    ``object_clearance``)."""

    friction: float = field(default=0.0, metadata=_in(0.0, 2.0))  # Coulomb μ, table and objects
    # The table's viscous drag on a sliding object, F = −m·v/τ: it slides v·τ, the model's
    # one-step slide when τ = Δt (docs/model.md, "The one-step slide"). None: Coulomb only.
    # The drag is applied once per 2 ms step of the simulation: below 1 ms it diverges (measured,
    # Drake's line search fails); the bound keeps a factor of 10.
    slide_time_constant: float | None = field(default=1.0, metadata=_in(0.01, 1000.0))
    # A box side: the hand holds a box at half its height and travels at TRAVEL_HEIGHT = 0.1 m
    # (systems/interpolator.py), so boxes of 0.2 m are refused by the station; below 1 mm the
    # contact no longer holds them (measured: 0.1 mm boxes are never delivered).
    object_size: float = field(default=0.05, metadata=_in(0.01, 0.2, hi_open=True))


@dataclass
class Task:
    """What to deliver where (goals, objects), under which rules, in sequential steps of
    (m_o, n_o), and how the planner aims and weighs its plans."""

    goals: dict[str, list[float]] = field(default_factory=dict, metadata=COORDINATE)
    objects: list[ObjectSpec] = field(default_factory=list)
    random_objects: RandomObjects | None = None
    seed: int = field(default=0, metadata=_in(0, 2**32 - 1))
    rule: int = 2
    m_o: int = field(default=2, metadata=_in(1, MAX_STEP_DELIVERIES))  # delivered per step (eq. 13)
    n_o: int = field(default=6, metadata=_in(1, MAX_OBJECTS))  # considered per step
    delivery: str = "reach"  # "reach" (paper, ◇θ) or "rest" (in the goal and at rest at T)
    task_form: str = "counting"  # "counting" (Σ ev_j ≥ m_o) or "subsets" (eq. 13 literally)
    rules: list[str] = field(default_factory=list)  # extra LTL rules, text syntax
    # optional ‖v_hand‖₁ penalty next to cost (17), whose terms are metres
    state_weight: float = field(default=0.0, metadata=_in(0.0, 100.0))
    pruning: bool = True
    # the planner aims this far inside each goal box (closed loop)
    goal_margin: float = field(default=0.0, metadata=_in(0.0, 1.0))
    goal_slots: bool = False  # aim each object at its own column of its goal (closed loop)
    # Objects have extent: one held or sliding keeps this gap (m) between its box
    # (``object_size``) and every other's (docs/formulation.md, (C1)–(C3)); None: points, as in
    # the paper (``simulate`` sets it, docs/scenarios.md, "The on-robot overrides")
    object_clearance: float | None = field(default=None, metadata=_in(0.0, 1.0))

    def validate(self) -> None:
        if self.random_objects is not None:
            self.random_objects.validate()
        if not self.goals:
            raise ScenarioError("goals: at least one goal region is needed")
        for name, box in self.goals.items():
            _box(box, f"goals.{name}")
            if 2 * self.goal_margin >= min(box[1] - box[0], box[3] - box[2]):
                raise ScenarioError(f"goal_margin: {self.goal_margin} leaves nothing of "
                                    f"goals.{name}")
        if not self.objects:
            raise ScenarioError("objects: no objects (give objects or random_objects)")
        if len(self.objects) > MAX_OBJECTS:
            raise ScenarioError(f"objects: {len(self.objects):,} objects, at most {MAX_OBJECTS} "
                                "(docs/scenarios.md, Caps)")
        names = set()
        for j, o in enumerate(self.objects):
            if not o.position:
                raise ScenarioError(f"objects[{j}].position: missing (give [x, y])")
            _point(o.position, f"objects[{j}].position")
            if o.goal not in self.goals:
                raise ScenarioError(f"objects[{j}].goal: {o.goal!r} is not a goal (goals: "
                                    f"{', '.join(self.goals)})")
            if not o.name or o.name in names:
                raise ScenarioError(f"objects[{j}].name: missing or repeated name {o.name!r}")
            names.add(o.name)
        if self.goal_slots:
            for name, box in self.goals.items():
                count = sum(o.goal == name for o in self.objects)
                if count and (box[1] - box[0]) / count <= 2 * self.goal_margin:
                    raise ScenarioError(f"goal_slots: goals.{name} is too narrow for {count} "
                                        f"slots with goal_margin {self.goal_margin}")
        if self.rule not in (1, 2):
            raise ScenarioError(f"rule: must be 1 (no-throw) or 2 (no-juggle, no-swap), got "
                                f"{self.rule!r}")
        if self.delivery not in ("reach", "rest"):
            raise ScenarioError(f"delivery: must be 'reach' or 'rest', got {self.delivery!r}")
        if self.task_form not in ("counting", "subsets"):
            raise ScenarioError(f"task_form: must be 'counting' or 'subsets', got "
                                f"{self.task_form!r}")
        if not 1 <= self.m_o <= self.n_o:
            raise ScenarioError(f"m_o: need 1 <= m_o <= n_o, got m_o={self.m_o}, n_o={self.n_o}")
        subsets = math.comb(min(self.n_o, len(self.objects)), self.m_o)
        if self.task_form == "subsets" and subsets > MAX_TASK_SUBSETS:
            raise ScenarioError(
                f"task_form: subsets makes φ_task a disjunction of {subsets:,} subsets (m_o = "
                f"{self.m_o} of n_o = {self.n_o}), more than {MAX_TASK_SUBSETS:,}; use "
                "task_form: counting (the same task) or a smaller n_o")
        if subsets * 2**self.m_o > MAX_ROUTE_CHOICES:
            raise ScenarioError(
                f"n_o: the route bound weighs {subsets * 2**self.m_o:,} choices of the objects "
                f"delivered and their hands (C({min(self.n_o, len(self.objects))}, {self.m_o})"
                f"·2^{self.m_o}), more than {MAX_ROUTE_CHOICES:,}; use a smaller n_o or m_o")
        for n, text in enumerate(self.rules):
            try:
                parse(text)
            except LTLSyntaxError as err:
                raise ScenarioError(f"rules[{n}]: {err}") from err


@dataclass
class Scenario:
    """Everything the planner and the simulation need; units are metres, seconds and Δt steps.
    The YAML names each field flat (``max_speed``, not ``robot.max_speed``):
    :data:`~dualarm_mpc.model.scenario.YAML_FIELDS`."""

    name: str = "scenario"
    robot: Robot = field(default_factory=Robot)
    table: Table = field(default_factory=Table)
    task: Task = field(default_factory=Task)
    solver: SolverSettings = field(default_factory=SolverSettings)
    events: list[Event] = field(default_factory=list)

    @property
    def n_objects(self) -> int:
        return len(self.task.objects)

    def validate(self) -> None:
        """Check values that types alone cannot; each error names its YAML field."""
        self.check_ranges()
        self.robot.validate()
        self.task.validate()
        self.solver.validate()
        latency = self.solver.replan_latency_s
        if latency is not None and latency > self.robot.dt:
            raise ScenarioError(f"solver.replan_latency_s: at most robot.dt ({self.robot.dt} s), "
                                f"got {latency}")
        for e, event in enumerate(self.events):
            event.validate(f"events[{e}]", self.task)
        self._check_reach()

    @property
    def replan_latency(self) -> float:
        """Simulated seconds from a replan to its plan in force: ``solver.replan_latency_s``,
        unset 0 in lockstep and Δt in real time."""
        latency = self.solver.replan_latency_s
        if latency is None:
            return self.robot.dt if self.solver.realtime else 0.0
        return latency

    def check_ranges(self) -> None:
        """Every number in its field's :class:`~dualarm_mpc.model.scenario.Range` and every text at
        most MAX_TEXT_CHARS long (before anything computes with them)."""
        for key, path in YAML_FIELDS.items():
            owner, name = _owner(self, path)
            rng = _fields(type(owner))[name].metadata.get("range")
            _check_range(getattr(owner, name), rng, key)

    def _check_reach(self) -> None:
        """Objects no hand can move: off the table (beyond the hand range widened by the grasp
        box, eq. 11, and not in their goal), or farther from their goal than an object can travel
        in one horizon (a held or sliding object moves at most max_speed·dt per step and axis)."""
        robot, task, max_horizon = self.robot, self.task, self.solver.max_horizon
        xmin, xmax, ymin, ymax = robot.workspace
        step = robot.max_speed * robot.dt
        drawn = "" if task.random_objects is None else " (drawn from random_objects.region)"
        by_name = {o.name: o for o in task.objects}
        # (field, object, position, how it got there, whether its start): an object an event
        # moves must stay where a hand can fetch it, as at its start
        places = [(f"objects[{j}].position", o, o.position, f"at {o.position}{drawn}", True)
                  for j, o in enumerate(task.objects)]
        places += [(f"events[{e}].position", by_name[event.target], event.position,
                    f"moved to {event.position} at t = {event.time:g} s", False)
                   for e, event in enumerate(self.events) if event.kind == "move_object"]
        for path, o, (x, y), how, start in places:
            half = o.grasp_half_size
            gx0, gx1, gy0, gy1 = task.goals[o.goal]
            away = max(gx0 - x, x - gx1, gy0 - y, y - gy1, 0.0)  # per axis, as the speed bound
            reach = xmin - half <= x <= xmax + half and ymin - half <= y <= ymax + half
            if away > 0 and not reach:
                raise ScenarioError(
                    f"{path}: {o.name} {how} lies beyond the hands' reach (workspace "
                    f"{robot.workspace} widened by its grasp_half_size {half}) and outside its "
                    f"goal {o.goal}")
            if start and away > step * max_horizon + 1e-9:
                raise ScenarioError(
                    f"dt: with dt = {robot.dt} s and max_speed = {robot.max_speed} m/s an object "
                    f"moves at most {step:.3g} m per step, {step * max_horizon:.3g} m in "
                    f"solver.max_horizon = {max_horizon} steps, but {o.name} is {away:.3g} m "
                    f"from its goal {o.goal}: raise dt, max_speed or solver.max_horizon")


#: The scenario file is one flat mapping: each key and the field it sets. The loader reads the
#: file through this table only, so the file format and the error paths are the YAML keys.
YAML_FIELDS = {
    "name": "name",
    "dt": "robot.dt",
    "workspace": "robot.workspace",
    "hand_start": "robot.hand_start",
    "arm_bases": "robot.arm_bases",
    "max_speed": "robot.max_speed",
    "max_force": "robot.max_force",
    "hand_gap": "robot.hand_gap",
    "robot_model": "robot.robot_model",
    "hand_frames": "robot.hand_frames",
    "robot_base": "robot.robot_base",
    "grasp_tolerance": "robot.grasp_tolerance",
    "table_friction": "table.friction",
    "slide_time_constant": "table.slide_time_constant",
    "object_size": "table.object_size",
    "goals": "task.goals",
    "objects": "task.objects",
    "random_objects": "task.random_objects",
    "seed": "task.seed",
    "rule": "task.rule",
    "m_o": "task.m_o",
    "n_o": "task.n_o",
    "delivery": "task.delivery",
    "task_form": "task.task_form",
    "rules": "task.rules",
    "state_weight": "task.state_weight",
    "pruning": "task.pruning",
    "goal_margin": "task.goal_margin",
    "goal_slots": "task.goal_slots",
    "object_clearance": "task.object_clearance",
    "solver": "solver",
    "events": "events",
}


# --- loading -----------------------------------------------------------------------------------


def _convert(value, hint, path: str):
    """Convert plain YAML data to ``hint``, naming ``path`` in any error."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return None if value is None else _convert(value, args[0], path)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ScenarioError(f"{path}: expected a mapping, got {_show(value)}")
        return _build(hint, value, path)
    if origin is list:
        (item,) = typing.get_args(hint)
        if not isinstance(value, list):
            raise ScenarioError(f"{path}: expected a list, got {_show(value)}")
        return [_convert(v, item, f"{path}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        _, item = typing.get_args(hint)
        if not isinstance(value, dict):
            raise ScenarioError(f"{path}: expected a mapping, got {_show(value)}")
        return {str(k): _convert(v, item, f"{path}.{k}") for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ScenarioError(f"{path}: expected a number, got {_show(value)}")
        try:
            number = float(value)
        except OverflowError:  # an integer of more than 308 digits
            number = math.inf
        if not math.isfinite(number):
            raise ScenarioError(f"{path}: expected a finite number, got "
                                f"{_show(yamlcore.written(value))}")
        return number
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ScenarioError(f"{path}: expected an integer, got {_show(value)}")
        return int(value)
    if hint is bool:
        if not isinstance(value, bool):
            raise ScenarioError(f"{path}: expected true or false, got {_show(value)}")
        return value
    if hint is str:  # names and rules: a number as written (1e3, 010), never true or null
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            quote = " (quote it to mean the text)" if value is None or isinstance(value, bool) \
                else ""
            raise ScenarioError(f"{path}: expected text, got {_show(value)}{quote}")
        return str(yamlcore.written(value))
    raise TypeError(f"unsupported schema type {hint!r} at {path}")


def _update(current, value, hint, path: str):
    """``value`` (plain YAML data) as ``hint``, over ``current``: a mapping updates a dataclass
    field by field and a mapping key by key (``goals: {red: [...]}`` moves red and keeps the other
    goals, as Drake's ``yaml_load_typed`` does with retain_map_defaults; an empty mapping clears
    it); a mapping of indices updates those elements of a list. Anything else replaces."""
    if isinstance(value, dict) and current is not None:
        if dataclasses.is_dataclass(current):
            return _build(type(current), value, path, current)
        if isinstance(current, dict) and value:
            _, item = typing.get_args(hint)
            return {**current, **{str(k): _update(current.get(str(k)), v, item, f"{path}.{k}")
                                  for k, v in value.items()}}
        if isinstance(current, list) and value and all(map(_is_index, value)):
            (item,) = typing.get_args(hint)
            out = list(current)
            for i, v in value.items():
                i = _check_index(i, out, path)
                out[i] = _update(out[i], v, item, f"{path}[{i}]")
            return out
    return _convert(value, hint, path)


def _build(cls, data: dict, path: str, base=None):
    hints = _hints(cls)
    _known(data, hints, f"{path}.")
    obj = base if base is not None else cls()
    for key, value in data.items():
        setattr(obj, key, _update(getattr(obj, key), value, hints[key], f"{path}.{key}"))
    return obj


@functools.cache
def _hints(cls) -> dict:
    """The field types of dataclass ``cls`` (once: a thousand objects would each ask)."""
    return typing.get_type_hints(cls)


@functools.cache
def _fields(cls) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls)}


def _owner(scenario: Scenario, path: str) -> tuple[object, str]:
    """The group of ``scenario`` holding a YAML_FIELDS path, and the field's name in it."""
    *group, name = path.split(".")
    return (getattr(scenario, group[0]) if group else scenario), name


def _build_scenario(data: dict, base: Scenario | None = None) -> Scenario:
    """``data``, a scenario file's flat mapping, set into ``base``'s groups (YAML_FIELDS)."""
    _known(data, YAML_FIELDS, "")
    scenario = base if base is not None else Scenario()
    for key, value in data.items():
        owner, name = _owner(scenario, YAML_FIELDS[key])
        setattr(owner, name, _update(getattr(owner, name), value, _hints(type(owner))[name], key))
    return scenario


def _check_range(value, rng: Range | None, path: str) -> None:
    """``value`` (a number, or a list, mapping or dataclass of them) in its range."""
    if dataclasses.is_dataclass(value):
        for name, f in _fields(type(value)).items():
            _check_range(getattr(value, name), f.metadata.get("range"), f"{path}.{name}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_range(v, rng, f"{path}[{i}]")
    elif isinstance(value, dict):
        for k, v in value.items():
            _check_range(k, None, f"{path} key {_brief(k)}")
            _check_range(v, rng, f"{path}.{k}")
    elif isinstance(value, str):
        if len(value) > MAX_TEXT_CHARS:
            raise ScenarioError(f"{path}: {len(value):,} characters, at most {MAX_TEXT_CHARS:,}")
    elif rng is not None and value is not None:
        rng.check(value, path)


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _known(data: dict, names, prefix: str) -> None:
    unknown = sorted(str(k) for k in set(data) - set(names))
    if unknown:
        known = ", ".join(sorted(names))
        raise ScenarioError(f"{prefix}{_brief(unknown[0])}: unknown field (known: {known})")


def _brief(text: str) -> str:
    """``text`` for a message, its middle cut if long."""
    return text if len(text) <= 60 else f"{text[:28]}...{text[-28:]}"


_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 60


def _show(value) -> str:
    """``repr(value)`` for a message, shortened if long."""
    return _SHORT.repr(yamlcore.written(value))


# A key of an override that names a field by its path: solver.time_limit_s, objects[0].position
_PATH = re.compile(r"[A-Za-z_]\w*(?:\.[^.\[\]]+|\[[0-9]+\])+")
_STEP = re.compile(r"\.([^.\[\]]+)|\[([0-9]+)\]")


def _is_index(key) -> bool:
    """A key that picks a list element: ``[3]`` of a path, or a key ``3:`` (keys are text)."""
    return isinstance(key, int) and not isinstance(key, bool) or \
        isinstance(key, str) and key.isascii() and key.isdecimal()


def _check_index(i: int | str, items: list, path: str) -> int:
    if not 0 <= int(i) < len(items):
        raise ScenarioError(f"{path}[{i}]: no such element ({path} has {len(items)})")
    return int(i)


def _paths(data: dict) -> dict:
    """``data`` with its path keys (``solver.time_limit_s``, ``objects[0].position``) made
    nested mappings, an index becoming a mapping ``{index: value}``; later keys win."""
    out: dict = {}
    for key, value in copy.deepcopy(data).items():
        if isinstance(key, str) and ("." in key or "[" in key):
            if not _PATH.fullmatch(key):
                raise ScenarioError(f"{key}: not a field path (such as solver.time_limit_s or "
                                    f"objects[0].position)")
            head = re.match(r"\w+", key)[0]
            for name, index in reversed(_STEP.findall(key, len(head))):
                value = {name or int(index): value}
            key = head
        merge_overrides(out, {key: value})
    return out


def _yaml(text: str, where: str, empty: str) -> dict:
    """The flat mapping of fields in ``text``; none at all is an error saying ``empty`` (a file or
    an override that sets nothing would be read as the defaults, silently)."""
    try:
        data = yamlcore.load(text, where)
    except yamlcore.YAMLInputError as err:
        raise ScenarioError(str(err)) from None
    if data is None or data == {}:
        raise ScenarioError(f"{where}: {empty}")
    if not isinstance(data, dict):
        raise ScenarioError(f"{where}: expected a mapping of scenario fields, got {_show(data)}")
    return _paths(data)


def parse_override(text: str, where: str = "override") -> dict:
    """A YAML mapping of fields (or field paths) to values, e.g. ``solver.time_limit_s: 5``."""
    return _yaml(text, where, "sets nothing (give 'field: value', e.g. 'rule: 1')")


def scenario_path(name_or_path: str) -> Path:
    """A built-in scenario name (``table1_vc``, ``table1_vd``) or a path to a YAML file."""
    if name_or_path in BUILTIN:
        return Path(str(resources.files("dualarm_mpc.scenarios") / f"{name_or_path}.yaml"))
    path = Path(name_or_path)
    if not path.is_file():
        raise ScenarioError(
            f"scenario: {name_or_path!r} is neither a file nor one of {', '.join(BUILTIN)}"
        )
    return path


# On the robot, "delivered" means at rest in the goal; the planner aims a little inside it, each
# object at its own slot, so that later throws do not knock earlier ones (measured on §V-C: without
# slots one object in ten was knocked short of its goal, beyond reach); and objects have extent:
# one carried or sliding keeps 1 cm from every other (docs/formulation.md, (C1)-(C3); without,
# the boxes of `make demo` touched in 4 pairs, a dragged one shoving another 8 cm). 1 cm is what
# the slots leave between neighbours (2·goal_margin − object_size). The hand holds a box with its
# tool near the middle of its top face: the grasp box shrinks to 0.13 of the box, so that a held
# box's centre stays within 1 cm of the tool (0.0065·√2 m on a 5 cm box). Lengths
# are in object sizes, the 5 cm box of Table II's scenes: a robot of smaller reach carries the
# same scene scaled down (docs/robots.md).
ON_ROBOT = {"delivery": "rest", "goal_slots": True}
ON_ROBOT_SIZES = {"goal_margin": 0.6, "object_clearance": 0.2, "grasp_tolerance": 0.13}


def on_robot_overrides(scenario: Scenario) -> dict:
    """The overrides that make ``scenario`` fit for the robot (what ``load_scenario(...,
    on_robot=True)`` applies): ``ON_ROBOT``, ``ON_ROBOT_SIZES`` times the object size, and
    random objects drawn at least a box apart (plus 40 % of one), since physical boxes cannot
    overlap."""
    size = scenario.table.object_size
    extra = {key: round(factor * size, 9) for key, factor in ON_ROBOT_SIZES.items()}
    if scenario.task.random_objects is not None:
        extra["random_objects"] = {"min_separation": round(1.4 * size, 9)}
    return {**ON_ROBOT, **extra}


def load_scenario(name_or_path: str, overrides: dict | str | Iterable[str | dict] | None = None, *,
                  on_robot: bool = False) -> Scenario:
    """Load a scenario file (a path, or ``table1_vc`` / ``table1_vd``), apply ``overrides``, then
    validate it. ``overrides``: a mapping, YAML text, or several YAML texts applied in order (as
    ``--set`` flags are). ``on_robot``: first the overrides that fit the task to the robot
    (:func:`on_robot_overrides`, what ``simulate`` uses); ``overrides`` come after them and win."""
    path = scenario_path(name_or_path)
    try:
        with path.open(encoding="utf-8") as file:
            text = file.read(yamlcore.MAX_CHARS + 1)  # a longer file is refused unread
    except UnicodeDecodeError as err:
        raise ScenarioError(f"{path}: not UTF-8 text (byte {err.start} is "
                            f"{err.object[err.start]:#04x})") from err
    except OSError as err:
        raise ScenarioError(f"{path}: cannot read it: {err.strerror}") from err
    data = _yaml(text, str(path), "the file is empty (blank or comments only): a scenario "
                 "needs at least goals and objects (docs/scenarios.md)")
    model = data.get("robot_model")
    if isinstance(model, str) and model and "://" not in model:  # relative to the file
        data["robot_model"] = str((path.parent / model).resolve())
    _one_source_of_objects(data, drawn=False, listed=0)
    base = _build_scenario(data)
    if not on_robot and (overrides is None or isinstance(overrides, dict | str)):
        return apply_overrides(base, overrides)
    merged = on_robot_overrides(base) if on_robot else {}
    texts = [overrides] if isinstance(overrides, dict | str) else list(overrides or [])
    for k, extra in enumerate(texts):
        if isinstance(extra, str):
            extra = parse_override(extra, f"override {k + 1} ({extra!r})")
        elif not isinstance(extra, dict):
            raise ScenarioError(f"override {k + 1}: expected a mapping or YAML text, got "
                                f"{_show(extra)}")
        merge_overrides(merged, _paths(extra))
    return apply_overrides(base, merged)


def apply_overrides(scenario: Scenario, overrides: dict | str | None) -> Scenario:
    """A copy of ``scenario`` with ``overrides`` applied, objects resolved, all checked."""
    scenario = copy.deepcopy(scenario)
    overrides = parse_override(overrides) if isinstance(overrides, str) else \
        _paths(overrides or {})
    task = scenario.task
    if overrides:
        _one_source_of_objects(overrides, drawn=task.random_objects is not None,
                               listed=len(task.objects))
        _build_scenario(overrides, scenario)
    scenario.check_ranges()
    if task.random_objects is not None and task.goals:
        # the objects follow from (random_objects, seed); with no goals, validate says so
        task.random_objects.validate()
        task.objects = random_objects(task.random_objects, list(task.goals), task.seed)
    tolerance = scenario.robot.grasp_tolerance
    if tolerance is not None:
        for o in task.objects:
            o.grasp_half_size = min(o.grasp_half_size, tolerance)
    scenario.validate()
    return scenario


def _one_source_of_objects(data: dict, drawn: bool, listed: int) -> None:
    """Objects given where random objects are drawn would be replaced by the draw, and so would
    the ``listed`` objects if ``data`` starts a draw; ``drawn``, ``listed``: before ``data``."""
    if data.get("random_objects") is not None and not drawn and listed and \
            data.get("objects") != []:
        raise ScenarioError(f"random_objects: given while the scenario lists {listed} objects, "
                            "which the draw would replace; give one of the two (objects: [] "
                            "with random_objects to draw instead)")
    if "random_objects" in data:
        drawn = data["random_objects"] is not None
    if data.get("objects") and drawn:
        raise ScenarioError("objects: given while random_objects draws the objects, which would "
                            "replace them; give one of the two (random_objects: null to list "
                            "objects)")


def merge_overrides(into: dict, extra: dict, path: str = "") -> None:
    """Merge ``extra`` into ``into`` in place: mappings key by key, a mapping of indices into a
    list element by element (what ``objects[0].goal`` paths become), anything else replaced."""
    for key, value in extra.items():
        into[key] = _merged(into.get(key), value, f"{path}.{key}" if path else str(key))


def _merged(current, value, path: str):
    if isinstance(value, dict) and isinstance(current, dict):
        merge_overrides(current, value, path)
        return current
    if isinstance(value, dict) and isinstance(current, list) and value and \
            all(map(_is_index, value)):
        for i, v in value.items():
            _check_index(i, current, path)
            current[i] = _merged(current[i], v, f"{path}[{i}]")
        return current
    return value


def random_objects(spec: RandomObjects, goal_names: list[str], seed: int) -> list[ObjectSpec]:
    """§V-D: objects uniform in ``spec.region``; goal colours assigned round-robin
    (docs/scenarios.md)."""
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = spec.region
    if spec.min_separation <= 0:
        xy = rng.uniform([xmin, ymin], [xmax, ymax], size=(spec.count, 2))
    else:
        xy = np.empty((0, 2))
        for _ in range(1000 * spec.count):
            p = rng.uniform([xmin, ymin], [xmax, ymax])
            if len(xy) == 0 or np.abs(xy - p).max(axis=1).min() >= spec.min_separation:
                xy = np.vstack([xy, p])
                if len(xy) == spec.count:
                    break
        else:
            raise ScenarioError(f"random_objects: cannot place {spec.count} objects "
                                f"{spec.min_separation} m apart in {spec.region}")
    return [
        ObjectSpec(
            name=f"object{j + 1}",
            position=[round(float(x), 4), round(float(y), 4)],
            goal=goal_names[j % len(goal_names)],
            grasp_half_size=spec.grasp_half_size,
        )
        for j, (x, y) in enumerate(xy)
    ]


def seconds_problem(value) -> str | None:
    """What is wrong with ``value`` as a span of seconds (a time limit, a duration), or None:
    the one check of the command line's ``--time-limit`` and ``--duration`` and of the library's
    ``MpcPlanner(time_limit_s=)`` and ``simulate(duration=)``, in the same words."""
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not (math.isfinite(value) and value > 0):
        return f"must be a positive number of seconds, got {value}"
    return None


def check_goals(goals: dict, task: Task, where: str) -> None:
    """``goals`` (name → box, e.g. a goals port's value) gives every goal an object of ``task``
    is bound for a box [xmin, xmax, ymin, ymax] that is not empty: each error names ``where``
    and the field."""
    if not isinstance(goals, dict):
        raise ScenarioError(f"{where}: expected a mapping of goal names to boxes, got "
                            f"{_show(goals)}")
    needed = [name for name in task.goals if any(o.goal == name for o in task.objects)]
    for name in needed:
        if name not in goals:
            raise ScenarioError(f"{where}: goals.{name} is missing (the objects' goals: "
                                f"{', '.join(needed)})")
        _box(list(goals[name]), f"{where}: goals.{name}")


def _box(value: list[float], path: str) -> None:
    if len(value) != 4:
        raise ScenarioError(f"{path}: expected [xmin, xmax, ymin, ymax], got {value!r}")
    if not (value[0] < value[1] and value[2] < value[3]):
        raise ScenarioError(f"{path}: empty box {value!r} (need xmin < xmax and ymin < ymax)")
    if not math.isfinite(value[1] - value[0] + value[3] - value[2]):
        raise ScenarioError(f"{path}: a box too large to measure {value!r}")


def _point(value: list[float], path: str) -> None:
    if len(value) != 2:
        raise ScenarioError(f"{path}: expected [x, y], got {value!r}")
