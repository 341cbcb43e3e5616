"""Command line: ``dualarm-mpc check``, ``plan`` and ``simulate`` (the closed loop in Drake).

Exit codes: 0 done (or consistent), 2 bad input, 3 the task conflicts with the rules or bounds
(no plan exists), 4 undecided within the time limits or a failed run (a plan that fails
verification, an object not delivered), 130 interrupted (what was done is written)."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path

from dualarm_mpc.ltl import LTLSyntaxError
from dualarm_mpc.scenario import (
    SOLVER_BACKENDS,
    ScenarioError,
    load_scenario,
    merge_overrides,
    parse_override,
)

HEARTBEAT_S = 15.0  # seconds of a search without a line before it says it is still searching


def _overrides(args: argparse.Namespace) -> dict:
    """Scenario fields named by flags; ``--set`` YAML comes last and wins."""
    out: dict = {}
    for flag, field in (("rule", "rule"), ("mo", "m_o"), ("no", "n_o"), ("seed", "seed"),
                        ("delivery", "delivery")):
        value = getattr(args, flag, None)
        if value is not None:
            out[field] = value
    solver = {key: value for key, value in (("time_limit_s", getattr(args, "time_limit", None)),
                                            ("search", getattr(args, "search", None)),
                                            ("backend", getattr(args, "solver", None)))
              if value is not None}
    if solver:
        out["solver"] = solver
    for text in args.set or []:
        merge_overrides(out, parse_override(text, f"--set {text!r}"))
    return out


# Flag types: a bad value is an argparse error naming the flag (exit 2) before any work.


def _count(minimum: int):
    def count(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return count


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def _output(path: str) -> str:
    """A file the run writes at its end, checked before the run starts: a directory that does
    not exist or a place that cannot be written would lose the work."""
    p = Path(path)
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a directory")
    if not p.parent.is_dir():
        raise argparse.ArgumentTypeError(f"directory {p.parent} does not exist")
    existed = p.exists()
    try:
        with open(p, "a"):
            pass
    except OSError as err:
        raise argparse.ArgumentTypeError(f"cannot write {path}: {err.strerror}") from None
    if not existed:
        p.unlink()
    return path


def _directory(path: str) -> str:
    """A directory the run writes files into, checked before the run starts: made if missing
    (in a directory that exists)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is not a directory")
    where = p if p.exists() else p.parent
    if not where.is_dir():
        raise argparse.ArgumentTypeError(f"directory {where} does not exist")
    if not os.access(where, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"cannot write in {where}")
    return path


def _plot(path: str) -> str:
    """An output file whose suffix names a format matplotlib writes."""
    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(path).suffix.lstrip(".").lower()
    if suffix not in formats:
        raise argparse.ArgumentTypeError(f"unknown plot format {suffix or '(no suffix)'!r} "
                                         f"(one of {', '.join(sorted(formats))})")
    return _output(path)


def _objects_left(scenario) -> int:
    """How many objects do not yet rest in their goals; says so if none or fewer than m_o."""
    from dualarm_mpc.mld import State
    from dualarm_mpc.sequential import at_rest_in_goal

    left = int((~at_rest_in_goal(scenario, State.initial(scenario))).sum())
    if not left:
        print("nothing to do: every object already rests in its goal")
    elif left < scenario.task.m_o:
        print(f"note: m_o = {scenario.task.m_o}, but {left} object(s) are left to deliver: a step "
              f"delivers {left}")
    return left


def _scenario_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="a scenario YAML file, or table1_vc / table1_vd")
    p.add_argument("--rule", type=int, choices=(1, 2), help="1: no-throw; 2: no-juggle, no-swap")
    p.add_argument("--mo", type=_count(1), help="m_o, objects delivered per sequential step")
    p.add_argument("--no", type=_count(1), help="n_o, objects considered per sequential step")
    p.add_argument("--seed", type=_count(0), help="seed of random objects (table1_vd)")
    p.add_argument("--delivery", choices=("reach", "rest"), help="what 'delivered' means")
    p.add_argument("--time-limit", type=_seconds, help="seconds per horizon of a step")
    p.add_argument("--search", choices=("skeleton", "monolithic"),
                   help="solve each horizon by the skeleton search (default) or as one MILP")
    p.add_argument("--solver", choices=SOLVER_BACKENDS,
                   help="the MILP solver (default highs; the others where installed)")
    p.add_argument("--set", action="append", metavar="YAML",
                   help="override any scenario field, e.g. --set 'max_speed: 0.3' or "
                   "--set 'solver.time_limit_s: 5' (repeatable)")


def _check(scenario, joint: bool, file=sys.stdout):
    """Run the consistency check (``consistency.py``) and print what it found."""
    from dualarm_mpc.consistency import check

    report = check(scenario, joint=joint)
    for conflict in report.conflicts:
        print(f"conflict: {conflict}", file=file)
    for what in report.undecided:
        print(f"undecided within the time limit: {what}", file=file)
    return report


def cmd_check(args: argparse.Namespace) -> int:
    report = _check(load_scenario(args.scenario, _overrides(args)), joint=True)
    if report.conflicts:
        return 3
    if report.undecided:
        return 4
    print(f"consistent: every object has a plan on its own, and the first step as a whole, "
          f"within {report.horizon} steps")
    return 0


def _interruptible(work, stop, tick=lambda: None):
    """``work()`` on a thread, so that Ctrl-C reaches the main thread at once (a HiGHS run
    holds it until it returns); Ctrl-C stops the solves through ``stop`` (a
    ``solver.Interrupt``) and ``work`` returns what it has. ``tick()`` runs every 0.1 s."""
    out: dict = {}
    done = threading.Event()  # not Thread.join: a join cut short by Ctrl-C can lose the thread

    def run() -> None:
        try:
            out["value"] = work()
        except BaseException as err:  # re-raised on the main thread
            out["error"] = err
        finally:
            done.set()

    threading.Thread(target=run, daemon=True).start()
    try:
        while not done.wait(0.1):
            tick()
    except KeyboardInterrupt:
        stop.set()
        print("interrupted: stopping the solver", file=sys.stderr, flush=True)
        done.wait()
    if "error" in out:
        raise out["error"]
    return out["value"]


def cmd_plan(args: argparse.Namespace) -> int:
    from dualarm_mpc.horizon import solver_options
    from dualarm_mpc.sequential import PlanningError, plan
    from dualarm_mpc.solver import Interrupt
    from dualarm_mpc.verify import verify

    scenario = load_scenario(args.scenario, _overrides(args))
    task = scenario.task
    print(f"{scenario.name}: {scenario.n_objects} objects, rule {task.rule}, "
          f"(m_o, n_o) = ({task.m_o}, {task.n_o}), delivery {task.delivery}")
    if _check(scenario, joint=False, file=sys.stderr).conflicts:
        return 3
    left = _objects_left(scenario)
    if left:
        print(f"{'step':>4}  {'delivered':<22} {'T':>3} {'binaries':>8}  {'status':<10} "
              f"{'solve [s]':>9}  {'cost':>7}")
    count = [0]
    said = [time.perf_counter()] * 2  # the last line printed, the step's start

    def heartbeat() -> None:  # a long search is never silent
        now = time.perf_counter()
        if now - said[0] >= HEARTBEAT_S:
            print(f"{'':>4}  still searching step {count[0] + 1}: {now - said[1]:.0f} s so far",
                  flush=True)
            said[0] = now

    def progress(seg) -> None:
        said[0] = said[1] = time.perf_counter()
        count[0] += 1
        names = ",".join(task.objects[j].name.removeprefix("object") for j in seg.delivered)
        fewer = len(seg.objects) < task.m_o  # the last objects: m_o shrinks to them
        print(f"{count[0]:>4}  {names or '-':<22} {seg.horizon:>3} {seg.binaries:>8}  "
              f"{seg.status:<10} {seg.solve_time_s:>9.2f}  {seg.cost:>7.3f}"
              + (f"  (m_o = {len(seg.objects)}: the objects left)" if fewer else ""), flush=True)

    export = None
    if args.export:
        from dualarm_mpc.export import MpsExport

        export = MpsExport(scenario, args.export)

    def tried(t) -> None:  # a horizon without a plan: say so, a search is never silent
        if export:
            export(t)
        res = t.result
        if not res.status.has_solution:
            said[0] = time.perf_counter()
            print(f"{'':>4}  {'':<22} {res.horizon:>3} {res.binaries:>8}  "
                  f"{res.status.value:<10} {res.solve_time_s:>9.2f}", flush=True)

    stop = Interrupt()
    options = dataclasses.replace(solver_options(scenario), interrupt=stop)
    try:
        result = _interruptible(lambda: plan(scenario, options, progress, tried), stop,
                                heartbeat)
    except PlanningError as err:
        print(f"error: {err}", file=sys.stderr)
        if err.partial is not None and err.partial.segments:
            _save_plan(err.partial, args, scenario)
        return 3
    finally:
        if export and export.entries:
            print(f"wrote {len(export.entries)} MILP(s) as MPS, listed in "
                  f"{Path(args.export) / 'index.json'}")
    check = verify(scenario, result)
    result = dataclasses.replace(result, verified=check.ok)
    resting = sum(d is not None for d in result.delivered_step)
    already = f" ({scenario.n_objects - left} already there)" if left < scenario.n_objects else ""
    print(f"total: {resting}/{scenario.n_objects} resting in their goals{already}, cost "
          f"{result.total_cost:.3f}, solve time {result.total_solve_time_s:.2f} s "
          f"(CPU {result.total_cpu_time_s:.2f} s)")
    _save_plan(result, args, scenario)
    if result.partial:
        print(f"interrupted after {len(result.segments)} step(s): what was written is partial",
              file=sys.stderr)
        return 130
    if not check.ok:
        print("error: the plan fails verification:\n  " + "\n  ".join(check.problems),
              file=sys.stderr)
        return 4
    print("verified: the replayed trace satisfies every step's specification; "
          "every object rests in its goal")
    return 0


def _save_plan(result, args: argparse.Namespace, scenario) -> None:
    """Write the plan JSON and PNG asked for (a partial plan is marked so in both)."""
    from dualarm_mpc.plot import plot_plan

    partial = " (partial)" if result.partial else ""
    if args.out:
        result.save(args.out)
        print(f"wrote {args.out}{partial}")
    if args.plot:
        plot_plan(result, args.plot, title=f"{scenario.name}, rule {scenario.task.rule}: cost "
                  f"{result.total_cost:.3f}, solve {result.total_solve_time_s:.1f} s{partial}")
        print(f"wrote {args.plot}{partial}")


def cmd_simulate(args: argparse.Namespace) -> int:
    from dualarm_mpc.closed_loop import on_robot, simulate
    from dualarm_mpc.scenario import apply_overrides

    base = load_scenario(args.scenario)
    overrides = on_robot(base)
    merge_overrides(overrides, _overrides(args))
    scenario = apply_overrides(base, overrides)
    print(f"{scenario.name}: closed loop, {scenario.n_objects} objects, rule {scenario.task.rule}, "
          f"(m_o, n_o) = ({scenario.task.m_o}, {scenario.task.n_o})")
    if _check(scenario, joint=False, file=sys.stderr).conflicts:
        return 3
    _objects_left(scenario)
    print(f"{'t [s]':>7}  {'delivered':>9}  {'status':<10} {'T':>3}  {'solve [s]':>9}  objects")

    def progress(r) -> None:
        names = ",".join(scenario.task.objects[j].name.removeprefix("object") for j in r.objects)
        print(f"{r.t:>7.1f}  {r.delivered:>5}/{scenario.n_objects:<3}  {r.status:<10} "
              f"{r.horizon if r.horizon is not None else '-':>3}  {r.wall_s:>9.3f}  {names}"
              + (f"  ({r.note})" if r.note else ""), flush=True)

    meshcat = None
    if args.meshcat:
        from dualarm_mpc.recording import start_meshcat

        meshcat = start_meshcat(live=True)
        print(f"Meshcat: {meshcat.web_url()} (open it in a browser to watch the run live; "
              "it replays the run when the run ends)", flush=True)
    summary = simulate(scenario, args.duration, args.html, progress, meshcat=meshcat)
    n_in = sum(d is not None for d in summary.delivered_time_s)
    print(f"end: t = {summary.sim_time_s:.1f} s, {n_in}/{scenario.n_objects} objects resting in "
          f"their goals, real-time factor {summary.realtime_factor:.2f}")
    if args.summary:
        summary.save(args.summary)
        print(f"wrote {args.summary}")
    if args.html:
        print(f"wrote {args.html} (open it in a browser: it plays the run from the start)")
    if summary.interrupted:
        print(f"interrupted at t = {summary.sim_time_s:.1f} s: the summary and replay end there",
              file=sys.stderr)
        return 130
    if not summary.all_delivered:
        print("error: not every object ends at rest inside its goal", file=sys.stderr)
        return 4
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="dualarm-mpc", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("check", help="decide whether the task, the rules and the bounds admit a "
                       "plan; name each conflict (exit 3)")
    _scenario_arguments(p)
    p.set_defaults(run=cmd_check)
    p = sub.add_parser("plan", help="plan the whole task (sequential transportation) and verify it")
    _scenario_arguments(p)
    p.add_argument("--out", type=_output, help="write the plan JSON here")
    p.add_argument("--plot", type=_plot, help="write a PNG (or PDF, SVG, ...) of the plan here")
    p.add_argument("--export", type=_directory, metavar="DIR",
                   help="write the monolithic MILP of each horizon tried as an MPS file here, "
                   "with index.json")
    p.set_defaults(run=cmd_plan)
    p = sub.add_parser("simulate", help="run the receding-horizon planner on the robot in Drake")
    _scenario_arguments(p)
    p.add_argument("--duration", type=_seconds,
                   help="simulated seconds (default: by object count)")
    p.add_argument("--html", type=_output, help="write the self-contained Meshcat replay here")
    p.add_argument("--summary", type=_output, help="write the summary JSON here")
    p.add_argument("--meshcat", action="store_true",
                   help="start Drake's Meshcat server, print its URL and draw the run there live, "
                   "at real time")
    p.set_defaults(run=cmd_simulate)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    from dualarm_mpc.encoding import EncodingError  # here: it loads pydrake
    from dualarm_mpc.solver import SolverUnavailable

    try:
        return args.run(args)
    except (ScenarioError, LTLSyntaxError, EncodingError, SolverUnavailable) as err:  # one line
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # outside a solve (or a second Ctrl-C): nothing left to keep
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
