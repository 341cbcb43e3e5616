"""The whole task in one plan against sequential transportation on the same scene (issue 53).

What it measures: for n objects of ``table1_vd`` (``random_objects.count`` n, drawn from the seed),
each rule and seed, the scene planned twice through :func:`dualarm_mpc.plan` (every plan verified
by ``verify.py``): as one task (:func:`dualarm_mpc.whole_task`, ``plan --mo all``: m_o = n_o = n,
one exact search over every object, anytime from sequential transportation's plan at
``task.FIRST_PASS`` joined into one step) and by sequential transportation with ``--sequential``
(m_o, n_o) (Algorithm 1, n_o at most n). Per plan: wall time until the first plan was verified
(``first_plan_s``) and until the run ended (``wall_time_s``), whether the plan is the search's or
still the first (``joined``: sequential transportation's, at (m_o, n_o) ``joined_row``:
``task.FIRST_PASS``, or ``task.LARGER_STEPS`` where that was shorter; ``guided``: the route-guided
plan, ``planning/guided.py``; ``shortened``: the steps taken out of either by re-timing its hands,
``planning/shorten.py``), cost (17), the proven bound and gap, whether every horizon is proven
minimal, the makespan (steps of Δt), the steps, and the skeleton search's work (``search_stats``
summed over the steps: expansions, prunes, programs, their wall time). What sequential
transportation gives away is the difference on the same scene. Delivery is ``rest`` (each object at
rest in its goal at the end of its step), not Table II's ``reach``: under ``reach`` an object may
pass through its goal, and the whole plan then needs a second step, so it would not be one plan nor
its certificate the task's. Under ``rest`` the steps of sequential transportation, joined, are a
plan of the whole task, so its makespan is never below the whole plan's proven-minimal horizon. A
plan that outlasts ``--run-budget`` is stopped (``stopped``): the best complete plan so far is the
record's, with its gap (the whole task's first plan where the search found none better; under rule
2 the sequential plan's first pass, each step's no-throw witness, docs/search.md); without a
complete plan the run is counted apart. Records written before the whole task's first plan
(2026-12-06) have no ``joined``: their plans are the search's, and their first plan its.

Run it (from the repository root)::

    .venv/bin/python bench/whole.py                                  # n = 3, 4; rule 1; seeds 0-9
    .venv/bin/python bench/whole.py --objects 5 --rules 1 2 --seeds 0-2 --run-budget 300

The Markdown tables go to stdout and next to the JSON (``--json``, default
bench/results/whole.json, rewritten after every run).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time
from pathlib import Path

from benchlib import (
    Progress,
    fmt,
    footer,
    machine,
    options_json,
    parse_seeds,
    table,
    write_json_atomic,
    write_report,
)
from table2 import SCENARIO, parse_row

import dualarm_mpc as dm

METHODS = ("whole", "sequential")
STATS = ("expansions", "prunes", "programs", "leaf_time_s")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--objects", nargs="+", type=int, default=[3, 4], metavar="N",
                   help="numbers of objects of the scene (default 3 4)")
    p.add_argument("--rules", nargs="+", type=int, choices=(1, 2), default=[1])
    p.add_argument("--seeds", type=parse_seeds, default=list(range(10)),
                   help="0-9, 0,3,7 or a count (default 0-9)")
    p.add_argument("--sequential", type=parse_row, default=(2, 5), metavar="M,N",
                   help="(m_o, n_o) of sequential transportation, n_o at most the objects "
                        "(default 2,5: Table II's first row)")
    p.add_argument("--time-limit", type=float, default=30.0, help="seconds per horizon")
    p.add_argument("--run-budget", type=float, default=600.0, metavar="S",
                   help="stop a plan after S s of wall time (default 600)")
    p.add_argument("--json", type=Path, default=Path("bench/results/whole.json"))
    return p.parse_args(argv)


def scenario_of(n: int, rule: int, seed: int, method: str, args: argparse.Namespace):
    m_o, n_o = args.sequential
    scenario = dm.load_scenario(SCENARIO, {
        "seed": seed, "random_objects": {"count": n}, "rule": rule, "delivery": "rest",
        "m_o": min(m_o, n), "n_o": min(n_o, n), "solver": {"time_limit_s": args.time_limit}})
    return dm.whole_task(scenario) if method == "whole" else scenario


def plan_one(n: int, rule: int, seed: int, method: str, args: argparse.Namespace) -> dict:
    """One verified plan and its certificate, or why there is none; never raises."""
    record = {"objects": n, "rule": rule, "seed": seed, "method": method, "status": "error",
              "message": ""}
    stop = dm.Interrupt()
    budget = threading.Timer(args.run_budget, stop.set)
    t0 = time.perf_counter()
    try:
        scenario = scenario_of(n, rule, seed, method, args)
        budget.start()
        plan = dm.plan(scenario, check_first=False, stop=stop)
        if plan.partial:  # stopped before any complete plan
            record.update(status="run_budget", message=f"stopped after {args.run_budget:g} s")
        else:  # stopped or not, a complete verified plan (the anytime plan's first, if stopped)
            stats = [s.search_stats or {} for s in plan.segments]
            record.update(
                status="ok", cost=plan.total_cost, bound=plan.total_bound, gap=plan.gap,
                horizon_proven_minimal=plan.horizon_proven_minimal,
                first_plan_s=plan.first_plan_s, solve_time_s=plan.total_solve_time_s,
                makespan=plan.trajectory.steps, steps=len(plan.segments),
                horizons=[s.horizon for s in plan.segments], stopped=stop.is_set(),
                joined=plan.segments[0].sequential_steps is not None,
                joined_row=plan.segments[0].sequential_row,
                guided=plan.segments[0].guided, shortened=plan.segments[0].shortened,
                least_horizon=least_horizon(plan),
                **{k: sum(s.get(k, 0) for s in stats) for k in STATS})
    except dm.VerificationError as err:
        record.update(status="verify_failed", message="; ".join(err.problems))
    except dm.PlanningError as err:
        record.update(status="run_budget" if stop.is_set() else "planning_error",
                      message=str(err))
    finally:
        budget.cancel()
    record["wall_time_s"] = time.perf_counter() - t0
    record["load_avg_1min"] = os.getloadavg()[0]
    return record


def least_horizon(plan: dm.Plan) -> int | None:
    """Of a plan in one step: the least horizon not proven to have no plan (a lower bound of
    the whole task's makespan; the plan's own where its horizon is proven minimal)."""
    if len(plan.segments) != 1:
        return None
    step = plan.segments[0]
    return min(step.horizons_undecided, default=step.horizon)


# --- report ------------------------------------------------------------------------------------


def mean(runs: list[dict], key: str, spec: str) -> str:
    return fmt(statistics.fmean(r[key] for r in runs) if runs else None, spec)


def summary_table(runs: list[dict]) -> str:
    """Per (n, rule): the whole plans (verified, proven, time, work) and both methods' means
    over the seeds where both gave a verified plan."""
    header = ["objects", "rule", "whole: verified plans", "the search's own",
              "proven optimal at a proven-minimal horizon", "largest gap",
              "mean time to the first verified plan (s)", "mean time (s)",
              "mean expansions / prunes / programs", "mean leaf time (s)", "sequential: "
              "verified plans", "mean time (s)", "paired seeds", "mean cost, whole / sequential",
              "mean makespan (Δt), whole / sequential"]
    rows = []
    for n, rule in sorted({(r["objects"], r["rule"]) for r in runs}):
        of = {m: {r["seed"]: r for r in runs if (r["objects"], r["rule"], r["method"])
                  == (n, rule, m)} for m in METHODS}
        whole = [r for r in of["whole"].values() if r["status"] == "ok"]
        seq = [r for r in of["sequential"].values() if r["status"] == "ok"]
        both = [(of["whole"][s], of["sequential"][s]) for s in sorted(of["whole"])
                if of["whole"][s]["status"] == "ok" and
                of["sequential"].get(s, {}).get("status") == "ok"]
        proven = sum(r["gap"] <= 1e-4 and r["horizon_proven_minimal"] for r in whole)
        searched = [r for r in whole if not r.get("joined") and not r.get("guided")]
        pair = [w for w, _ in both], [s for _, s in both]
        rows.append([
            str(n), str(rule), f"{len(whole)}/{len(of['whole'])}",
            f"{len(searched)}/{len(whole)}", f"{proven}/{len(whole)}",
            fmt(max((r["gap"] for r in whole), default=None), ".3f"),
            mean(whole, "first_plan_s", ".1f"), mean(whole, "wall_time_s", ".1f"),
            " / ".join(mean(whole, k, ".0f") for k in STATS[:3]),
            mean(whole, "leaf_time_s", ".1f"), f"{len(seq)}/{len(of['sequential'])}",
            mean(seq, "first_plan_s", ".1f"), str(len(both)),
            f"{mean(pair[0], 'cost', '.3f')} / {mean(pair[1], 'cost', '.3f')}",
            f"{mean(pair[0], 'makespan', '.1f')} / {mean(pair[1], 'makespan', '.1f')}"])
    return table(header, rows)


def makespan(r: dict) -> str:
    """The whole plan's makespan, with the least the search left possible where it is less."""
    least = r.get("least_horizon")
    return f"{r['makespan']} (≥ {least})" if least is not None and least < r["makespan"] \
        else str(r["makespan"])


def origin(r: dict) -> str:
    """Whose the whole plan is: the search's, or still a first plan's."""
    taken = r.get("shortened")  # not in records before planning/shorten.py
    shortened = f", re-timed (−{taken} Δt)" if taken else ""
    if r.get("joined"):
        row = r.get("joined_row")  # not in records before task.LARGER_STEPS
        return ("sequential's, joined" if row is None else
                f"sequential ({row[0]},{row[1]}), joined") + shortened
    return "route-guided" + shortened if r.get("guided") else "the search's"


def seed_table(runs: list[dict]) -> str:
    """Per scene: each method's cost, makespan and time (what the decomposition gives away)."""
    by = {(r["objects"], r["rule"], r["seed"], r["method"]): r for r in runs}
    header = ["objects", "rule", "seed", "whole: plan", "cost", "gap",
              "makespan (Δt; ≥ the least not proven empty)",
              "first plan (s)", "time (s)", "sequential: cost", "makespan (Δt)", "time (s)"]
    rows = []
    for n, rule, seed in sorted({k[:3] for k in by}):
        cells = [str(n), str(rule), str(seed)]
        for method in METHODS:
            r = by.get((n, rule, seed, method), {"status": "not run"})
            if r["status"] != "ok":
                cells += [r["status"]] + ["—"] * (5 if method == "whole" else 2)
                continue
            if method == "whole":
                cells += [origin(r),
                          f"{r['cost']:.3f}", f"{r['gap']:.3f}", makespan(r),
                          f"{r['first_plan_s']:.1f}", f"{r['wall_time_s']:.1f}"]
            else:
                cells += [f"{r['cost']:.3f}", str(r["makespan"]), f"{r['first_plan_s']:.1f}"]
        rows.append(cells)
    return table(header, rows)


def report(data: dict) -> str:
    o = data["options"]
    m_o, n_o = o["sequential"]
    head = (f"{SCENARIO}, delivery rest: the whole task in one plan (`plan --mo all`) against "
            f"sequential transportation ({m_o},{n_o}) (n_o at most the objects) on the same "
            f"scenes; {o['time_limit']:g} s per horizon, {o['run_budget']:g} s a plan at most; "
            "one plan at a time:")
    return "\n".join([head, "", summary_table(data["runs"]), "", "Per scene:", "",
                      seed_table(data["runs"]), ""])


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t0 = time.perf_counter()
    data = {"scenario": SCENARIO, "options": options_json(args), "machine": machine(),
            "complete": False, "runs": []}
    grid = [(n, rule, seed, method) for n in args.objects for rule in args.rules
            for seed in args.seeds for method in METHODS]
    progress = Progress(len(grid))
    for k, (n, rule, seed, method) in enumerate(grid, 1):
        r = plan_one(n, rule, seed, method, args)
        data["runs"].append(r)
        data["complete"] = k == len(grid)
        write_json_atomic(args.json, data)
        what = (f"cost {r['cost']:.3f} gap {r['gap']:.3f} in {r['first_plan_s']:.1f} s"
                if r["status"] == "ok" else f"{r['status']}: {r['message'][:80]}")
        progress.advance(f"[{k}/{len(grid)}] n={n} rule {rule} seed {seed} {method}: {what}")
    write_report(args.json, report(data) + footer(data["machine"], t0))
    return 1 if any(r["status"] == "verify_failed" for r in data["runs"]) else 0


if __name__ == "__main__":
    sys.exit(main())
