"""Solvers side by side on the same Table II models: the skeleton search and the monolithic MILP
on every installed backend (HiGHS, SCIP, Gurobi, CPLEX).

What it measures: for each (m_o, n_o) row, rule and seed of ``table1_vd`` (delivery ``reach``,
as in bench/table2.py), a reference plan is made with the skeleton search on HiGHS. Its
sequential steps — each a start state, the step's objects and specification, and the horizon
the plan used — are the models: every backend solves every one of them twice, by the skeleton
search and as one monolithic MILP, with the same time limit, on the same machine, one solve at
a time. Per solve: wall and CPU time (this process, every thread), status (proven optimal or
not), cost, and whether the model fits the backend's free licence (Gurobi's pip licence: 2000
variables and 2000 constraints; CPLEX Community: 1000 and 1000, ``backends.py``): a model over
it is counted, not solved. The search also solves narrowed programs of the same MILP; it fits
when every one of them does.

Run it (from the repository root)::

    nice .venv/bin/python bench/solvers.py --rows 2,5 2,6 --rules 1 2 --seeds 1 --time-limit 10

The Markdown table goes to stdout and next to the JSON (``--json``, default
bench/results/solvers.json), which keeps every solve, the machine, the options and the load
average before and after each model.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

from benchlib import fmt, machine, options_json, parse_seeds, table, write_json_atomic, write_report
from table2 import SCENARIO, parse_row, step_starts

from dualarm_mpc.milp.horizon import HorizonProgram, solve_step
from dualarm_mpc.milp.solver import SolverUnavailable, installed_backends
from dualarm_mpc.model.scenario import load_scenario
from dualarm_mpc.model.spec import StepProblem, specification
from dualarm_mpc.planning.sequential import transport
from dualarm_mpc.search.skeleton import search_step

METHODS = ("search", "monolithic")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rows", nargs="+", type=parse_row, default=[(2, 5), (2, 6)], metavar="M,N")
    p.add_argument("--rules", nargs="+", type=int, choices=(1, 2), default=[1, 2])
    p.add_argument("--seeds", type=parse_seeds, default=[0])
    p.add_argument("--time-limit", type=float, default=10.0, help="seconds per solve")
    p.add_argument("--solvers", nargs="+", default=installed_backends(),
                   choices=installed_backends(), help="default: every installed backend")
    p.add_argument("--json", type=Path, default=Path("bench/results/solvers.json"))
    p.add_argument("--summarize", type=Path, metavar="JSON",
                   help="print the table of an earlier run's JSON; run nothing")
    return p.parse_args(argv)


def solve_one(problem: StepProblem, horizon: int, backend: str, method: str) -> dict:
    """One model by one backend and method: times, status, cost, or the licence refusal."""
    solver = replace(problem.scenario.solver, backend=backend)
    problem = replace(problem, scenario=replace(problem.scenario, solver=solver))
    t0, cpu0 = time.perf_counter(), time.process_time()
    try:
        if method == "search":
            res = search_step(problem, horizon)
        else:
            res = solve_step(problem, horizon)
    except SolverUnavailable as err:
        return {"status": "over_licence", "message": str(err)}
    return {"status": res.status.value, "cost": res.cost if res.status.has_solution else None,
            "bound": res.bound, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - cpu0}


def run_model(m_o: int, n_o: int, rule: int, seed: int, args: argparse.Namespace) -> list[dict]:
    """Every step of the reference plan of one Table II model, by every backend and method."""
    overrides = {"m_o": m_o, "n_o": n_o, "rule": rule, "seed": seed, "delivery": "reach",
                 "solver": {"time_limit_s": args.time_limit}}
    scenario = load_scenario(SCENARIO, overrides)
    reference = transport(scenario)
    out = []
    for n, (seg, state) in enumerate(step_starts(reference), 1):
        spec = specification(scenario, seg.objects)
        form = HorizonProgram(scenario, state, list(seg.objects), seg.horizon).standard_form(spec)
        size = {"variables": len(form.c), "constraints": form.A.shape[0]}
        for backend in args.solvers:
            for method in METHODS:
                load = os.getloadavg()[0]
                r = solve_one(StepProblem(scenario, state, spec), seg.horizon, backend, method)
                out.append({"m_o": m_o, "n_o": n_o, "rule": rule, "seed": seed, "step": n,
                            "horizon": seg.horizon, **size, "backend": backend,
                            "method": method, "load_avg_1min": load, **r})
                print(f"({m_o},{n_o}) rule {rule} seed {seed} step {n} T={seg.horizon} "
                      f"{size['variables']}x{size['constraints']} {backend:<6} {method:<10} "
                      f"{r['status']:<12} {fmt(r.get('wall_s'), '.2f')} s",
                      file=sys.stderr, flush=True)
    return out


def summarize(solves: list[dict], solvers: list[str]) -> list[dict]:
    """Per backend and method over ``solves`` (one group of models): the models within the
    licence, proven optimal, the cost over them and the time; next to HiGHS's search on the
    same models (its cost where both have a plan, its CPU time on every model within the
    licence)."""
    ref = {(s["m_o"], s["n_o"], s["rule"], s["seed"], s["step"]): s for s in solves
           if s["backend"] == "highs" and s["method"] == "search"}

    def highs(s: dict) -> dict:
        return ref[(s["m_o"], s["n_o"], s["rule"], s["seed"], s["step"])]

    out = []
    for backend in solvers:
        for method in METHODS:
            these = [s for s in solves if s["backend"] == backend and s["method"] == method]
            fit = [s for s in these if s["status"] != "over_licence"]
            both = [s for s in fit if s["cost"] is not None and highs(s)["cost"] is not None]
            out.append({
                "backend": backend, "method": method, "models": len(these),
                "within_licence": len(fit),
                "largest_within": max((s["constraints"] for s in fit), default=None),
                "optimal": sum(s["status"] == "optimal" for s in fit),
                "cost": sum(s["cost"] for s in both) if both else None,
                "highs_search_cost": sum(highs(s)["cost"] for s in both) if both else None,
                "wall_s": sum(s["wall_s"] for s in fit) if fit else None,
                "cpu_s": sum(s["cpu_s"] for s in fit) if fit else None,
                "highs_search_cpu_s": sum(highs(s)["cpu_s"] for s in fit) if fit else None,
            })
    return out


def groups(solves: list[dict]) -> dict[str, list[dict]]:
    """The solves per (m_o, n_o) row and rule, and all of them pooled."""
    keys = sorted({(s["m_o"], s["n_o"], s["rule"]) for s in solves})
    out = {f"({m},{n}) rule {rule}": [s for s in solves if (s["m_o"], s["n_o"], s["rule"])
                                       == (m, n, rule)] for m, n, rule in keys}
    return {**out, "all": solves}


def report(solves: list[dict], args: argparse.Namespace) -> str:
    header = ["models", "solver", "method", "steps within licence (largest, rows)",
              "proven optimal", "cost (HiGHS search, same steps)", "wall (s)",
              "CPU (s) (HiGHS search, same steps)"]
    rows = []
    for label, group in groups(solves).items():
        for s in summarize(group, args.solvers):
            rows.append([label, s["backend"], s["method"],
                         f"{s['within_licence']}/{s['models']} ({fmt(s['largest_within'], 'd')})",
                         f"{s['optimal']}/{s['within_licence']}",
                         f"{fmt(s['cost'], '.3f')} ({fmt(s['highs_search_cost'], '.3f')})",
                         fmt(s["wall_s"], ".1f"),
                         f"{fmt(s['cpu_s'], '.1f')} ({fmt(s['highs_search_cpu_s'], '.1f')})"])
    loads = [s["load_avg_1min"] for s in solves]
    return "\n".join([
        f"Steps of {SCENARIO} plans (seeds {','.join(map(str, args.seeds))}), each step of "
        f"HiGHS's reference plan solved by every backend, {args.time_limit:g} s per solve, one "
        f"solve at a time; load average {min(loads):.1f}-{max(loads):.1f} (median "
        f"{statistics.median(loads):.1f}) on {os.cpu_count()} cores:", "",
        table(header, rows), ""])


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.summarize:
        data = json.loads(args.summarize.read_text())
        print(report(data["solves"], argparse.Namespace(**data["options"])))
        return 0
    head = {"options": options_json(args),
            "machine": machine()}
    solves: list[dict] = []
    for m_o, n_o in args.rows:
        for rule in args.rules:
            for seed in args.seeds:
                solves += run_model(m_o, n_o, rule, seed, args)
                write_json_atomic(args.json, {**head, "solves": solves})
    write_json_atomic(args.json, {**head, "solves": solves})
    write_report(args.json, report(solves, args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
