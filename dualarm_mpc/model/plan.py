"""Plan: the planner's output — a trajectory of the MLD system plus how each sequential step went.

Array conventions (index order is the paper's): arm ``i`` = 0 is arm 1 (right), ``i`` = 1 is arm 2
(left); object ``j`` follows the scenario's object list; step ``k`` = 0..K.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from dualarm_mpc.base import outputs


def relative_gap(cost: float, bound: float) -> float:
    """(cost − bound) / cost, a certificate's gap: 0 for a cost of 0."""
    return max(0.0, (cost - bound) / cost) if cost > 0 else 0.0


@dataclass(frozen=True)
class Trajectory:
    """States k = 0..K, inputs k = 0..K-1, of the MLD system (eqs. 1, 8)."""

    hand_pos: np.ndarray  # (K+1, 2, 2)
    hand_vel: np.ndarray  # (K+1, 2, 2)
    force: np.ndarray  # (K, 2, 2)
    object_pos: np.ndarray  # (K+1, N, 2)
    object_vel: np.ndarray  # (K+1, N, 2)
    grasp: np.ndarray  # (K+1, 2, N) of 0/1: η_ij(k)

    @property
    def steps(self) -> int:
        """K, the number of transitions."""
        return len(self.force)

    @staticmethod
    def still(state) -> Trajectory:
        """The trajectory of no step: ``state`` (an ``mld.State``) alone."""
        return Trajectory(state.hand_pos[None], state.hand_vel[None],
                          np.zeros((0, *state.hand_pos.shape)), state.object_pos[None],
                          state.object_vel[None], state.grasp[None])

    def then(self, other: Trajectory) -> Trajectory:
        """This trajectory followed by ``other``, whose step 0 repeats this one's last step."""
        return Trajectory(
            *(
                np.concatenate([a, b[1:]]) if name != "force" else np.concatenate([a, b])
                for name, a, b in zip(FIELDS, self.arrays(), other.arrays(), strict=True)
            )
        )

    def arrays(self) -> tuple[np.ndarray, ...]:
        return tuple(getattr(self, name) for name in FIELDS)

    def to_json(self) -> dict:
        return {
            name: (a.astype(int) if name == "grasp" else np.round(a, 9)).tolist()
            for name, a in zip(FIELDS, self.arrays(), strict=True)
        }

    @staticmethod
    def from_json(data: dict) -> Trajectory:
        n = len(data["object_pos"][0])
        arrays = []
        for name in FIELDS:
            a = np.asarray(data[name], dtype=int if name == "grasp" else float)
            if a.size == 0:  # an empty list loses its trailing dimensions
                a = a.reshape((0, 2, n) if name == "grasp" else (0, 2, 2))
            arrays.append(a)
        return Trajectory(*arrays)


FIELDS = ("hand_pos", "hand_vel", "force", "object_pos", "object_vel", "grasp")


@dataclass(frozen=True)
class Segment:
    """One sequential step of Algorithm 1."""

    objects: list[int]  # scenario indices of the n_o objects in the program
    delivered: list[int]  # the ones at rest in their goal at the end of the step
    horizon: int
    status: str
    solve_time_s: float  # wall time of the whole step: every horizon, build and solve
    cost: float
    binaries: int = 0
    gap: float = 0.0
    cpu_time_s: float = 0.0  # CPU time of the step summed over every worker thread
    # Every shorter horizon from predictT was proven to have no plan; with status "optimal",
    # the step's plan is then proven optimal at a proven-minimal horizon.
    horizon_proven_minimal: bool = False
    witness_cost: float | None = None  # the no-throw witness's (sequential.witness), if any
    witness_horizon: int | None = None
    # the shorter horizons proven to have no plan by the second prover (solver.prover: cpsat);
    # those left undecided (neither proven nor given a plan in time)
    horizons_proven_by_cpsat: list[int] = field(default_factory=list)
    horizons_undecided: list[int] = field(default_factory=list)
    # [horizon, cost]: a shorter horizon's plan the step passed over, its witness being cheaper
    shorter_plan: list | None = None
    # A proven lower bound of the cost (17) of every plan of the step at its horizon: the
    # certificate beside ``cost`` and ``gap`` (0, trivially, in files written before it)
    bound: float = 0.0
    # The skeleton search's work on the step's horizon, where a search ran
    # (``skeleton.SearchStats``): nodes expanded, nodes pruned, seconds in leaf programs
    search_stats: dict | None = None
    # A whole-task step joined from this many sequential steps (``Plan.as_one_step``: the
    # first plan of ``--mo all``), which claims nothing beyond being a plan unless the search
    # reached its horizon from it and bettered nothing (then the search's certificate); None:
    # searched
    sequential_steps: int | None = None
    # [m_o, n_o] of the sequential transportation those steps are (``task.FIRST_PASS``, or
    # ``task.LARGER_STEPS`` where that plan was shorter; n_o at most the objects); None: not
    # joined, or a file before it
    sequential_row: list[int] | None = None
    # A whole-task step whose plan is the route-guided program's first (planning/guided.py):
    # shorter than sequential transportation's, its cost unproven (as above)
    guided: bool = False
    # A whole-task step whose plan is the one above (joined, or route-guided) with this many
    # steps taken out by re-timing its hands (planning/shorten.py); its cost unproven (as above)
    shortened: int = 0

    def to_json(self) -> dict:
        """The step as an entry of the plan file's ``segments`` (docs/formats.md)."""
        return {
            "objects": self.objects,
            "delivered": self.delivered,
            "horizon": self.horizon,
            "status": self.status,
            "solve_time_s": round(self.solve_time_s, 4),
            "cost": round(self.cost, 9),
            "binaries": self.binaries,
            "gap": self.gap,
            "cpu_time_s": round(self.cpu_time_s, 4),
            "horizon_proven_minimal": self.horizon_proven_minimal,
            "proven_optimal": self.proven_optimal,
            "witness_cost": self.witness_cost,
            "witness_horizon": self.witness_horizon,
            "horizons_proven_by_cpsat": self.horizons_proven_by_cpsat,
            "horizons_undecided": self.horizons_undecided,
            "shorter_plan": None if self.shorter_plan is None else
            [self.shorter_plan[0], round(self.shorter_plan[1], 9)],
            "bound": round(self.bound, 9),
            "search_stats": self.search_stats,
            "sequential_steps": self.sequential_steps,
            "sequential_row": self.sequential_row,
            "guided": self.guided,
            "shortened": self.shortened,
        }

    @property
    def proven_optimal(self) -> bool:
        """The plan is proven optimal at its horizon."""
        return self.status == "optimal"

    @staticmethod
    def from_json(data: dict) -> Segment:
        """:meth:`to_json` read back; a gap without a bound is written null (JSON has no
        Infinity: ``outputs.json_text``)."""
        gap = data.get("gap", 0.0)
        data = {k: v for k, v in data.items() if k != "proven_optimal"}  # derived
        return Segment(**{**data, "gap": math.inf if gap is None else gap})


@dataclass(frozen=True)
class Plan:
    """The whole task: sequential steps joined without repeating the joining step."""

    dt: float
    rule: int
    delivery: str
    goals: dict[str, list[float]]
    objects: list[dict]  # {"name", "goal", "grasp_half_size"}, index j
    workspace: list[float]
    trajectory: Trajectory
    delivered_step: list[int | None]
    segments: list[Segment] = field(default_factory=list)
    verified: bool = False
    search: str = "skeleton"  # how each step was solved: "skeleton" or "monolithic"
    # The steps completed before an interrupt or an error: not every object is delivered.
    partial: bool = False
    # Wall seconds from the start of planning until a complete plan delivering every object
    # existed and passed verification (``task.plan``); None where none did
    first_plan_s: float | None = None
    # Wall seconds of searches this plan's steps did not take: of the anytime plan's other pass
    # (``task.plan``), the one whose plan was not kept
    unused_solve_time_s: float = 0.0

    @property
    def total_cost(self) -> float:
        return float(sum(s.cost for s in self.segments))

    @property
    def makespan(self) -> int:
        """The plan's length in steps of Δt: the horizons of its steps added up."""
        return int(sum(s.horizon for s in self.segments))

    def as_one_step(self, row: tuple[int, int] | None = None) -> Plan:
        """This complete plan as one step over every object: the whole task's plan
        (``--mo all``) that sequential transportation gives, at ``row`` = (m_o, n_o). Its
        steps' certificates hold for the steps only, so the step claims nothing beyond being a
        plan: bound 0, status feasible, every shorter horizon undecided."""
        steps = self.segments
        stats: dict = {}
        for s in steps:
            for key, value in (s.search_stats or {}).items():
                stats[key] = round(stats.get(key, 0) + value, 4)
        cost = self.total_cost
        one = Segment(
            objects=sorted({j for s in steps for j in s.objects}),
            delivered=sorted({j for s in steps for j in s.delivered}), horizon=self.makespan,
            status="feasible" if cost > 0 else "optimal",
            solve_time_s=float(sum(s.solve_time_s for s in steps)), cost=cost,
            binaries=max((s.binaries for s in steps), default=0),
            gap=1.0 if cost > 0 else 0.0, cpu_time_s=self.total_cpu_time_s,
            horizons_undecided=list(range(1, self.makespan)),
            search_stats=stats or None, sequential_steps=len(steps),
            sequential_row=None if row is None else list(row))
        return replace(self, segments=[one])

    @property
    def total_bound(self) -> float:
        """The steps' proven lower bounds summed: no plan of the same steps, each from the
        state it started in and at its horizon, costs less. Of a whole-task plan (one step,
        ``--mo all``) it bounds every plan of the task at that horizon."""
        return float(sum(s.bound for s in self.segments))

    @property
    def gap(self) -> float:
        """(total cost − total bound) / total cost: 0 where every step is proven optimal."""
        return relative_gap(self.total_cost, self.total_bound)

    @property
    def horizon_proven_minimal(self) -> bool:
        """Every step's horizon is proven minimal (Segment.horizon_proven_minimal)."""
        return all(s.horizon_proven_minimal for s in self.segments)

    @property
    def total_solve_time_s(self) -> float:
        """Every search's wall time: the steps' and the searches they did not take."""
        return float(sum(s.solve_time_s for s in self.segments)) + self.unused_solve_time_s

    @property
    def total_cpu_time_s(self) -> float:
        return float(sum(s.cpu_time_s for s in self.segments))

    def to_json(self) -> dict:
        return {
            "dt": self.dt,
            "rule": self.rule,
            "delivery": self.delivery,
            "goals": self.goals,
            "objects": self.objects,
            "workspace": self.workspace,
            "trajectory": self.trajectory.to_json(),
            "delivered_step": self.delivered_step,
            "segments": [s.to_json() for s in self.segments],
            "total_cost": round(self.total_cost, 9),
            "total_solve_time_s": round(self.total_solve_time_s, 4),
            "verified": self.verified,
            "total_cpu_time_s": round(self.total_cpu_time_s, 4),
            "search": self.search,
            "partial": self.partial,
            "total_bound": round(self.total_bound, 9),
            "gap": round(self.gap, 9),
            "horizon_proven_minimal": self.horizon_proven_minimal,
            "first_plan_s": None if self.first_plan_s is None else round(self.first_plan_s, 4),
            "unused_solve_time_s": round(self.unused_solve_time_s, 4),
        }

    def save(self, path: str | Path) -> None:
        """Write the plan JSON, whole or not at all."""
        outputs.write(path, outputs.json_text(self.to_json()))

    @staticmethod
    def from_json(data: dict) -> Plan:
        return Plan(
            dt=data["dt"],
            rule=data["rule"],
            delivery=data["delivery"],
            goals=data["goals"],
            objects=data["objects"],
            workspace=data["workspace"],
            trajectory=Trajectory.from_json(data["trajectory"]),
            delivered_step=data["delivered_step"],
            segments=[Segment.from_json(s) for s in data.get("segments", [])],
            verified=data.get("verified", False),
            search=data.get("search", "monolithic"),
            partial=data.get("partial", False),
            first_plan_s=data.get("first_plan_s"),
            unused_solve_time_s=data.get("unused_solve_time_s", 0.0),
        )

    @staticmethod
    def load(path: str | Path) -> Plan:
        return Plan.from_json(json.loads(Path(path).read_text()))


@dataclass(frozen=True)
class TimedTrajectory:
    """A trajectory anchored in simulation time: step k happens at ``t0 + k·dt``."""

    t0: float
    dt: float
    trajectory: Trajectory


_EPS = 1e-9  # time slack so that t = t0 + k·dt computed in floating point lands in step k


def empty_plan(n_objects: int, hand_pos: np.ndarray | None = None) -> TimedTrajectory:
    """A plan of one step (K = 0): both hands at rest at ``hand_pos`` (2×2), nothing held."""
    hand = np.zeros((1, 2, 2)) if hand_pos is None else np.asarray(hand_pos, float).reshape(1, 2, 2)
    trajectory = Trajectory(
        hand_pos=hand,
        hand_vel=np.zeros((1, 2, 2)),
        force=np.zeros((0, 2, 2)),
        object_pos=np.zeros((1, n_objects, 2)),
        object_vel=np.zeros((1, n_objects, 2)),
        grasp=np.zeros((1, 2, n_objects), dtype=int),
    )
    return TimedTrajectory(t0=0.0, dt=1.0, trajectory=trajectory)


def step_at(plan: TimedTrajectory, t: float) -> tuple[int, float]:
    """(k, s): the step index k = floor((t − t0)/dt) (any integer) and s ∈ [0, 1) within it."""
    tau = (t - plan.t0) / plan.dt
    k = math.floor(tau + _EPS)
    return k, min(max(tau - k, 0.0), 1.0)


def sample_grasp(plan: TimedTrajectory, t: float) -> np.ndarray:
    """The grasp command η at time t, flattened row-major ([i][j], length 2N)."""
    grasp = plan.trajectory.grasp
    k, _ = step_at(plan, t)
    return np.asarray(grasp[min(max(k, 0), len(grasp) - 1)], dtype=float).reshape(-1)
