"""A whole task's route-guided plan: one joint program, each hand held to the share and the
order that the route bound finds fastest, probed from that share's route bound upward.

On six objects the exact search (docs/search.md) finds no plan of the whole task within a
minute on most scenes: it must cover the 2^n shares of the objects between the hands and every
order within them. Under no-throw (18) the route bound (``route.py``) counts the fewest steps
in which a hand can deliver a share, and each order's windows (``route.Order``). The share
whose slower hand needs the fewest steps is the likeliest to have a plan at a short horizon; of
those, the one whose hands cross least, since eq. (16) keeps arm 1 to the right of arm 2. Its
program — the whole step's MILP with η_ij = 0 outside the share, each hand along its shortest
order (``HorizonProgram.standard_form(allowed=, orders=)``), both hands costed — is a
restriction of the whole step, so its plan is a plan of the whole task: its horizon no shorter
than the task's minimal one, its cost unproven (the first plan found, bettered in the time
left). ``task.plan`` takes it where it is shorter than sequential transportation's, and the
exact search then looks no further than its horizon."""

from __future__ import annotations

import dataclasses
import itertools
import time

import numpy as np

from dualarm_mpc.milp.horizon import HorizonProgram, StepResult
from dualarm_mpc.milp.solver import SolveOptions
from dualarm_mpc.model import route
from dualarm_mpc.model.mld import N_HANDS, Model
from dualarm_mpc.model.spec import StepProblem
from dualarm_mpc.search.subprograms import SPLIT_MAX_OBJECTS

# The whole tasks it is tried on: six objects, where the exact search finds no plan in a minute
# on most scenes and this program finds one on about half. On seven and eight HiGHS found no
# plan of it in 30 s (seven: seeds 0-2; eight: seeds 0-1, and 120 s on seed 0), nor on ten in
# 60 s a horizon from the route bound to sequential transportation's (seed 0). Five objects
# and fewer are the exact search's.
OBJECTS = range(6, 7)
# The shares probed at each horizon, the share of the time limit each probe may take, and
# how many such slices the first plan found is bettered in at most (the search gets the rest).
CANDIDATES = 3
SLICE = 1 / 6
BETTER_SLICES = 2


def guided_plan(problem: StepProblem, below: int, options: SolveOptions) -> StepResult | None:
    """The first plan of a route-guided program (module docstring) at the least horizon below
    ``below`` that has one within ``options.time_limit_s`` in all; None where it does not
    apply (not a whole task of ``OBJECTS``, an object that may be thrown), or none is found in
    time. At each horizon the ``CANDIDATES`` best shares whose routes it allows are probed in
    turn, each for ``SLICE`` of the time; the first plan found is then bettered
    (``_bettered``). Its status and bound are the restricted program's."""
    scenario, state, spec = problem.scenario, problem.state, problem.spec
    objects = list(spec.objects)
    if len(objects) not in OBJECTS or spec.m_o != len(objects) or \
            spec.released_only_in_goal() != frozenset(objects):
        return None
    deadline = time.perf_counter() + options.time_limit_s
    model = Model.from_scenario(scenario, objects)
    local = state.select(objects)
    no_throw = frozenset(range(len(objects)))
    candidates = _shares(model, local, no_throw, below - 1, options)
    for horizon in range(min((steps for steps, _ in candidates), default=below), below):
        for steps, shares in candidates:
            left = deadline - time.perf_counter()
            if left <= 0 or options.stopped():
                return None
            if steps > horizon:
                continue
            found = [route.orders(model, local, i, share, no_throw, horizon)
                     for i, share in enumerate(shares) if share]
            if not all(found):
                continue
            allowed = np.zeros((N_HANDS, len(objects)), bool)
            for i, share in enumerate(shares):
                allowed[i, list(share)] = True
            program = HorizonProgram(scenario, state, objects, horizon)
            narrow = dict(allowed=allowed, orders=tuple(each[0] for each in found))
            probe = dataclasses.replace(options, mip_rel_gap=1.0, small_trees=True,
                                        time_limit_s=min(left, SLICE * options.time_limit_s))
            res = program.solve(spec, probe, **narrow)
            if res.status.has_solution:
                return _bettered(program, spec, res, narrow, options, deadline)
    return None


def _bettered(program: HorizonProgram, spec, first: StepResult, narrow: dict,
              options: SolveOptions, deadline: float) -> StepResult:
    """``first`` (a probe's first plan) bettered within ``BETTER_SLICES`` slices of the time
    left at most: the same program solved for its optimum, MIP-started from it. A probe's first
    plan is a plan and no more; on six objects it cost up to 1.6 times sequential
    transportation's."""
    left = min(deadline - time.perf_counter(), BETTER_SLICES * SLICE * options.time_limit_s)
    if left <= 0 or options.stopped():
        return first
    res = program.solve(spec, dataclasses.replace(options, time_limit_s=left),
                        lambda x, v=first.solution: v, apart=first.apart, **narrow)
    return res if res.status.has_solution and res.cost < first.cost else first


def _shares(model: Model, state, no_throw: frozenset[int], cap: int, options: SolveOptions
            ) -> list[tuple[int, tuple[tuple[int, ...], tuple[int, ...]]]]:
    """The ``CANDIDATES`` shares of the objects between the hands (local indices) whose slower
    hand's route bound is least, and of equal bounds those with the fewest crossings, each
    with that bound; none where none is within ``cap`` or the search was stopped. A hand's
    share has ``SPLIT_MAX_OBJECTS`` at most, whose orders are few enough to be counted."""
    n = model.n_objects
    goal_x = np.array([(g.lo[0] + g.hi[0]) / 2 for g in model.goals])
    place_x = state.object_pos[:, 0]
    ranked = []
    for hands in itertools.product(range(N_HANDS), repeat=n):
        shares = tuple(tuple(j for j in range(n) if hands[j] == i) for i in range(N_HANDS))
        if max(map(len, shares)) > SPLIT_MAX_OBJECTS:
            continue
        steps = max(route.route_steps(model, state, i, share, no_throw, cap, options.stopped)
                    if share else 0 for i, share in enumerate(shares))
        if options.stopped():
            return []
        # arm 1 (hand 0) right of arm 2: a pair whose goals or places lie the other way
        crossings = sum(int(goal_x[j] < goal_x[k]) + int(place_x[j] < place_x[k])
                        for j in shares[0] for k in shares[1])
        if steps <= cap:
            ranked.append((steps, crossings, shares))
    return [(steps, shares) for steps, _, shares in sorted(ranked)[:CANDIDATES]]


__all__ = ["BETTER_SLICES", "CANDIDATES", "OBJECTS", "SLICE", "guided_plan"]
