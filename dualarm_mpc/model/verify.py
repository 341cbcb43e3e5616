"""Verification: replay a plan through the model and check its LTL specification on the trace.

The oracle for every plan: :func:`~dualarm_mpc.model.mld.replay` replays the planned forces and
grasps, the atoms are read off the simulated trace exactly (θ_j(k) is "object j inside its goal
box", two-sided), and each sequential step's specification is evaluated by ``evaluate.py`` — code
that shares nothing with the MILP encoder.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualarm_mpc.logic.evaluate import evaluate
from dualarm_mpc.logic.ltl import Atom
from dualarm_mpc.model.mld import (
    POSITION_TOL,
    REST_TOL,
    Model,
    Rect,
    State,
    crowding,
    delivered,
    in_goal,
    replay,
    standing,
    violations,
)
from dualarm_mpc.model.plan import Plan, Trajectory
from dualarm_mpc.model.scenario import Scenario
from dualarm_mpc.model.spec import rule_formulas, specification


@dataclass(frozen=True)
class Verification:
    ok: bool
    problems: list[str]


def atom_trace(scenario: Scenario, traj: Trajectory, start: int, stop: int):
    """The atoms' truth on steps ``start..stop`` of ``traj`` as a callable ``(atom, k) -> bool``."""
    goals = [Rect.of(scenario.task.goals[o.goal]) for o in scenario.task.objects]

    def value(atom: Atom, k: int) -> bool:
        step = start + k
        if atom.name == "eta":
            i, j = atom.index
            return bool(traj.grasp[step, i - 1, j - 1])
        if atom.name == "theta":
            (j,) = atom.index
            return bool(in_goal(traj.object_pos[step, j - 1], goals[j - 1]))
        raise KeyError(f"no value for atom {atom} in a plan's trace")

    return value


def verify(scenario: Scenario, plan: Plan) -> Verification:
    """Every check a plan must pass: model replay, model constraints, each step's specification,
    and — unless the plan is partial — every object resting in its goal at the end."""
    problems: list[str] = []
    model = Model.from_scenario(scenario)
    traj = plan.trajectory
    replayed = replay(model, State.initial(scenario), traj.force, traj.grasp)
    for name in ("hand_pos", "hand_vel", "object_pos", "object_vel"):
        err = float(np.abs(getattr(replayed, name) - getattr(traj, name)).max(initial=0.0))
        if err > POSITION_TOL:
            problems.append(f"{name} differs from the model's replay by {err:.2e}")
    problems += violations(model, replayed)
    rules = rule_formulas(scenario, plan.rule)
    start = 0
    for n, seg in enumerate(plan.segments):
        spec = specification(scenario, seg.objects, rules=rules)
        holds = atom_trace(scenario, replayed, start, start + seg.horizon)
        problems += _crowding(scenario, model, replayed, seg.objects, start, start + seg.horizon,
                              f"step {n + 1}")
        if not evaluate(spec.task(), holds, seg.horizon):
            problems.append(f"step {n + 1}: φ_task (13) is false on the replayed trace")
        for name, formula in spec.rules:
            if not evaluate(formula, holds, seg.horizon):
                problems.append(f"step {n + 1}: rule {name} is false on the replayed trace")
        start += seg.horizon
    if start != traj.steps:
        problems.append(f"the steps' horizons add up to {start}, the trajectory has {traj.steps}")
    end = State.last(replayed)
    goals = scenario.task.goals
    for j, o in enumerate([] if plan.partial else scenario.task.objects):
        if not delivered(end.object_pos[j], end.object_vel[j], goals[o.goal], REST_TOL):
            problems.append(f"{o.name} does not end at rest in goal {o.goal}")
    return Verification(not problems, problems)


def _crowding(scenario: Scenario, model: Model, traj: Trajectory, objects: list[int],
              start: int, stop: int, step: str) -> list[str]:
    """(C1)–(C2) on steps ``start..stop`` of ``traj``, the sequential step over ``objects``; the
    others stand where they are at ``start``."""
    part = Trajectory(traj.hand_pos[start:stop + 1], traj.hand_vel[start:stop + 1],
                      traj.force[start:stop], traj.object_pos[start:stop + 1, objects],
                      traj.object_vel[start:stop + 1, objects],
                      traj.grasp[start:stop + 1][:, :, objects])
    others = [j for j in range(scenario.n_objects) if j not in objects]
    names = [scenario.task.objects[j].name for j in [*objects, *others]]
    return [f"{step}: {names[j]} comes within {model.spacing:g} m of {names[o]} (C1) over its "
            f"step {k}"
            for j, o, k in crowding(model, part, *standing(State.at(traj, start), objects,
                                                          model.dt))]
