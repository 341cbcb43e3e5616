"""Closed loop on §V-D: per-replan wall time and the simulation's real-time factor.

What it measures: for each rule and seed, the scenario ``table1_vd`` (ten objects uniform in
[-0.25, 0.25]² from the seed, reachable goals) with (m_o, n_o) = (2, 6), delivery ``rest`` and a
goal margin of 0.03 m is run closed loop by :func:`dualarm_mpc.sim.closed_loop.simulate`: the MPC
planner replans every Δt = 1 s from the measured state while Drake simulates the dual SCARA robot.

* **objects delivered** — counted on the plant at the end of the run: objects whose final (x, y)
  is inside their goal box and whose speed is below 0.01 m/s (not the planner's own count);
* **wall per replan** — the wall time of each replan that had work to do (model build, every
  horizon tried, extraction), as median, 95th percentile (linear interpolation) and maximum.
  Replans with status ``done`` or ``stuck``, which only hold the hands once nothing is left to
  do, are left out; ``kept`` ones (on a proven plan, which need no search) and those that raised
  (status ``error``, often before any solve) are in, so read the medians next to the status
  counts of the detail table. The simulation blocks while the planner runs, so on a robot each
  replan must finish within Δt;
* **real-time factor** — simulated time / wall time of the whole run (solves included); above 1
  is faster than real time;
* runs are lockstep (the default of ``simulate``): what the robot does, and so every figure but
  the wall times, is the same on any machine; ``--set 'solver.realtime: true'`` replans against
  the wall clock instead (a budget of 0.4 Δt per replan), and then the run depends on the machine;
* **arms apart** — the least distance between the two arms' collision geometries over the run
  (the summary's ``min_arm_clearance_m``, by SceneGraph every 20 ms), in cm;
* **hand into a box** — the deepest any hand geometry reached into any object over the run (the
  summary's ``max_hand_penetration_m``, by SceneGraph every 20 ms), in mm;
* **object contacts** — the pairs of objects that touched while one of them moved (the summary's
  ``object_contacts``, from the plant's contact results every 20 ms): a box shoved by another.

* **any robot** (issue 50) — ``--scenes table1_vd panda_vd@scara panda_vd table1_vc
  panda_vc@scara panda_vc`` runs each Panda scene (a quarter of the SCARA's, docs/robots.md) on
  the Panda pair and on our SCARA (``…@scara``: the same scene, so the same plans to follow),
  beside the SCARA's own full-size scene, one after the other for each (rule, seed): the wall
  and CPU time of the same task with the differential IK against the closed form
  (``cpu_time_s``: the process's, threads included), the arms' clearance, the hands' depth into
  boxes, and the largest distance from a hand to the box it held (``max_held_offset_m``);
* **on the clock** (issue 49) — ``--scenes table1_vc table1_vd`` runs §V-C (rule 2 only: rule 1
  cannot throw to its unreachable goals) beside §V-D; ``--busy N`` keeps N other processes busy
  (a loop each, ended with the bench) to measure a loaded machine; each run records its
  simulated time, the seconds the robot stood at rest waiting for a search (``waiting_s``), the
  replans' wall times and the latency (``solver.replan_latency_s``, through ``--set``).

Run it (from the repository root)::

    .venv/bin/python bench/closed_loop.py                       # rules 1 and 2, seeds 0-2
    .venv/bin/python bench/closed_loop.py --scenes table1_vc table1_vd --busy 2 \
        --set 'solver.realtime: true' --json bench/results/closed_loop-clock-realtime-busy.json
    .venv/bin/python bench/closed_loop.py --scenes table1_vd panda_vd@scara panda_vd \
        table1_vc panda_vc@scara panda_vc --json bench/results/closed_loop-robots.json
    .venv/bin/python bench/closed_loop.py --rules 2 --seeds 0,4 --time-limit 5
    .venv/bin/python bench/closed_loop.py --set 'goal_slots: true' --json bench/results/slots.json

``--set`` adds scenario overrides after the fixed ones (rule, seed, (m_o, n_o) = (2, 6), delivery
rest, goal margin 0.03 m); the JSON records them with the other options.

One line per replan and per finished run goes to stderr; the Markdown tables go to stdout and next
to the JSON (``--json``, default bench/results/closed_loop.json, rewritten after every run), which
holds every run's record (with every replan), a summary per rule, the machine and the options.
Runs go one after another in this process, so the timings are those of one otherwise idle core.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import subprocess
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

import numpy as np
from benchlib import (
    fmt,
    footer,
    machine,
    options_json,
    parse_seeds,
    table,
    write_json_atomic,
    write_report,
)

from dualarm_mpc.model.mld import REST_SPEED, in_goal
from dualarm_mpc.model.scenario import (
    Robot,
    ScenarioError,
    load_scenario,
    merge_overrides,
    on_robot_overrides,
    parse_override,
)
from dualarm_mpc.sim.closed_loop import simulate

SCENARIO = "table1_vd"
# A Panda scene carried by our SCARA (``panda_vd@scara``): the same scene, so the same plans to
# follow, and the wall times differ by what the robot costs (its inverse kinematics, controller
# and physics) and not by the planning a scene needs.
ON_SCARA = "@scara"
# §V-D scenes (seeds, rules) and §V-C scenes (rule 2, one run), each on our SCARA and on the Panda
# pair (docs/robots.md)
VD_SCENES = (SCENARIO, "panda_vd", "panda_vd" + ON_SCARA)
SCENES = (*VD_SCENES, "table1_vc", "panda_vc", "panda_vc" + ON_SCARA)
M_O, N_O = 2, 6
SOLUTION = ("optimal", "feasible", "kept")  # a plan in force after the replan
NO_SOLVE = ("done", "stuck")  # replans that only hold the hands: every object done, or none can be


# --- command line ------------------------------------------------------------------------------


def parse_set(text: str) -> dict:
    """``--set`` as the CLI reads it (field paths, YAML 1.2 numbers)."""
    try:
        return parse_override(text, f"--set {text!r}")
    except ScenarioError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=parse_seeds, default=[0, 1, 2],
                   help="0-2, 0,3,7 or a count (default 0-2)")
    p.add_argument("--rules", nargs="+", type=int, choices=(1, 2), default=[1, 2])
    p.add_argument("--time-limit", type=float, default=None,
                   help="seconds per MILP solve (default: the scenario's, 30 s)")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated seconds at most per run (default: simulate's, by object count)")
    p.add_argument("--set", action="append", type=parse_set, default=[], metavar="YAML",
                   help="extra scenario overrides, applied last, e.g. --set 'goal_slots: true' "
                        "(repeatable)")
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=[SCENARIO],
                   help="table1_vd / panda_vd (seeds, rules) and/or table1_vc / panda_vc "
                        "(rule 2, one run)")
    p.add_argument("--busy", type=int, default=0, metavar="N",
                   help="other processes kept busy during the runs (a loaded machine)")
    p.add_argument("--json", type=Path, default=Path("bench/results/closed_loop.json"))
    p.add_argument("--quiet", action="store_true", help="no per-replan lines on stderr")
    return p.parse_args(argv)


# --- one run -----------------------------------------------------------------------------------


def overrides(rule: int, seed: int, time_limit: float | None, extra: list[dict],
              scene: str = SCENARIO) -> dict:
    """The robot's settings (as ``dualarm-mpc simulate``), then this run's (the SCARA in place of
    the scene's robot for ``…@scara``), then ``--set``."""
    out = {**on_robot_overrides(load_scenario(scene.removesuffix(ON_SCARA))), "rule": rule,
           "seed": seed, "m_o": M_O, "n_o": N_O}
    if scene.endswith(ON_SCARA):
        out.update(robot_model=None, hand_frames=[], arm_bases=Robot().arm_bases)
    if time_limit is not None:
        out["solver"] = {"time_limit_s": time_limit}
    for more in extra:
        merge_overrides(out, more)
    return out


def resting_in_goal(summary) -> list[bool]:
    """Per object: its final (x, y) inside its goal box (the true box, as the summary's goals
    give it) and at rest on the robot (``mld.REST_SPEED``) — judged on the plant, not by the
    planner: the summary's ``all_delivered``, per object."""
    return [bool(in_goal(summary.final_object_pos[j][:2], summary.goals[obj["goal"]])
                 and summary.final_object_speed[j] <= REST_SPEED)
            for j, obj in enumerate(summary.objects)]


def percentiles(values: list[float]) -> dict:
    if not values:
        return {"median": None, "p95": None, "max": None, "mean": None}
    a = np.asarray(values, float)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)),
            "max": float(a.max()), "mean": float(a.mean())}


def run_one(rule: int, seed: int, args: argparse.Namespace, scene: str = SCENARIO) -> dict:
    """Simulate one (rule, seed); always returns a record, never raises."""
    record = {"scene": scene, "rule": rule, "seed": seed, "m_o": M_O, "n_o": N_O,
              "status": "error", "message": ""}
    tag = f"{scene} rule {rule} seed {seed}"

    def progress(r) -> None:
        if not args.quiet:
            horizon = "-" if r.horizon is None else r.horizon
            print(f"  {tag}: t {r.t:6.1f}  delivered {r.n_delivered:>2}  {r.status:<10} "
                  f"T {horizon:>2}  {r.wall_s:7.3f} s" + (f"  ({r.note})" if r.note else ""),
                  file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    try:
        scenario = load_scenario(scene.removesuffix(ON_SCARA),
                                 overrides(rule, seed, args.time_limit, args.set, scene))
        record["latency_s"] = scenario.replan_latency
        record["busy"] = getattr(args, "busy", 0)
        record["time_limit_s"] = scenario.solver.time_limit_s
        record["object_clearance"] = scenario.task.object_clearance
        record["n_objects"] = scenario.n_objects
        record["objects"] = [{"name": o.name, "position": o.position, "goal": o.goal}
                             for o in scenario.task.objects]
        cpu0 = _cpu_time()
        summary = simulate(scenario, args.duration, progress=progress)
        record["cpu_time_s"] = round(_cpu_time() - cpu0, 2)
    except Exception:  # a bug in one run must not end the bench: record it and go on
        record["message"] = traceback.format_exc(limit=4)
        record["wall_time_s"] = time.perf_counter() - t0
        return record
    solves = [r for r in replan_log(summary) if r["status"] not in NO_SOLVE]
    record.update(
        summary_record(summary),
        planner_delivered=sum(d is not None for d in summary.delivered_time_s),
        all_delivered=summary.all_delivered,
        replans_without_plan=sum(r["status"] not in SOLUTION for r in solves),
        replans_over_dt=sum(r["wall_s"] > scenario.robot.dt for r in solves),
    )
    return record


def _cpu_time() -> float:
    """CPU seconds of this process, its threads (HiGHS's) included: what a run costs, which
    other work on the machine does not change as it does the wall time."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def replan_log(summary) -> list[dict]:
    """The summary's replans, each with its wall time (``Summary.wall_clock``)."""
    return [{**r, "wall_s": w}
            for r, w in zip(summary.replans, summary.wall_clock["replan_wall_s"], strict=True)]


def summary_record(summary) -> dict:
    """What every closed-loop bench records of a run's summary (the wall clock's figures too:
    a bench measures this machine)."""
    resting = resting_in_goal(summary)
    log = replan_log(summary)
    solves = [r for r in log if r["status"] not in NO_SOLVE]
    return dict(
        status="ok",
        mode=summary.mode,
        delivered=sum(resting),
        resting_in_goal=resting,
        sim_time_s=summary.sim_time_s,
        wall_time_s=summary.wall_clock["wall_time_s"],
        realtime_factor=summary.wall_clock["realtime_factor"],
        min_arm_clearance_m=summary.min_arm_clearance_m,
        max_hand_penetration_m=summary.max_hand_penetration_m,
        max_held_offset_m=summary.max_held_offset_m,
        object_contacts=summary.object_contacts,
        replans=len(summary.replans),
        solving_replans=len(solves),
        replan_wall_s=percentiles([r["wall_s"] for r in solves]),
        statuses=dict(Counter(r["status"] for r in summary.replans)),
        replans_over_budget=len(summary.replans_over_budget),
        waiting_s=summary.waiting_s,
        final_object_pos=summary.final_object_pos,
        final_object_speed=summary.final_object_speed,
        delivered_time_s=summary.delivered_time_s,
        replan_log=[{k: r[k] for k in ("t", "wall_s", "status", "horizon", "delivered", "note")}
                    for r in log],
        load_avg_1min=os.getloadavg()[0],  # other work on the machine skews the times
    )


def run_line(k: int, n: int, r: dict) -> str:
    head = f"[{k}/{n}] {r.get('scene', SCENARIO)} rule {r['rule']} seed {r['seed']}"
    if r["status"] != "ok":
        return f"{head}: ERROR after {r['wall_time_s']:.0f} s: " \
               f"{r['message'].strip().splitlines()[-1]}"
    w = r["replan_wall_s"]
    return (f"{head}: {r['delivered']}/{r['n_objects']} resting in goal, "
            f"sim {r['sim_time_s']:.0f} s, {r['replans']} replans, wall/replan median "
            f"{fmt(w['median'], '.3f')} max {fmt(w['max'], '.2f')} s, "
            f"real-time factor {r['realtime_factor']:.2f}")


# --- summary -----------------------------------------------------------------------------------


def summarize(records: list[dict], rule: int) -> dict:
    """One row per rule: replan wall times pooled over its runs; real-time factor as total
    simulated time / total wall time."""
    runs = [r for r in records if r["rule"] == rule]
    ok = [r for r in runs if r["status"] == "ok"]
    walls = [x["wall_s"] for r in ok for x in r["replan_log"] if x["status"] not in NO_SOLVE]
    sim = sum(r["sim_time_s"] for r in ok)
    wall = sum(r["wall_time_s"] for r in ok)
    return {
        "rule": rule, "runs": len(runs), "ok": len(ok),
        "delivered": sum(r["delivered"] for r in ok),
        "objects": sum(r["n_objects"] for r in ok),
        "runs_all_delivered": sum(r["delivered"] == r["n_objects"] for r in ok),
        "mean_sim_time_s": sum(r["sim_time_s"] for r in ok) / len(ok) if ok else None,
        "replans": sum(r["replans"] for r in ok),
        "solving_replans": len(walls),
        "replan_wall_s": percentiles(walls),
        "replans_without_plan": sum(r["replans_without_plan"] for r in ok),
        "replans_over_dt": sum(r["replans_over_dt"] for r in ok),
        "realtime_factor": sim / wall if wall > 0 else None,
        "min_arm_clearance_m": min((r["min_arm_clearance_m"] for r in ok
                                    if r.get("min_arm_clearance_m") is not None), default=None),
        # runs recorded before the summary had them have none
        "max_hand_penetration_m": (max(r["max_hand_penetration_m"] for r in ok)
                                   if ok and all(r.get("max_hand_penetration_m") is not None
                                                 for r in ok) else None),
        "object_contacts": (sum(len(r["object_contacts"]) for r in ok)
                            if all("object_contacts" in r for r in ok) else None),
    }


def walls(w: dict) -> str:
    return f"{fmt(w['median'], '.3f')} / {fmt(w['p95'], '.3f')} / {fmt(w['max'], '.2f')}"


def main_table(records: list[dict], summary: list[dict]) -> str:
    header = ["rule", "seed", "objects delivered (resting in goal) / 10", "sim time (s)",
              "replans", "wall per replan median / p95 / max (s)", "real-time factor",
              "arms apart (cm)", "hand into a box (mm)", "object contacts (pairs)"]
    rows = []
    for s in summary:
        for r in (r for r in records if r["rule"] == s["rule"]):
            if r["status"] != "ok":
                rows.append([str(r["rule"]), str(r["seed"]), "error"] + ["—"] * 7)
                continue
            contacts = r.get("object_contacts")
            rows.append([str(r["rule"]), str(r["seed"]), f"{r['delivered']}/{r['n_objects']}",
                         f"{r['sim_time_s']:.0f}", str(r["replans"]), walls(r["replan_wall_s"]),
                         f"{r['realtime_factor']:.2f}", centimetres(r.get("min_arm_clearance_m")),
                         millimetres(r.get("max_hand_penetration_m")),
                         fmt(None if contacts is None else len(contacts), "d")])
        rows.append([f"**{s['rule']}**", f"**all ({s['ok']}/{s['runs']} runs)**",
                     f"**{s['delivered']}/{s['objects']}**", fmt(s["mean_sim_time_s"], ".0f"),
                     str(s["replans"]), walls(s["replan_wall_s"]), fmt(s["realtime_factor"]),
                     centimetres(s["min_arm_clearance_m"]),
                     millimetres(s["max_hand_penetration_m"]), fmt(s.get("object_contacts"), "d")])
    return table(header, rows)


def centimetres(metres: float | None) -> str:
    return fmt(None if metres is None else 100 * metres, ".1f")


def millimetres(metres: float | None) -> str:
    return fmt(None if metres is None else 1000 * metres, ".1f")


def detail_table(records: list[dict]) -> str:
    header = ["rule", "seed", "planner counted delivered", "replans with work",
              "replans without a plan", "replans over Δt", "statuses"]
    rows = []
    for r in records:
        if r["status"] != "ok":
            rows.append([str(r["rule"]), str(r["seed"]), "—", "—", "—", "—",
                         r["message"].strip().splitlines()[-1]])
            continue
        statuses = ", ".join(f"{k} {v}" for k, v in sorted(r["statuses"].items()))
        rows.append([str(r["rule"]), str(r["seed"]), f"{r['planner_delivered']}/{r['n_objects']}",
                     str(r["solving_replans"]), str(r["replans_without_plan"]),
                     str(r["replans_over_dt"]), statuses])
    return table(header, rows)


def report(records: list[dict], args: argparse.Namespace) -> str:
    summary = [summarize(records, rule) for rule in args.rules]
    limits = sorted({r["time_limit_s"] for r in records if "time_limit_s" in r})
    extra = "".join(f", {json.dumps(e)}" for e in args.set)
    modes = sorted({r.get("mode", "realtime") for r in records})
    limit = (f"time limit {', '.join(f'{v:g}' for v in limits) or '—'} s per solve"
             if "realtime" in modes else "work limits, no time limit")
    # the objects' spacing, recorded since it exists (simulate's default then: 1 cm)
    apart = sorted({f"{c:g} m apart" if c is not None else "as points" for c in
                    (r["object_clearance"] for r in records if "object_clearance" in r)})
    objects = f", objects {' and '.join(apart)}" if apart else ""
    head = (f"Closed loop, {SCENARIO}, (m_o, n_o) = ({M_O}, {N_O}), delivery rest, goal margin "
            f"0.03 m{objects}{extra}, {' and '.join(modes) or '—'}, {limit}, "
            f"Δt = 1 s. Wall per replan over replans with work (not done/stuck); per-rule rows "
            f"pool all replans of the rule, real-time factor = total sim time / total wall time.")
    return "\n".join([head, "", main_table(records, summary), "", "Detail:", "",
                      detail_table(records), ""])


# --- output ------------------------------------------------------------------------------------


def write_json(path: Path, args: argparse.Namespace, records: list[dict], info: dict,
               complete: bool) -> None:
    """Written after every run (``complete`` false until the last), atomically."""
    options = options_json(args)
    data = {"scenario": SCENARIO, "m_o": M_O, "n_o": N_O, "options": options, "machine": info,
            "complete": complete, "summary": [summarize(records, rule) for rule in args.rules],
            "runs": records}
    write_json_atomic(path, data)


@contextlib.contextmanager
def busy(n: int):
    """``n`` other processes, each a loop on a core of its own, until the block ends (each also
    ends by itself after a day, should this process be killed)."""
    loop = "import time\nend = time.time() + 86400\nwhile time.time() < end: pass"
    procs = [subprocess.Popen([sys.executable, "-c", loop]) for _ in range(n)]
    try:
        yield
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    # scene after scene for each (rule, seed): the same task on two robots runs under the same
    # load of the machine
    tasks = sorted(((scene, rule, seed) for scene in args.scenes
                    for rule in (args.rules if scene in VD_SCENES else [2])
                    for seed in (args.seeds if scene in VD_SCENES else [0])),
                   key=lambda t: (t[0] not in VD_SCENES, t[1], t[2]))
    info = machine()
    records: list[dict] = []
    t0 = time.perf_counter()
    with busy(args.busy):
        for k, (scene, rule, seed) in enumerate(tasks, 1):
            print(f"[{k}/{len(tasks)}] {scene} rule {rule} seed {seed}: running",
                  file=sys.stderr, flush=True)
            record = run_one(rule, seed, args, scene)
            records.append(record)
            print(run_line(k, len(tasks), record), file=sys.stderr, flush=True)
            write_json(args.json, args, records, info, complete=k == len(tasks))
    text = report(records, args) + footer(info, t0)
    write_report(args.json, text)
    return 1 if any(r["status"] != "ok" for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
