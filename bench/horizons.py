"""The horizons of one sequential step: where the time of a hard step goes.

What it measures: for one Table II model of ``table1_vd`` (a row (m_o, n_o), a rule, a seed;
delivery ``reach``, as in bench/table2.py), the steps before the one asked are planned as the
bench plans them (skeleton search, ``--plan-time-limit`` per horizon), and that step is then
solved at every horizon asked, by the skeleton search (its feasibility pass and best-first
search, ``search.search_step``) and by the monolithic MILP (``horizon.solve_step``), each with
``--time-limit`` per solve, one solve at a time. Per horizon and method: the status (a horizon
below the step's first plan is "infeasible" when proven so, "time_limit" when left undecided),
cost, bound, gap, wall and CPU time (this process, every thread). Algorithm 1 takes the first
horizon with a plan from predictT on, so every horizon below that one must be proven
infeasible for the step to be decided; this shows which are, and at what cost. It is the
measurement behind bench/search-experiments.md ("Open: a bound for relay nodes").

Run it (from the repository root)::

    .venv/bin/python bench/horizons.py --row 3,5 --rule 2 --seed 0 --step 2 --horizons 12-17

The Markdown table goes to stdout and next to the JSON (``--json``, default
bench/results/horizons.json), which keeps every solve, the step's start state, the machine and
the options.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from benchlib import (
    fmt,
    footer,
    machine,
    options_json,
    parse_numbers,
    table,
    write_json_atomic,
    write_report,
)
from solvers import METHODS, solve_one
from table2 import SCENARIO, parse_row

from dualarm_mpc.milp.horizon import solve_options
from dualarm_mpc.milp.solver import Interrupt
from dualarm_mpc.model.mld import State, delivered_objects
from dualarm_mpc.model.scenario import load_scenario
from dualarm_mpc.model.spec import StepProblem, specification
from dualarm_mpc.planning.sequential import predict_horizon, select_objects, transport


def parse_horizons(text: str) -> list[int]:
    """``12-17`` (a range) or ``12,14,16`` (a list)."""
    try:
        return parse_numbers(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected 12-17 or 12,14,16, got {text!r}") from err


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--row", type=parse_row, default=(3, 5), metavar="M,N")
    p.add_argument("--rule", type=int, choices=(1, 2), default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--step", type=int, default=2, help="the sequential step (1 = the first)")
    p.add_argument("--horizons", type=parse_horizons, required=True, metavar="A-B")
    p.add_argument("--time-limit", type=float, default=60.0, help="seconds per solve")
    p.add_argument("--plan-time-limit", type=float, default=30.0,
                   help="seconds per horizon for the steps before (bench/table2.py's)")
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    p.add_argument("--json", type=Path, default=Path("bench/results/horizons.json"))
    args = p.parse_args(argv)
    if args.step < 1:
        p.error("--step: the first step is 1")
    return args


def scenario_for(args: argparse.Namespace, time_limit: float):
    m_o, n_o = args.row
    return load_scenario(SCENARIO, {"m_o": m_o, "n_o": n_o, "rule": args.rule, "seed": args.seed,
                                    "delivery": "reach", "solver": {"time_limit_s": time_limit}})


def step_start(args: argparse.Namespace) -> tuple[State, list[dict]]:
    """The state the step starts from: Algorithm 1 run up to it (stopped as the step before
    ends), with the steps planned on the way."""
    scenario = scenario_for(args, args.plan_time_limit)
    if args.step == 1:
        return State.initial(scenario), []
    stop = Interrupt()
    options = replace(solve_options(scenario), interrupt=stop)

    planned = []

    def progress(segment) -> None:
        planned.append(segment)
        if len(planned) >= args.step - 1:
            stop.set()  # the next step stops before its first solve

    result = transport(scenario, options, progress=progress)
    if len(result.segments) < args.step - 1:
        raise SystemExit(f"the plan has {len(result.segments)} steps, none numbered {args.step}")
    return State.last(result.trajectory), [s.to_json() for s in result.segments]


def solve(problem: StepProblem, horizon: int, method: str) -> dict:
    """One horizon by one method (bench/solvers.py's solve, on the scenario's backend), its
    gap derived from cost and bound."""
    r = solve_one(problem, horizon, problem.scenario.solver.backend, method)
    bound = r["bound"] if math.isfinite(r["bound"]) else None  # none: no plan at all
    cost = r["cost"]
    gap = None if cost is None or bound is None else (cost - bound) / max(abs(cost), 1e-12)
    return {"horizon": horizon, "method": method, **r, "bound": bound, "gap": gap}


def report(data: dict) -> str:
    step = data["step"]
    head = (f"{SCENARIO} ({data['options']['row'][0]},{data['options']['row'][1]}) rule "
            f"{data['options']['rule']} seed {data['options']['seed']}, step "
            f"{data['options']['step']}: objects {', '.join(str(j + 1) for j in step['objects'])}"
            f", predictT {step['predicted_horizon']}; {data['options']['time_limit']:g} s a "
            "solve, one at a time:")
    rows = [[str(s["horizon"]), s["method"], s["status"], fmt(s["cost"], ".4f"),
             fmt(s["bound"], ".4f"), fmt(s["gap"], ".3f"), fmt(s["wall_s"], ".1f"),
             fmt(s["cpu_s"], ".1f")] for s in data["solves"]]
    header = ["T", "method", "status", "cost", "bound", "gap", "wall (s)", "CPU (s)"]
    return "\n".join([head, "", table(header, rows), ""])


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t0 = time.perf_counter()
    info = machine()
    state, before = step_start(args)
    scenario = scenario_for(args, args.time_limit)
    done = delivered_objects(scenario, state.object_pos, state.object_vel)
    remaining = np.flatnonzero(~done).tolist()
    if not remaining:
        raise SystemExit(f"every object is delivered before step {args.step}")
    objects = select_objects(scenario, state, remaining)
    problem = StepProblem(scenario, state, specification(scenario, objects))
    first = predict_horizon(problem)
    data = {"options": options_json(args),
            "machine": info, "steps_before": before,
            "step": {"objects": objects, "predicted_horizon": first,
                     "hand_pos": state.hand_pos.tolist(), "hand_vel": state.hand_vel.tolist(),
                     "object_pos": state.object_pos.tolist(),
                     "object_vel": state.object_vel.tolist(), "grasp": state.grasp.tolist()},
            "solves": []}
    for horizon in args.horizons:
        for method in args.methods:
            data["solves"].append(solve(problem, horizon, method))
            s = data["solves"][-1]
            print(f"T={horizon} {method:<10} {s['status']:<10} {fmt(s['wall_s'], '.1f')} s",
                  file=sys.stderr, flush=True)
            write_json_atomic(args.json, data)
    write_report(args.json, report(data) + footer(info, t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
