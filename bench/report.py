"""Every benchmark table of README.md and docs/*.md, regenerated from the committed records.

The records are the JSON files the benches write to bench/results/: one file per invocation of a
bench, with its options, the machine (date, cores, code, and its speed at the start by
``benchlib.calibration``) and every run. A table lives in a Markdown file between two marker
comments, the first naming what it shows::

    <!-- report table2-m2.json -->
    (generated: never edit by hand)
    <!-- /report -->

A file name renders that file as its bench's own report does (``--summarize``), the bench told
by the name's start (``table2``, ``solvers``, ``closed_loop``, ``robustness``, ``horizons``,
``demo``, ``install``, ``whole``); ``paper`` is Table II of the paper beside ours, pooled over every
``table2*.json``; ``clearance`` is what ``object_clearance`` costs and saves, from
``table2-m2-apart.json`` and the two closed-loop records (``closed_loop.json``: objects apart,
``closed_loop-points.json``); ``clock`` is the closed loop on the clock, one row per
``closed_loop-clock-*.json`` (lockstep or real time, the latency, other processes kept busy);
``robots`` is each Panda scene on the Panda pair and on our SCARA, beside the SCARA's full-size
scene (``closed_loop-robots.json``).
Every table ends with the records it comes from: their date and the
machine's speed.

Run it (from the repository root)::

    .venv/bin/python bench/report.py            # rewrite the tables
    .venv/bin/python bench/report.py --check    # exit 1 if a committed table differs

Exit status: 0 done (or, with ``--check``, every table equal), 1 a table differs (``--check``),
2 a marker names no record or the records disagree.
"""

from __future__ import annotations

import argparse
import importlib
import json
import re
import sys
from pathlib import Path

import numpy as np
from benchlib import fmt, table

ROOT = Path(__file__).resolve().parent.parent
BLOCK = re.compile(r"(<!-- report (\S+) -->\n)(.*?)(<!-- /report -->)", re.DOTALL)
BENCHES = ("table2", "solvers", "closed_loop", "robustness", "horizons", "demo", "install",
           "whole")


class RecordError(Exception):
    """A marker that names no record, or records that disagree: one line, exit 2."""


# --- one results file --------------------------------------------------------------------------


def load(results: Path, name: str) -> dict:
    path = results / name
    if not path.is_file():
        raise RecordError(f"{path}: no such record (a marker names it)")
    return json.loads(path.read_text())


def bench_of(name: str) -> str:
    for bench in BENCHES:
        if name.startswith(bench):
            return bench
    raise RecordError(f"{name}: not the record of a bench (names start with "
                      f"{', '.join(BENCHES)})")


def render_file(results: Path, name: str, commit: bool = True) -> str:
    """The file's tables as its bench prints them, then where they come from (the code's commit
    with ``commit``: in docs, not in the README)."""
    data = load(results, name)
    bench = bench_of(name)
    module = importlib.import_module(bench)  # closed_loop and robustness import Drake: only here
    options = data["options"]
    if bench == "table2":
        text = module.report(data["runs"], argparse.Namespace(**options))
    elif bench == "solvers":
        text = module.report(data["solves"], argparse.Namespace(**options))
    elif bench == "closed_loop":
        text = module.report(data["runs"], argparse.Namespace(**options))
    elif bench == "robustness":
        text = module.report(data["runs"], options)
    else:
        text = module.report(data)
    return text.rstrip("\n") + "\n\n" + provenance(name, data, commit=commit) + "\n"


def provenance(name: str, data: dict, commit: bool) -> str:
    """Where a table comes from: the file, when, the machine's speed; the code's commit in docs
    (``commit``), not in the README."""
    m = data["machine"]
    c = m["calibration"]
    parts = [m.get("date", "date not recorded").replace("T", " ").replace("+00:00", " UTC"),
             f"{m['cpu_count']} cores",
             f"machine speed at the start (`benchlib.calibration`, lower is faster): Python loop "
             f"{c['python_loop_s']:.3f} s, HiGHS knapsack {c['highs_knapsack_s']:.3f} s"]
    runs = data.get("runs") or data.get("solves") or data.get("installs") or []
    loads = [r["load_avg_1min"] for r in runs if r.get("load_avg_1min") is not None]
    if loads:
        parts.append(f"load average {min(loads):.1f}–{max(loads):.1f} during the runs")
    if commit and m.get("git_commit"):
        parts.append(f"code {m['git_commit'][:7]}" + (" with uncommitted changes"
                                                       if m.get("git_changes") else ""))
    if not data.get("complete", True):
        parts.append("incomplete: the bench was stopped")
    return f"Records: [`bench/results/{name}`](../bench/results/{name}) ({'; '.join(parts)})."


# --- Table II against the paper ----------------------------------------------------------------


def render_paper(results: Path) -> str:
    """Our Table II beside the paper's, every ``table2*.json`` pooled (one run per row, rule,
    horizon policy and seed: a run recorded twice is an error), counting form and skeleton search
    only; a row per horizon policy and second prover (records older than ``solver.horizons`` ran
    ``exact``, those older than ``solver.prover`` none)."""
    table2 = importlib.import_module("table2")
    records = {p.name: load(results, p.name) for p in sorted(results.glob("table2*.json"))}
    runs, seen = [], {}
    # a comparison of object_clearance has its own table, and so has a slowed machine
    records = {name: data for name, data in records.items()
               if all(data["options"].get(k) is None for k in ("apart", "slowdown"))}
    for name, data in records.items():
        for r in data["runs"]:
            if r["task_form"] != "counting" or r["search"] != "skeleton":
                continue
            r = {**r, "horizons": r.get("horizons", "exact") + (
                " + CP-SAT" if r.get("prover", "none") == "cpsat" else "")}
            key = (r["m_o"], r["n_o"], r["rule"], r["horizons"], r["seed"])
            if key in seen:
                raise RecordError(f"({key[0]},{key[1]}) rule {key[2]} horizons {key[3]} seed "
                                  f"{key[4]} is in both {seen[key]} and {name}: keep one")
            seen[key] = name
            runs.append(r)
    header = ["(m_o,n_o)", "rule", "horizons", "seeds", "verified plans", "our mean cost",
              "paper cost", "proven gap", "our mean time (s)",
              "time to the first verified plan (s)", "paper time (s)", "our mean CPU time (s)",
              "steps proven optimal"]
    rows = []
    policies = sorted({r["horizons"] for r in runs}, reverse=True)  # witness (default), exact
    summaries = [(policy, s) for policy in policies
                 for s in table2.summary_rows([r for r in runs if r["horizons"] == policy])]
    summaries.sort(key=lambda ps: (ps[1]["m_o"], ps[1]["n_o"], ps[1]["rule"],
                                   policies.index(ps[0])))
    for policy, s in summaries:
        seeds = sorted(r["seed"] for r in runs if (r["m_o"], r["n_o"], r["rule"], r["horizons"])
                       == (s["m_o"], s["n_o"], s["rule"], policy))
        rows.append([f"({s['m_o']},{s['n_o']})", str(s["rule"]), policy, seed_text(seeds),
                     f"{s['ok']}/{s['runs']}", fmt(s["mean_cost"], ".3f"), fmt(s["paper_cost"]),
                     fmt(s["mean_gap"], ".3f"), fmt(s["mean_time_s"], ".1f"),
                     fmt(s["mean_first_plan_s"], ".1f"),
                     fmt(s["paper_time_s"], ".4g"), fmt(s["mean_cpu_time_s"], ".1f"),
                     f"{s['steps_optimal']}/{s['steps']}"])
    sources = [provenance(name, data, commit=False) for name, data in records.items()]
    return (table(header, rows) + "\n\n" + "\n".join(f"- {s}" for s in sources) + "\n")


# --- objects kept apart against points ---------------------------------------------------------

CLEARANCE_RECORDS = ("table2-m2-apart.json", "closed_loop-points.json", "closed_loop.json")


def render_clearance(results: Path) -> str:
    """``object_clearance`` side by side with the paper's point objects: the plan time and cost
    on Table II (2,·) (runs paired by seed, both verified) and, in the §V-D closed loop, the
    object contacts, the replans left without a plan, the objects delivered and the deepest
    any hand went into a box."""
    apart = load(results, CLEARANCE_RECORDS[0])
    clearance = apart["options"]["apart"]
    pairs: dict[int, list] = {}  # rule → (points, apart) runs over the rows
    for (_, _, rule, _), runs in sorted(importlib.import_module("table2").apart_pairs(
            apart["runs"]).items()):
        pairs.setdefault(rule, []).extend(runs)
    loops = []  # points, then apart: the closed loop with each
    for name, expected in zip(CLEARANCE_RECORDS[1:], (None, clearance), strict=True):
        runs = load(results, name)["runs"]
        if {r.get("object_clearance") for r in runs} != {expected}:
            raise RecordError(f"{name}: not every run has object_clearance {expected}, "
                              f"the table's")
        loops.append(runs)
    rows = []
    for rule, runs in pairs.items():
        mean = [sum(p[i]["solve_time_s"] for p in runs) / len(runs) for i in (0, 1)]
        cost = [sum(p[i]["cost"] for p in runs) / len(runs) for i in (0, 1)]
        rows.append([f"Table II (2,·) rule {rule}: mean plan time ({len(runs)} plans)",
                     f"{mean[0]:.1f} s", f"{mean[1]:.1f} s ({mean[1] / mean[0]:.1f}×)"])
        rows.append([f"Table II (2,·) rule {rule}: mean cost", f"{cost[0]:.3f}",
                     f"{cost[1]:.3f} (+{100 * (cost[1] / cost[0] - 1):.0f} %)"])
    for label, count in (
            ("pairs of objects that touched while one moved", lambda r: len(r["object_contacts"])),
            ("replans that found no plan", lambda r: r["replans_without_plan"]),
            ("objects at rest in their goals", lambda r: r["delivered"])):
        cells = []
        for runs in loops:
            total = sum(count(r) for r in runs)
            cells.append(f"{total}/{sum(r['n_objects'] for r in runs)}"
                         if label.startswith("objects") else str(total))
        rows.append([f"§V-D closed loop ({len(loops[1])} runs): {label}", *cells])
    deepest = [max((r.get("max_hand_penetration_m") for r in runs),  # older runs have none
                   key=lambda d: float("inf") if d is None else d) for runs in loops]
    rows.append([f"§V-D closed loop ({len(loops[1])} runs): deepest hand into a box",
                 *("not recorded" if d is None else f"{1000 * d:.1f} mm" for d in deepest)])
    header = ["", "objects as points (the paper's)", f"objects {100 * clearance:g} cm apart"]
    sources = [provenance(name, load(results, name), commit=False) for name in CLEARANCE_RECORDS]
    return table(header, rows) + "\n\n" + "\n".join(f"- {s}" for s in sources) + "\n"


CLOCK_RECORDS = "closed_loop-clock-*.json"


def render_clock(results: Path) -> str:
    """The closed loop on the clock (issue 49): per record, one configuration (lockstep or real
    time, the replan latency, how many other processes were kept busy) over the same runs (§V-C
    rule 2, §V-D seeds and rules): objects delivered, simulated time against lockstep's without
    latency, the seconds the robot stood waiting for a search, and the replans' wall times."""
    names = sorted(p.name for p in results.glob(CLOCK_RECORDS))
    if not names:
        raise RecordError(f"{results}/{CLOCK_RECORDS}: no record (the clock marker needs one)")
    data = {name: load(results, name) for name in names}

    def key(r: dict) -> tuple:
        return r["scene"], r["rule"], r["seed"]

    base = {}  # the lockstep runs without latency: what each run's time is held against
    for d in data.values():
        for r in d["runs"]:
            if r["status"] == "ok" and r["mode"] == "lockstep" and r["latency_s"] == 0:
                base[key(r)] = r["sim_time_s"]
    rows = []
    for d in data.values():
        ok = [r for r in d["runs"] if r["status"] == "ok"]
        if not ok:
            continue
        latency = {r["latency_s"] for r in ok}
        walls = [x["wall_s"] for r in ok for x in r["replan_log"]
                 if x["status"] not in ("done", "stuck")]
        ratios = [r["sim_time_s"] / base[key(r)] for r in ok if key(r) in base]
        busy = d["options"].get("busy", 0)
        rows.append([
            f"{ok[0]['mode']}, latency {', '.join(f'{v:g}' for v in sorted(latency))} s"
            + (f", beside {busy} busy processes" if busy else ""),
            f"{len(ok)}", f"{sum(r['delivered'] for r in ok)}/{sum(r['n_objects'] for r in ok)}",
            f"{sum(r['sim_time_s'] for r in ok) / len(ok):.1f}",
            f"{max(ratios):.2f}×" if ratios else "—",
            f"{sum(r.get('waiting_s', 0) for r in ok):g}",
            *(f"{v:.3f}" for v in np.percentile(walls, [50, 95])), f"{max(walls):.2f}"])
    header = ["configuration", "runs", "at rest in their goals", "mean simulated time (s)",
              "most against lockstep", "s waiting for a search", "replan wall p50 (s)",
              "p95 (s)", "max (s)"]
    sources = [provenance(name, d, commit=False) for name, d in data.items()]
    return table(header, rows) + "\n\n" + "\n".join(f"- {s}" for s in sources) + "\n"


ROBOTS_RECORD = "closed_loop-robots.json"
# Each Panda scene is run three times: on the Panda pair, on our SCARA (``…@scara``: the same
# scene and so the same plans, what the robot costs alone) and the SCARA's full-size scene it is
# scaled from (the same task where the hands' gap is a smaller share of the range).
SAME_SCENE = {"panda_vd": "panda_vd@scara", "panda_vc": "panda_vc@scara"}
FULL_SIZE = {"panda_vd": "table1_vd", "panda_vd@scara": "table1_vd",
             "panda_vc": "table1_vc", "panda_vc@scara": "table1_vc"}


def render_robots(results: Path) -> str:
    """Any robot (issue 50): each Panda scene closed loop on the Panda pair and on our SCARA,
    beside the SCARA's full-size scene (each (rule, seed) on all three one after the other):
    objects at rest in their goals, the run's wall time against the SCARA's on the same scene and
    on the full-size one, the replans' share of it (the planner's, which the scene decides) and
    the rest's per simulated second (physics, controller, gripper, monitors: what the robot
    decides), each against the SCARA's on the same scene; the arms' least clearance, the deepest
    hand into a box, the farthest a held box's centre strayed from its tool."""
    data = load(results, ROBOTS_RECORD)
    ok = {(r["scene"], r["rule"], r["seed"]): r for r in data["runs"] if r["status"] == "ok"}

    def planning(r: dict) -> float:
        return sum(x["wall_s"] for x in r["replan_log"])

    def robot_side(r: dict) -> float:  # lockstep: the simulation waits for every replan
        return (r["wall_time_s"] - planning(r)) / r["sim_time_s"]

    def wall(r: dict) -> float:
        return r["wall_time_s"]

    def against(value: float, base: dict | None, measure) -> str:
        return "" if base is None else f" ({value / measure(base):.1f}×)"

    rows = []
    for (scene, rule, seed), r in ok.items():
        same = ok.get((SAME_SCENE.get(scene), rule, seed))
        full = ok.get((FULL_SIZE.get(scene), rule, seed))
        rows.append([
            scene, f"{rule}", f"{seed}", f"{r['delivered']}/{r['n_objects']}",
            f"{r['sim_time_s']:.0f}",
            f"{wall(r):.0f}" + against(wall(r), same, wall),
            "" if full is None else f"{wall(r) / wall(full):.1f}×",
            f"{planning(r):.0f}" + against(planning(r), same, planning),
            f"{robot_side(r):.2f}" + against(robot_side(r), same, robot_side),
            "—" if r["min_arm_clearance_m"] is None else f"{100 * r['min_arm_clearance_m']:.1f}",
            "—" if r["max_hand_penetration_m"] is None
            else f"{1000 * r['max_hand_penetration_m']:.1f}",
            "—" if r.get("max_held_offset_m") is None
            else f"{1000 * r['max_held_offset_m']:.1f}"])
    header = ["scene", "rule", "seed", "at rest in their goals", "simulated s",
              "wall s (× the SCARA's on this scene)", "wall × the SCARA's at full size",
              "of it, replans s (×)", "the rest, s per simulated s (×)", "arms apart (cm)",
              "hand into a box (mm)", "held box from its tool (mm)"]
    return table(header, rows) + "\n\n- " + provenance(ROBOTS_RECORD, data, commit=False) + "\n"


def seed_text(seeds: list[int]) -> str:
    """``0–9`` for a range, ``0, 3, 7`` otherwise."""
    if len(seeds) > 2 and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}–{seeds[-1]}"
    return ", ".join(map(str, seeds))


# --- the Markdown files ------------------------------------------------------------------------


def documents(root: Path) -> list[Path]:
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def regenerate(text: str, results: Path, relative: str) -> str:
    """``text`` with every block rendered anew; links to the records made relative to the
    document (``relative``: the path from its folder to the repository root)."""
    def block(match: re.Match) -> str:
        name = match.group(2)
        body = (render_paper(results) if name == "paper"
                else render_clearance(results) if name == "clearance"
                else render_clock(results) if name == "clock"
                else render_robots(results) if name == "robots"
                else render_file(results, name, commit=relative != ""))
        return match.group(1) + body.replace("](../", f"]({relative}") + match.group(4)
    return BLOCK.sub(block, text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--check", action="store_true",
                   help="change nothing; exit 1 if a committed table differs from the records")
    p.add_argument("--root", type=Path, default=ROOT,
                   help="the repository to read and write (default: this one)")
    args = p.parse_args(argv)
    results = args.root / "bench" / "results"
    stale = []
    try:
        for doc in documents(args.root):
            old = doc.read_text()
            new = regenerate(old, results, "" if doc.parent == args.root else "../")
            if new == old:
                continue
            stale.append(doc)
            if not args.check:
                doc.write_text(new)
    except RecordError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for doc in stale:
        print(f"{doc.relative_to(args.root)}: "
              + ("differs from the records" if args.check else "rewritten"), file=sys.stderr)
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
