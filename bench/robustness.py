"""Robustness of the closed loop on §V-D: seeded random disturbances, and what still gets delivered.

What it measures: for each rule and seed, the scenario ``table1_vd`` (ten objects uniform in
[-0.25, 0.25]² from the seed, reachable goals, its default (m_o, n_o)) with the robot's settings
(:func:`dualarm_mpc.model.scenario.on_robot_overrides`) runs closed loop while
:class:`dualarm_mpc.sim.disturbances.RandomDisturbances` disturbs it, once per kind by default
(``--per-kind``): an object knocked out of the hand that carries it (``held``), out of its goal
(``delivered``), anywhere on the table (``table``); a goal moved (``goal``). That module says
how they are drawn (seeded per run: both rules of a seed get the same disturbances; lockstep, so
the same on any machine, which ``--set 'solver.realtime: true'`` gives up) and when an object is
**stuck** (no plan within the model can deliver it from where a knock left it, or where it rests
when its goal moves; decided from the model's bounds at each event, never from how the run
ended). The run's stuck objects are those stuck after the last event.

Reported per rule (pooled over seeds) and per run:

* **delivered** — objects at rest (< 0.01 m/s) inside their goal box at the end, on the plant;
* **stuck** — as above; **reachable delivered** = delivered among the objects not stuck (the
  goal is all of them); **missed** names the reachable objects not delivered;
* **failed replans** — replans whose status is not a plan and not a planned wait: ``infeasible``,
  ``unbounded``, ``time_limit``, ``error``, ``no_horizon`` (a failed replan keeps the previous
  plan). **Over budget** (``searching``, ``over_budget``) are counted apart: the robot followed
  the plan in force or waited at rest while the search went on;
* **replan wall time** — p95 and max of the wall time each replan with work held the simulation
  (statuses ``done`` and ``stuck`` left out, as in bench/closed_loop.py).

Run it (from the repository root)::

    .venv/bin/python bench/robustness.py                          # rules 1, 2 x seeds 0-14
    .venv/bin/python bench/robustness.py --rules 2 --seeds 3 --per-kind 2
    .venv/bin/python bench/robustness.py --workers 2 --json bench/results/robustness.json
    .venv/bin/python bench/robustness.py --scheduler tcp://10.0.0.5:8786
    .venv/bin/python bench/robustness.py --summarize bench/results/robustness.json

One line per run (and per disturbance) goes to stderr; the Markdown tables to stdout and next to
the JSON (``--json``, default bench/results/robustness.json, rewritten after every run), which
keeps every run's record (every disturbance, every replan), the summary per rule, the machine and
the options. ``--workers N`` runs the runs as Dask tasks on a local cluster of N processes (each
search then on one thread), ``--scheduler ADDRESS`` on an existing cluster (needs ``pip install
'.[dask]'``); without either they run one after the other here. The report then says how many
runs shared a machine: in real time the replan budget is wall time, so runs on a loaded machine
may diverge.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import traceback
from pathlib import Path

import benchlib
import closed_loop
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
    table,
    write_json_atomic,
    write_report,
)
from closed_loop import NO_SOLVE, parse_set, percentiles, resting_in_goal, summary_record

from dualarm_mpc.model.scenario import (
    SOLVER_BACKENDS,
    Scenario,
    load_scenario,
    merge_overrides,
    on_robot_overrides,
)
from dualarm_mpc.sim.closed_loop import default_duration, simulate
from dualarm_mpc.sim.disturbances import KINDS, RandomDisturbances

SCENARIO = "table1_vd"
EXTRA_DURATION = 30.0  # simulated s added to simulate's default duration per disturbance
FAILED = ("infeasible", "unbounded", "time_limit", "error", "no_horizon")
OVER_BUDGET = ("searching", "over_budget")
LOST_NOTE = " can no longer reach the goal"  # the planner's "stuck" replan note ends so


# --- command line ------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=parse_seeds, default=list(range(15)),
                   help="0-14 (default), 0,3,7 or a count")
    p.add_argument("--rules", nargs="+", type=int, choices=(1, 2), default=[1, 2])
    p.add_argument("--per-kind", type=int, default=1,
                   help="disturbances of each kind per run (default 1: four per run)")
    p.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    p.add_argument("--time-limit", type=float, default=None,
                   help="seconds per MILP solve (default: the scenario's, 30 s)")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated seconds at most per run (default: simulate's by object count "
                        f"plus {EXTRA_DURATION:g} s per disturbance)")
    p.add_argument("--set", action="append", type=parse_set, default=[], metavar="YAML",
                   help="extra scenario overrides, applied last (repeatable)")
    p.add_argument("--solver", choices=SOLVER_BACKENDS, default="highs",
                   help="the MILP solver (default highs)")
    cluster_arguments(p)
    p.add_argument("--json", type=Path, default=Path("bench/results/robustness.json"))
    p.add_argument("--summarize", type=Path, metavar="JSON",
                   help="print the tables of an earlier (possibly partial) run's JSON; run nothing")
    p.add_argument("--quiet", action="store_true", help="no per-replan lines on stderr")
    args = p.parse_args(argv)
    if args.per_kind < 1:
        p.error("--per-kind must be >= 1")
    check_cluster_arguments(p, args)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        p.error(f"--duration: must be a positive number, got {args.duration}")
    return args


# --- one run -----------------------------------------------------------------------------------


def scenario_for(rule: int, seed: int, task: dict) -> Scenario:
    """``table1_vd`` with the robot's settings, this run's rule and seed, then ``--set``."""
    out = {**on_robot_overrides(load_scenario(SCENARIO)), "rule": rule, "seed": seed}
    solver = {"backend": task.get("solver", "highs")}
    if task["time_limit"] is not None:
        solver["time_limit_s"] = task["time_limit"]
    if task["shared_machine"]:
        solver["workers"] = 1  # the runs share the cores already
    out["solver"] = solver
    for more in task["set"]:
        merge_overrides(out, more)
    return load_scenario(SCENARIO, out)


def run_one(task: dict) -> dict:
    """Simulate one (rule, seed) with its disturbances; always returns a record, never raises."""
    rule, seed = task["rule"], task["seed"]
    record = {"rule": rule, "seed": seed, "status": "error", "message": "",
              "shared_machine": task["shared_machine"]}
    tag = f"rule {rule} seed {seed}"

    def progress(r) -> None:
        if not task["quiet"]:
            print(f"  {tag}: t {r.t:6.1f}  delivered {r.n_delivered:>2}  {r.status:<11} "
                  f"{r.wall_s:6.3f} s" + (f"  ({r.note})" if r.note else ""),
                  file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    disturb = None
    try:
        scenario = scenario_for(rule, seed, task)
        disturb = RandomDisturbances(scenario, seed, task["per_kind"], tuple(task["kinds"]))
        duration = task["duration"] or (default_duration(scenario)
                                        + EXTRA_DURATION * len(disturb.schedule))
        record.update(m_o=scenario.task.m_o, n_o=scenario.task.n_o, n_objects=scenario.n_objects,
                      time_limit_s=scenario.solver.time_limit_s, duration_s=duration,
                      objects=[{"name": o.name, "position": o.position, "goal": o.goal}
                               for o in scenario.task.objects],
                      planned=[{"kind": d.kind, "due": d.due} for d in disturb.schedule])
        summary = simulate(scenario, duration, progress=progress, disturb=disturb)
    except Exception:  # a bug in one run must not end the bench: record it and go on
        record["message"] = traceback.format_exc(limit=6)
        record["wall_time_s"] = time.perf_counter() - t0
        if disturb is not None:
            record["disturbances"] = disturb.log
        return record
    names = [o["name"] for o in summary.objects]
    resting = resting_in_goal(summary)
    stuck = {names[j]: r for j, r in sorted(disturb.stuck.items())}
    missed = [names[j] for j in range(len(names)) if not resting[j] and names[j] not in stuck]
    note = next((r["note"] for r in reversed(summary.replans) if r["status"] == "stuck"), "")
    lost = sorted(n.strip() for n in note.removesuffix(LOST_NOTE).split(",") if n.strip())
    record.update(
        summary_record(summary),
        stuck=stuck,
        stuck_delivered=sum(resting[names.index(n)] for n in stuck),
        missed=missed,
        planner_lost=lost,  # the objects the planner itself gave up on at the end
        timed_out=summary.sim_time_s >= duration - 1e-6,
        disturbances=disturb.log,
        failed_replans=sum(r["status"] in FAILED for r in summary.replans),
        failed_replan_log=[r for r in summary.replans if r["status"] in FAILED],
        final_goals=summary.goals,
    )
    return record


def describe(e: dict) -> str:
    if "skipped" in e:
        return f"{e['kind']} at {e['t']:.1f} s: skipped ({e['skipped']})"
    if e["kind"] == "goal":
        what = f"goal {e['target']} → {e['to']}"
    else:
        what = f"{e['target']} {e['from']} → {e['to']}" + (" out of the hand" if e.get(
            "was_held") else "")
    stuck = e.get("stuck")
    return f"{e['kind']} at {e['t']:.1f} s: {what}" + (f" — STUCK: {stuck}" if stuck else "")


def run_line(k: int, n: int, r: dict) -> str:
    head = f"[{k}/{n}] rule {r['rule']} seed {r['seed']}"
    if r["status"] != "ok":
        return f"{head}: ERROR after {r['wall_time_s']:.0f} s: " \
               f"{r['message'].strip().splitlines()[-1]}"
    w = r["replan_wall_s"]
    lines = [f"{head}: {r['delivered']}/{r['n_objects']} delivered, {len(r['stuck'])} stuck, "
             f"missed {', '.join(r['missed']) or 'none'}; sim {r['sim_time_s']:.0f} s"
             + (" (TIMED OUT)" if r["timed_out"] else "")
             + f", failed replans {r['failed_replans']}, over budget {r['replans_over_budget']}, "
             f"replan p95 {fmt(w['p95'], '.2f')} max {fmt(w['max'], '.2f')} s"]
    lines += [f"    {describe(e)}" for e in r["disturbances"]]
    lost = r.get("planner_lost", [])
    if sorted(r["stuck"]) != lost:
        lines.append(f"    the planner gave up on {', '.join(lost) or 'nothing'}")
    return "\n".join(lines)


# --- summary -----------------------------------------------------------------------------------


def summarize(records: list[dict], rule: int) -> dict:
    runs = [r for r in records if r["rule"] == rule]
    ok = [r for r in runs if r["status"] == "ok"]
    objects = sum(r["n_objects"] for r in ok)
    delivered = sum(r["delivered"] for r in ok)
    stuck = sum(len(r["stuck"]) for r in ok)
    reachable = objects - stuck
    reachable_delivered = delivered - sum(r["stuck_delivered"] for r in ok)
    walls = [x["wall_s"] for r in ok for x in r["replan_log"] if x["status"] not in NO_SOLVE]
    events = [e for r in ok for e in r["disturbances"]]
    return {
        "rule": rule, "runs": len(runs), "ok": len(ok), "objects": objects,
        "delivered": delivered, "delivered_share": delivered / objects if objects else None,
        "stuck": stuck, "stuck_share": stuck / objects if objects else None,
        "reachable": reachable, "reachable_delivered": reachable_delivered,
        "reachable_delivered_share": reachable_delivered / reachable if reachable else None,
        "missed": [f"seed {r['seed']}: {n}" for r in ok for n in r["missed"]],
        "runs_all_reachable_delivered": sum(not r["missed"] for r in ok),
        # runs where the planner gave up on other objects than those counted stuck here
        "runs_planner_disagrees": sum(sorted(r["stuck"]) != r.get("planner_lost", []) for r in ok),
        "timed_out": sum(r["timed_out"] for r in ok),
        "replans": sum(r["replans"] for r in ok),
        "failed_replans": sum(r["failed_replans"] for r in ok),
        "replans_over_budget": sum(r["replans_over_budget"] for r in ok),
        "replan_wall_s": percentiles(walls),
        "disturbances": {k: sum(e["kind"] == k and "skipped" not in e for e in events)
                         for k in KINDS},
        "skipped": sum("skipped" in e for e in events),
        "mean_sim_time_s": sum(r["sim_time_s"] for r in ok) / len(ok) if ok else None,
        "shared_machine": any(r.get("shared_machine") for r in runs),
        "runs_per_host": max((r.get("runs_per_host", 1) for r in runs), default=1),
    }


def machine_use(runs_per_host: int) -> str:
    """Whether a rule's runs had their machine to themselves."""
    return "alone" if runs_per_host <= 1 else f"{runs_per_host} runs per machine at once"


def share(n: int, d: int) -> str:
    return f"{n}/{d} ({100 * n / d:.1f} %)" if d else "—"


def main_table(summary: list[dict]) -> str:
    header = ["rule", "runs", "disturbances held / delivered / table / goal (skipped)",
              "objects delivered", "stuck (beyond reach)", "reachable delivered",
              "failed replans / replans", "over budget", "replan wall p95 / max (s)",
              "mean sim time (s)", "times taken"]
    rows = []
    for s in summary:
        d = s["disturbances"]
        w = s["replan_wall_s"]
        rows.append([str(s["rule"]), f"{s['ok']}/{s['runs']}",
                     f"{d['held']} / {d['delivered']} / {d['table']} / {d['goal']} "
                     f"({s['skipped']})",
                     share(s["delivered"], s["objects"]), share(s["stuck"], s["objects"]),
                     share(s["reachable_delivered"], s["reachable"]),
                     f"{s['failed_replans']}/{s['replans']}", str(s["replans_over_budget"]),
                     f"{fmt(w['p95'], '.2f')} / {fmt(w['max'], '.2f')}",
                     fmt(s["mean_sim_time_s"], ".0f"), machine_use(s["runs_per_host"])])
    return table(header, rows)


def detail_table(records: list[dict]) -> str:
    header = ["rule", "seed", "delivered", "stuck", "missed (reachable, not delivered)",
              "failed replans", "over budget", "replan wall p95 / max (s)", "sim time (s)",
              "disturbances"]
    rows = []
    for r in sorted(records, key=lambda r: (r["rule"], r["seed"])):
        if r["status"] != "ok":
            rows.append([str(r["rule"]), str(r["seed"]), "error", "—", "—", "—", "—", "—", "—",
                         r["message"].strip().splitlines()[-1]])
            continue
        w = r["replan_wall_s"]
        events = "; ".join(describe(e) for e in r["disturbances"])
        rows.append([str(r["rule"]), str(r["seed"]), f"{r['delivered']}/{r['n_objects']}",
                     ", ".join(f"{n} ({why})" for n, why in r["stuck"].items()) or "—",
                     ", ".join(r["missed"]) or "—", str(r["failed_replans"]),
                     str(r["replans_over_budget"]),
                     f"{fmt(w['p95'], '.2f')} / {fmt(w['max'], '.2f')}",
                     f"{r['sim_time_s']:.0f}" + (" (timed out)" if r["timed_out"] else ""),
                     events])
    return table(header, rows)


def report(records: list[dict], options: dict) -> str:
    summary = [summarize(records, rule) for rule in options["rules"]]
    most = max((r.get("runs_per_host", 1) for r in records), default=1)
    shared = (f"up to {most} runs at once on a machine: timings measured on a shared machine"
              if most > 1 else "one run at a time")
    first = next((r for r in records if "m_o" in r), {})
    extra = "".join(f", {json.dumps(e)}" for e in options["set"])
    head = (f"Robustness, {SCENARIO} closed loop, (m_o, n_o) = ({first.get('m_o', '—')}, "
            f"{first.get('n_o', '—')}), the robot's settings{extra}; {options['per_kind']} "
            f"disturbance(s) of each kind per run ({', '.join(options['kinds'])}); {shared}. "
            f"Shares are of all objects; reachable = not stuck. Failed replans: status "
            f"{', '.join(FAILED)}; over budget: {', '.join(OVER_BUDGET)}. Replan wall time over "
            f"replans with work (not done/stuck), pooled per rule.")
    missed = [f"rule {s['rule']}: {', '.join(s['missed'])}" for s in summary if s["missed"]]
    parts = [head, "", main_table(summary), ""]
    parts += ["Reachable objects not delivered: " + ("; ".join(missed) if missed else "none")
              + ". Runs where the planner gave up on other objects than those counted stuck: "
              + ", ".join(f"rule {s['rule']}: {s['runs_planner_disagrees']}" for s in summary)
              + ".", ""]
    parts += ["Detail:", "", detail_table(records), ""]
    return "\n".join(parts)


# --- output ------------------------------------------------------------------------------------


def write_json(path: Path, args: argparse.Namespace, records: list[dict], info: dict,
               complete: bool) -> None:
    """Written after every run (``complete`` false until the last), atomically."""
    data = {"scenario": SCENARIO, "options": options_json(args), "machine": info,
            "complete": complete, "summary": [summarize(records, r) for r in args.rules],
            "runs": records}
    write_json_atomic(path, data)


def summarize_file(path: Path) -> str:
    data = json.loads(path.read_text())
    state = "" if data["complete"] else "\n(incomplete: the bench was stopped)\n"
    return report(data["runs"], data["options"]) + state


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.summarize:
        print(summarize_file(args.summarize))
        return 0
    shared = args.workers > 1 or args.scheduler is not None
    tasks = [{"rule": rule, "seed": seed, "per_kind": args.per_kind, "kinds": args.kinds,
              "time_limit": args.time_limit, "duration": args.duration, "set": args.set,
              "solver": args.solver, "shared_machine": shared, "quiet": args.quiet or shared}
             for rule in args.rules for seed in args.seeds]
    info = machine()
    done: list[dict | None] = [None] * len(tasks)  # in task order, whatever order runs end in
    progress = Progress(len(tasks))
    helpers = tuple(Path(m.__file__) for m in (benchlib, closed_loop))  # for a remote cluster
    t0 = time.perf_counter()
    for k, (i, record) in enumerate(run_tasks(run_one, tasks, args.workers, args.scheduler,
                                              helpers), 1):
        done[i] = record
        progress.advance(run_line(k, len(tasks), record))
        records = [r for r in done if r is not None]
        write_json(args.json, args, records, info, complete=k == len(tasks))
    text = report(records, options_json(args)) + footer(info, t0)
    write_report(args.json, text)
    bad = any(r["status"] != "ok" or r["missed"] for r in records)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
