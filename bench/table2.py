"""Table II of the paper (§V-D): mean total cost and solve time of sequential transportation.

What it measures: for each (m_o, n_o) row, rule and seed, the scenario ``table1_vd`` (ten objects
uniform in [-0.25, 0.25]² from the seed, reachable goals, delivery ``reach`` as in the paper) is
planned with :func:`dualarm_mpc.planning.task.plan` (sequential transportation, then every plan
checked with :func:`dualarm_mpc.model.verify.verify`). "Time" is the plan's total solve time: build
and solve of every horizon tried in every sequential step (the paper's "calculation time"); "time
to the first verified plan" is the plan's ``first_plan_s``, until a plan of every object existed
and passed verification; "mean proven gap" is the plan's gap at the end, (cost − Σ the steps'
proven bounds) / cost (``Plan.gap``; "—" for records before ``Segment.bound``). Means are over the
runs that produced a verified plan; planning errors, verification failures and runs stopped by
``--run-budget`` are counted apart and never stop the bench.

Run it (from the repository root)::

    .venv/bin/python bench/table2.py                                  # the whole grid, ~hours
    .venv/bin/python bench/table2.py --rows 2,5 2,6 --rules 1 --seeds 3 --time-limit 10
    .venv/bin/python bench/table2.py --rows 2,6 --seeds 0-2 --compare-forms
    .venv/bin/python bench/table2.py --rows 2,5 2,6 2,10 --seeds 0-2 --apart 0.01
    .venv/bin/python bench/table2.py --workers 2                      # a local Dask cluster
    .venv/bin/python bench/table2.py --scheduler tcp://10.0.0.5:8786  # an existing one

Runs are Dask tasks with ``--workers N`` (a local cluster of N processes) or ``--scheduler``
(needs ``pip install '.[dask]'``); without either they run one after the other here. The plans,
costs and statuses are the same either way (a run's search picks its plan whatever its threads);
only the timing columns differ, and the tables say whether runs shared a machine.

One line per finished run goes to stderr, under a progress bar; the Markdown tables go to stdout
and next to the JSON (``--json``, default bench/results/table2.json, rewritten after every run,
runs in grid order), which holds every run's record, the summary rows, the machine and the
options.

``--apart C`` runs every (row, rule, seed) twice, one right after the other: with the paper's
objects (points) and with ``object_clearance`` C (docs/formulation.md, "Objects that keep apart"),
and adds a table of what keeping them apart costs; Table II's rows are the points' runs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import threading
import time
import traceback
from pathlib import Path

from benchlib import (
    Progress,
    check_cluster_arguments,
    cluster_arguments,
    fmt,
    footer,
    machine,
    options_json,
    parse_seeds,
    run_tasks,
    slowed,
    table,
    write_json_atomic,
    write_report,
)

from dualarm_mpc.milp.horizon import solve_step
from dualarm_mpc.milp.solver import Interrupt
from dualarm_mpc.model.mld import State
from dualarm_mpc.model.scenario import SOLVER_BACKENDS, load_scenario, ortools_installed
from dualarm_mpc.model.spec import StepProblem, specification
from dualarm_mpc.planning.sequential import PlanningError, predict_horizon
from dualarm_mpc.planning.task import VerificationError, plan

SCENARIO = "table1_vd"
ROWS = ((2, 5), (2, 6), (2, 10), (3, 5), (3, 6))
FORMS = ("counting", "subsets")
# Table II of the paper: (cost, time in s) per row and rule; CPLEX, 3.3 GHz Xeon.
PAPER = {
    (2, 5): {1: (9.03, 2.52), 2: (8.79, 11.3)},
    (2, 6): {1: (9.70, 2.54), 2: (9.07, 11.7)},
    (2, 10): {1: (9.80, 2.78), 2: (9.04, 16.9)},
    (3, 5): {1: (12.68, 2700.0), 2: (8.96, 19.7)},
    (3, 6): {1: (12.51, 3640.0), 2: (8.81, 26.4)},
}


# --- command line ------------------------------------------------------------------------------


def parse_row(text: str) -> tuple[int, int]:
    try:
        m_o, n_o = (int(v) for v in text.split(","))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected m_o,n_o (e.g. 2,5), got {text!r}") from err
    return m_o, n_o


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rows", nargs="+", type=parse_row, default=list(ROWS), metavar="M,N",
                   help="(m_o, n_o) rows, e.g. --rows 2,5 2,6 (default: all five)")
    p.add_argument("--rules", nargs="+", type=int, choices=(1, 2), default=[1, 2])
    p.add_argument("--seeds", type=parse_seeds, default=list(range(10)),
                   help="0-9, 0,3,7 or a count (default 0-9)")
    p.add_argument("--time-limit", type=float, default=30.0, help="seconds per MILP solve")
    p.add_argument("--task-form", choices=FORMS, default="counting",
                   help="phi_task as sum(ev_j) >= m_o (counting) or eq. (13) literally (subsets)")
    p.add_argument("--compare-forms", action="store_true",
                   help="run both task forms and add a table comparing them")
    p.add_argument("--apart", type=float, default=None, metavar="C",
                   help="run each plan also with object_clearance C (m) and add a table "
                        "comparing the two")
    p.add_argument("--run-budget", type=float, default=None, metavar="S",
                   help="stop a run after S s of wall time (its solves are interrupted); "
                        "default: no budget")
    p.add_argument("--search", choices=("skeleton", "monolithic"), default="skeleton",
                   help="how each step is solved: the skeleton search (default) or one MILP")
    p.add_argument("--horizons", choices=("witness", "exact"), default="witness",
                   help="solver.horizons: the no-throw witness first (default) or Algorithm 1 "
                        "as the paper")
    p.add_argument("--prover", choices=("cpsat", "none"),
                   default="cpsat" if ortools_installed() else "none",
                   help="solver.prover: CP-SAT beside the search on the horizons it leaves "
                        "undecided (default where OR-Tools is installed) or none")
    p.add_argument("--solver", choices=SOLVER_BACKENDS, default="highs",
                   help="the MILP solver (default highs)")
    p.add_argument("--slowdown", type=float, default=None, metavar="F",
                   help="run as on a machine F times slower (stopped for 1 - 1/F of every 20 "
                        "ms; the record's calibration says how much slower it was)")
    cluster_arguments(p)
    p.add_argument("--compare", action="store_true",
                   help="also solve every step of every plan as one monolithic MILP from the "
                        "same state and horizon, and compare the optima")
    p.add_argument("--json", type=Path, default=Path("bench/results/table2.json"))
    p.add_argument("--summarize", type=Path, metavar="JSON",
                   help="print the tables of an earlier (possibly partial) run's JSON; run nothing")
    args = p.parse_args(argv)
    check_cluster_arguments(p, args)
    if args.slowdown is not None and not 1 <= args.slowdown < math.inf:
        p.error(f"--slowdown must be a finite factor >= 1, got {args.slowdown:g}")
    return args


def grid(args: argparse.Namespace) -> list[dict]:
    forms = FORMS if args.compare_forms else (args.task_form,)
    apart = (None, args.apart) if args.apart is not None else (None,)
    return [
        {"m_o": m, "n_o": n, "rule": rule, "seed": seed, "task_form": form,
         "time_limit_s": args.time_limit, "run_budget_s": args.run_budget,
         "search": args.search, "solver": args.solver, "compare": args.compare,
         "horizons": args.horizons, "prover": args.prover, "object_clearance": clearance,
         "shared_machine": args.workers > 1 or args.scheduler is not None}
        for (m, n) in args.rows for rule in args.rules for seed in args.seeds for form in forms
        for clearance in apart
    ]


# --- one run -----------------------------------------------------------------------------------


def step_starts(result):
    """Each sequential step of a plan with the state it started from."""
    k = 0
    for seg in result.segments:
        yield seg, State.at(result.trajectory, k)
        k += seg.horizon


def predicted_horizons(scenario, result) -> list[int]:
    """predictT of each sequential step, from the state the step started in: the horizon the
    planner tried first (the horizons between it and the accepted one were infeasible or timed
    out)."""
    return [predict_horizon(StepProblem(scenario, state, specification(scenario, seg.objects)))
            for seg, state in step_starts(result)]


def step_records(scenario, result, segments) -> list[dict]:
    """The plan's sequential steps with their predictT where it is complete; else those run so
    far (``segments``, of the pass that was stopped)."""
    steps = [s.to_json() for s in (segments if result is None else result.segments)]
    if result is not None:
        for step, first in zip(steps, predicted_horizons(scenario, result), strict=True):
            step["predicted_horizon"] = first
    return steps


def run_one(task: dict) -> dict:
    """Plan and verify one (row, rule, seed, form); always returns a record, never raises."""
    overrides = {k: task[k] for k in ("m_o", "n_o", "rule", "seed", "task_form")}
    solver = {"time_limit_s": task["time_limit_s"], "search": task["search"],
              "horizons": task.get("horizons", "exact"), "prover": task.get("prover", "none"),
              "backend": task.get("solver", "highs")}
    if task["shared_machine"]:
        solver["workers"] = 1  # the runs share the cores already
    overrides |= {"delivery": "reach", "solver": solver,
                  "object_clearance": task.get("object_clearance")}
    record = dict(task, status="error", message="", cost=None, solve_time_s=None,
                  cpu_time_s=None)
    segments, result, scenario = [], None, None
    # The run budget interrupts the solves (a timer, not a signal: a Dask task runs on a
    # worker's thread, where signals cannot be handled).
    stop = Interrupt()
    budget = threading.Timer(task["run_budget_s"], stop.set) if task["run_budget_s"] else None
    t0 = time.perf_counter()
    try:
        scenario = load_scenario(SCENARIO, overrides)
        if budget:
            budget.start()
        try:
            result, problems = plan(scenario, check_first=False, progress=segments.append,
                                    stop=stop), []
        except VerificationError as err:
            result, problems = err.plan, err.problems
        if result.partial:  # stopped before any complete plan: its steps are in ``segments``
            result = None
            record.update(status="run_budget", message=f"stopped after {task['run_budget_s']} s")
        else:  # stopped or not, a complete plan (the anytime plan's first, where stopped)
            record.update(status="verify_failed" if problems else "ok", problems=problems,
                          cost=result.total_cost, solve_time_s=result.total_solve_time_s,
                          cpu_time_s=result.total_cpu_time_s, first_plan_s=result.first_plan_s,
                          stopped=stop.is_set())
    except PlanningError as err:
        record.update(status="run_budget" if stop.is_set() else "planning_error",
                      message=str(err))
    except Exception:  # a bug in one run must not end the bench: record it and go on
        record.update(message=traceback.format_exc(limit=3))
    finally:
        if budget:
            budget.cancel()
    record["wall_time_s"] = time.perf_counter() - t0
    record["load_avg_1min"] = os.getloadavg()[0]  # other work on the machine skews the times
    record["steps"] = step_records(scenario, result, segments)
    if task["compare"] and result is not None:
        compare_steps(scenario, result, record["steps"])
    return record


def compare_steps(scenario, result, steps: list[dict]) -> None:
    """The monolithic MILP of each step from the same state and horizon: its optimum next to
    ours (``monolithic_cost``, ``monolithic_status``). Whole plans can differ where a step has
    several optimal plans, so the optima are compared step by step."""
    for step, (seg, state) in zip(steps, step_starts(result), strict=True):
        problem = StepProblem(scenario, state, specification(scenario, seg.objects))
        mono = solve_step(problem, seg.horizon)
        step["monolithic_status"] = mono.status.value
        step["monolithic_cost"] = mono.cost if mono.status.has_solution else None
        step["monolithic_time_s"] = mono.solve_time_s + mono.build_time_s


def progress_line(k: int, n: int, r: dict) -> str:
    head = (f"[{k}/{n}] ({r['m_o']},{r['n_o']}) rule {r['rule']} seed {r['seed']} "
            f"{r['task_form']}")
    steps = r["steps"]
    optimal = sum(s["status"] == "optimal" for s in steps)
    if r["status"] in ("ok", "verify_failed"):
        verified = "verified" if r["status"] == "ok" else "VERIFY FAILED: " + r["problems"][0]
        return (f"{head}: cost {r['cost']:.3f}  time {r['solve_time_s']:.1f} s  "
                f"optimal {optimal}/{len(steps)} steps  {verified}")
    return (f"{head}: {r['status'].upper()} after {r['wall_time_s']:.1f} s, {len(steps)} steps: "
            f"{r['message'].strip().splitlines()[-1]}")


# --- summary -----------------------------------------------------------------------------------


def summarize(records: list[dict], key: tuple) -> dict:
    """One summary row over the runs of ``key`` = (m_o, n_o, rule, task_form)."""
    runs = [r for r in records if (r["m_o"], r["n_o"], r["rule"], r["task_form"]) == key]
    ok = [r for r in runs if r["status"] == "ok"]
    steps = [s for r in ok for s in r["steps"]]
    tried = [s for r in runs for s in r["steps"]]  # also the steps of runs that failed later
    times = [r["solve_time_s"] for r in ok]
    paper_cost, paper_time = PAPER.get(key[:2], {}).get(key[2], (None, None))
    mean_cost = statistics.fmean(r["cost"] for r in ok) if ok else None
    mean_time = statistics.fmean(times) if ok else None
    recorded = all("horizon_proven_minimal" in s for s in steps)
    return {
        "m_o": key[0], "n_o": key[1], "rule": key[2], "task_form": key[3],
        "runs": len(runs), "ok": len(ok),
        "planning_errors": sum(r["status"] == "planning_error" for r in runs),
        "verify_failures": sum(r["status"] == "verify_failed" for r in runs),
        "run_budget_stops": sum(r["status"] == "run_budget" for r in runs),
        "other_errors": sum(r["status"] == "error" for r in runs),
        "mean_cost": mean_cost, "paper_cost": paper_cost,
        "cost_ratio": mean_cost / paper_cost if ok and paper_cost else None,
        "mean_time_s": mean_time, "paper_time_s": paper_time,
        # until a plan of every object existed and passed verification (recorded since
        # Plan.first_plan_s; older records have none)
        "mean_first_plan_s": statistics.fmean(r["first_plan_s"] for r in ok)
        if ok and all(r.get("first_plan_s") is not None for r in ok) else None,
        # the plan's proven gap, (cost - the steps' bounds) / cost (recorded since Segment.bound)
        "mean_gap": statistics.fmean(plan_gap(r) for r in ok)
        if ok and all("bound" in s for r in ok for s in r["steps"]) else None,
        "time_ratio": mean_time / paper_time if ok and paper_time else None,
        "median_time_s": statistics.median(times) if ok else None,
        "max_time_s": max(times) if ok else None,
        "steps": len(steps),
        "steps_optimal": sum(s["status"] == "optimal" for s in steps),
        # proven optimal at a horizon every shorter one of which was decided (recorded since
        # solver.horizons; older records have neither field)
        "steps_proven": sum(s["status"] == "optimal" and s["horizon_proven_minimal"]
                            for s in steps) if recorded else None,
        # a shorter horizon left undecided (older records: not proven minimal, which under
        # the witness policy also counts a passed-over plan); a shorter horizon's plan passed
        # over for the cheaper witness
        "steps_undecided_below": sum(bool(s["horizons_undecided"]) for s in steps)
        if all("horizons_undecided" in s for s in steps) else
        sum(not s["horizon_proven_minimal"] for s in steps) if recorded else None,
        "steps_passed_over": sum(s["shorter_plan"] is not None for s in steps)
        if all("shorter_plan" in s for s in steps) else None,
        # decided by the second prover where the search had left them undecided (recorded
        # since solver.prover)
        "horizons_proven_by_cpsat": sum(len(s["horizons_proven_by_cpsat"]) for s in steps)
        if all("horizons_proven_by_cpsat" in s for s in steps) else None,
        # the plan's cost had every step kept its no-throw witness (its own cost where none)
        "mean_witness_cost": statistics.fmean(
            sum(s["cost"] if s["witness_cost"] is None else s["witness_cost"]
                for s in r["steps"]) for r in ok) if ok and recorded else None,
        "steps_run": len(tried),
        "steps_at_limit": sum(s["status"] == "feasible" for s in tried),
        "extra_horizon_tries": sum(s["horizon"] - s["predicted_horizon"] for s in steps),
        "mean_cpu_time_s": statistics.fmean(r["cpu_time_s"] for r in ok) if ok else None,
        "runs_per_host": max(r.get("runs_per_host", 1) for r in runs),
        **monolithic_agreement(steps),
    }


def monolithic_agreement(steps: list[dict]) -> dict:
    """How many steps' optima the monolithic MILP (``--compare``) confirmed: equal within the
    gap (1e-4 relative), decided otherwise (a mismatch), or left undecided at its time limit."""
    compared = [s for s in steps if "monolithic_status" in s]
    decided = [s for s in compared if s["monolithic_status"] == "optimal"]
    equal = [s for s in decided
             if abs(s["cost"] - s["monolithic_cost"]) <= 2e-4 * max(abs(s["cost"]), 1e-9)]
    return {"steps_compared": len(compared), "steps_monolithic_decided": len(decided),
            "steps_equal_to_monolithic": len(equal)}


def plan_gap(run: dict) -> float:
    """A verified run's proven gap: (cost − Σ steps' bounds) / cost, as ``Plan.gap``."""
    bound = sum(s["bound"] for s in run["steps"])
    return max(0.0, (run["cost"] - bound) / run["cost"]) if run["cost"] > 0 else 0.0


def summary_rows(records: list[dict]) -> list[dict]:
    """Table II's rows: the runs with the paper's objects, points (``--apart`` adds others)."""
    records = [r for r in records if r.get("object_clearance") is None]
    keys = {(r["m_o"], r["n_o"], r["rule"], FORMS.index(r["task_form"])) for r in records}
    return [summarize(records, (*key[:3], FORMS[key[3]])) for key in sorted(keys)]


def table2(summary: list[dict], form: str) -> str:
    """The paper's Table II next to ours, for one task form."""
    header = ["(m_o,n_o)", "rule", "runs", "our mean cost", "mean proven gap", "paper cost",
              "cost ratio", "our mean time (s)", "time to the first verified plan (s)",
              "paper time (s)", "time ratio", "steps proven optimal",
              "optimal at a proven-minimal horizon", "undecided shorter horizon",
              "costlier plan at a shorter horizon", "witness cost", "CPU time (s)", "times taken",
              "steps = monolithic"]
    rows = [[f"({s['m_o']},{s['n_o']})", str(s["rule"]), f"{s['ok']}/{s['runs']}",
             fmt(s["mean_cost"], ".3f"), fmt(s.get("mean_gap"), ".3f"), fmt(s["paper_cost"]),
             fmt(s["cost_ratio"]),
             fmt(s["mean_time_s"], ".1f"), fmt(s.get("mean_first_plan_s"), ".1f"),
             fmt(s["paper_time_s"], ".4g"), fmt(s["time_ratio"]),
             f"{s['steps_optimal']}/{s['steps']}", of(s.get("steps_proven"), s["steps"]),
             of(s.get("steps_undecided_below"), s["steps"]),
             of(s.get("steps_passed_over"), s["steps"]), fmt(s.get("mean_witness_cost"), ".3f"),
             fmt(s["mean_cpu_time_s"], ".1f"),
             machine_use(s["runs_per_host"]), agreement(s)]
            for s in summary if s["task_form"] == form]
    return table(header, rows)


def of(count: int | None, steps: int) -> str:
    return "—" if count is None else f"{count}/{steps}"


def machine_use(runs_per_host: int) -> str:
    """Whether a row's runs had their machine to themselves."""
    return "alone" if runs_per_host <= 1 else f"{runs_per_host} runs per machine at once"


def agreement(s: dict) -> str:
    """"equal/decided (undecided)" for the steps compared with the monolithic MILP."""
    if not s["steps_compared"]:
        return "—"
    undecided = s["steps_compared"] - s["steps_monolithic_decided"]
    return (f"{s['steps_equal_to_monolithic']}/{s['steps_monolithic_decided']}"
            + (f" ({undecided} undecided)" if undecided else ""))


def detail(summary: list[dict]) -> str:
    """Where the time goes and what failed, per row, rule and form."""
    header = ["(m_o,n_o)", "rule", "form", "planning errors", "verify failures",
              "run-budget stops", "other errors", "steps stopped at time limit / run",
              "extra horizon tries", "shorter horizons proven by CP-SAT", "median time (s)",
              "max time (s)"]
    rows = [[f"({s['m_o']},{s['n_o']})", str(s["rule"]), s["task_form"],
             str(s["planning_errors"]), str(s["verify_failures"]), str(s["run_budget_stops"]),
             str(s["other_errors"]), f"{s['steps_at_limit']}/{s['steps_run']}",
             str(s["extra_horizon_tries"]), fmt(s.get("horizons_proven_by_cpsat"), "d"),
             fmt(s["median_time_s"], ".1f"), fmt(s["max_time_s"], ".1f")]
            for s in summary]
    return table(header, rows)


def forms_table(records: list[dict]) -> str:
    """Counting vs. subsets form of φ_task on the same (row, rule, seed) — both runs verified."""
    by = {(r["m_o"], r["n_o"], r["rule"], r["seed"], r["task_form"]): r for r in records}
    pairs: dict[tuple, list] = {}
    for (m, n, rule, seed, form), r in by.items():
        other = by.get((m, n, rule, seed, "subsets"))
        if form == "counting" and other and r["status"] == other["status"] == "ok":
            pairs.setdefault((m, n, rule), []).append((r, other))
    header = ["(m_o,n_o)", "rule", "paired runs", "counting time (s)", "subsets time (s)",
              "subsets / counting", "counting cost", "subsets cost"]
    rows = []
    for (m, n, rule), runs in pairs.items():
        tc, ts = (statistics.fmean(p[i]["solve_time_s"] for p in runs) for i in (0, 1))
        cc, cs = (statistics.fmean(p[i]["cost"] for p in runs) for i in (0, 1))
        rows.append([f"({m},{n})", str(rule), str(len(runs)), f"{tc:.1f}", f"{ts:.1f}",
                     f"{ts / tc:.2f}", f"{cc:.3f}", f"{cs:.3f}"])
    return table(header, rows)


def apart_pairs(records: list[dict]) -> dict[tuple, list[tuple[dict, dict]]]:
    """``--apart``'s runs paired: (m_o, n_o, rule, clearance) → the (points, apart) runs of
    each seed where both gave a verified plan."""
    by = {(r["m_o"], r["n_o"], r["rule"], r["seed"], r.get("object_clearance")): r
          for r in records}
    pairs: dict[tuple, list] = {}
    for (m, n, rule, seed, clearance), r in by.items():
        points = by.get((m, n, rule, seed, None))
        if clearance is not None and points and r["status"] == points["status"] == "ok":
            pairs.setdefault((m, n, rule, clearance), []).append((points, r))
    return pairs


def apart_table(records: list[dict]) -> str:
    """``--apart``: each (row, rule, seed) with objects as points and kept apart, both runs
    verified: mean plan time (wall, and CPU over the worker threads), cost, steps' horizons."""
    pairs = apart_pairs(records)
    header = ["(m_o,n_o)", "rule", "object clearance (m)", "paired runs",
              "time, points / apart (s)", "apart / points", "CPU time, points / apart (s)",
              "apart / points", "cost, points / apart", "horizons, points / apart"]
    rows = []
    for (m, n, rule, clearance), runs in sorted(pairs.items()):
        mean = {key: [statistics.fmean(p[i][key] for p in runs) for i in (0, 1)]
                for key in ("solve_time_s", "cpu_time_s", "cost")}
        steps = [sum(s["horizon"] for p in runs for s in p[i]["steps"]) for i in (0, 1)]
        (t0, t1), (c0, c1), (k0, k1) = (mean[k] for k in ("solve_time_s", "cpu_time_s", "cost"))
        rows.append([f"({m},{n})", str(rule), f"{clearance:g}", str(len(runs)),
                     f"{t0:.1f} / {t1:.1f}", f"{t1 / t0:.2f}", f"{c0:.1f} / {c1:.1f}",
                     f"{c1 / c0:.2f}", f"{k0:.3f} / {k1:.3f}", f"{steps[0]} / {steps[1]}"])
    return table(header, rows)


def report(records: list[dict], args: argparse.Namespace) -> str:
    summary = summary_rows(records)
    forms = FORMS if args.compare_forms else (args.task_form,)
    parts = []
    most = max((r.get("runs_per_host", 1) for r in records), default=1)
    shared = "one run at a time (the machine to itself)" if most <= 1 else \
        f"up to {most} runs at once on a machine (shared: the times include their contention)"
    if getattr(args, "slowdown", None) is not None:
        shared += f", slowed down {args.slowdown:g}× (a slower machine)"
    for form in forms:
        parts += [f"Table II, {args.search} search on {getattr(args, 'solver', 'highs')}, horizons "
                  f"{getattr(args, 'horizons', 'exact')}, second prover "
                  f"{getattr(args, 'prover', 'none')}, task "
                  f"form {form}, time limit {args.time_limit:g} s per horizon, {shared} "
                  f"(runs = verified plans / runs):", "", table2(summary, form), ""]
    parts += ["Detail:", "", detail(summary), ""]
    if args.compare_forms:
        parts += ["Task forms (runs where both forms gave a verified plan):", "",
                  forms_table(records), ""]
    if getattr(args, "apart", None) is not None:
        parts += ["Objects kept apart (object_clearance, docs/formulation.md (C1)-(C3)) against "
                  "points, each run right after its points' run (runs where both gave a "
                  "verified plan):", "", apart_table(records), ""]
    return "\n".join(parts)


# --- output ------------------------------------------------------------------------------------


def write_json(path: Path, args: argparse.Namespace, records: list[dict], info: dict,
               complete: bool) -> None:
    """Written after every run (``complete`` false until the last), atomically."""
    options = options_json(args)
    data = {"scenario": SCENARIO, "options": options, "machine": info, "complete": complete,
            "summary": summary_rows(records), "runs": records}
    write_json_atomic(path, data)


def summarize_file(path: Path) -> str:
    data = json.loads(path.read_text())
    state = "" if data["complete"] else " (incomplete: the bench was stopped)"
    return report(data["runs"], argparse.Namespace(**data["options"])) + state


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.summarize:
        print(summarize_file(args.summarize))
        return 0
    tasks = grid(args)
    with slowed(args.slowdown):
        info = machine()
        done: list[dict | None] = [None] * len(tasks)  # in grid order, whatever order runs end
        progress = Progress(len(tasks))
        t0 = time.perf_counter()
        for k, (i, record) in enumerate(run_tasks(run_one, tasks, args.workers, args.scheduler),
                                        1):
            done[i] = record
            progress.advance(progress_line(k, len(tasks), record))
            records = [r for r in done if r is not None]
            write_json(args.json, args, records, info, complete=k == len(tasks))
    text = report(records, args) + footer(info, t0)
    write_report(args.json, text)
    bad = sum(r["status"] == "verify_failed" for r in records)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
