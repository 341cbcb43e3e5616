"""A whole task's plan made shorter by re-timing its hands: which hand holds which object, and
in what order, kept; one step at a time taken out.

Sequential transportation's steps, joined into one (``Plan.as_one_step``), wait at each seam
for the step's slower hand: the next step starts only when every object of this one is
delivered. The whole task has no seams, and the search that would close them (the skeleton
search over every object) finds no plan within a run's budget from seven objects on. But with
the plan's grasp schedule fixed — η_ij(k) for every hand, object and step — the MILP of a
horizon is linear in the forces and states (eqs. 1, 7–11, 14–16), its few binaries left the
goal indicators θ (13) and the rules' encoding: on ten objects it is solved in about 0.1 s.

Taking step p out of hand i's timeline moves every grasp of hand i after p one step earlier (a
carry or a way between objects one step shorter); the other hand loses its last step, or the
same step p. The program of the horizon one step shorter with that schedule fixed says whether
the hands can still do it — the dynamics, eq. (16) between the hands, the specification — and
at what least cost. The first removal that has a plan is taken, and the next one tried from
it, until none has. Each schedule is a restriction of the whole task (η fixed), so each plan
found is a plan of the whole task: its horizon no shorter than the task's minimal one, its
cost unproven. What it takes out of §V-D's plans, and what was tried beside it:
docs/search.md, "The anytime plan"."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator

import numpy as np

from dualarm_mpc.milp.horizon import HorizonProgram, StepResult
from dualarm_mpc.milp.solver import SolveOptions
from dualarm_mpc.model.mld import N_HANDS
from dualarm_mpc.model.spec import StepProblem


def shortened(problem: StepProblem, grasp: np.ndarray, options: SolveOptions
              ) -> tuple[StepResult, int] | None:
    """The plan of ``problem`` (a whole task's one step) with the grasp schedule ``grasp``
    ((T+1, 2, N): η of a plan of T steps, the step's objects in ``problem.spec.objects``'
    order) made as short as single removals make it (module docstring), and how many steps
    were taken out; None where not one step can be, or the time runs out first
    (``options.time_limit_s`` in all, and the search's stop)."""
    deadline = time.perf_counter() + options.time_limit_s
    objects = list(problem.spec.objects)
    found: StepResult | None = None
    taken = 0
    while len(grasp) > 2:
        horizon = len(grasp) - 2
        program = HorizonProgram(problem.scenario, problem.state, objects, horizon)
        for schedule in _removals(grasp):
            left = deadline - time.perf_counter()
            if left <= 0 or options.stopped():
                return None if found is None else (found, taken)
            res = program.solve(problem.spec, dataclasses.replace(options, time_limit_s=left),
                                grasp=schedule)
            if res.status.has_solution:
                found, grasp, taken = res, schedule, taken + 1
                break
        else:
            break
    return None if found is None else (found, taken)


def _removals(grasp: np.ndarray) -> Iterator[np.ndarray]:
    """The schedules one step shorter than ``grasp``: step p (1 ≤ p ≤ T) out of one hand's
    timeline and the last out of the other's — first for the hand whose last grasp ends later,
    which is the one that has to gain a step — then step p out of both. Step 0 is the start's
    grasp, never taken out. Steps within one stretch of a hand's timeline (a carry, a way
    between objects) are alike: each schedule is given once."""
    steps = len(grasp) - 1
    held = [np.flatnonzero(grasp[:, i].any(axis=1)) for i in range(N_HANDS)]
    ends = [h[-1] if h.size else 0 for h in held]
    first = sorted(range(N_HANDS), key=lambda i: -ends[i])
    removals = [{hand: p, 1 - hand: steps} for hand in first for p in range(1, steps + 1)]
    removals += [{0: p, 1: p} for p in range(1, steps)]
    seen = set()
    for removal in removals:
        schedule = _without(grasp, removal)
        key = schedule.tobytes()
        if key not in seen:
            seen.add(key)
            yield schedule


def _without(grasp: np.ndarray, steps: dict[int, int]) -> np.ndarray:
    """``grasp`` with step ``steps[i]`` taken out of hand i's timeline."""
    return np.stack([np.delete(grasp[:, i], steps[i], axis=0) for i in range(N_HANDS)], axis=1)


__all__ = ["shortened"]
