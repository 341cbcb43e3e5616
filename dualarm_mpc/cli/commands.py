"""The commands ``check``, ``plan`` and ``simulate``: each prints what it does and returns its
exit code (the table in :mod:`dualarm_mpc.cli.app`)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from dualarm_mpc.base import outputs
from dualarm_mpc.cli import process
from dualarm_mpc.cli.arguments import scenario_overrides
from dualarm_mpc.cli.process import (
    CONFLICT,
    FAILED,
    OK,
    heartbeat,
    interruptible,
    received,
    signal_name,
    stopped,
)
from dualarm_mpc.model.scenario import load_scenario


def _objects_left(scenario) -> int:
    """How many objects do not yet rest in their goals; says so if none or fewer than m_o."""
    from dualarm_mpc.model.mld import State, delivered_objects

    start = State.initial(scenario)
    left = int((~delivered_objects(scenario, start.object_pos, start.object_vel)).sum())
    if not left:
        print("nothing to do: every object already rests in its goal")
    elif left < scenario.task.m_o:
        print(f"note: m_o = {scenario.task.m_o}, but {left} object(s) are left to deliver: a step "
              f"delivers {left}")
    return left


def _check(scenario, joint: bool, file=None):
    """Run the consistency check (``consistency.py``) and print what it found. Nothing of it
    is kept if a signal stops it."""
    from dualarm_mpc.planning.consistency import check

    done = [0, 0]  # objects checked, of how many

    def progress(n: int, total: int) -> None:
        done[:] = max(done[0], n), total

    report = interruptible(
        lambda: check(scenario, joint=joint, progress=progress),
        tick=heartbeat(lambda: "checking the task against the rules"
                        + (f" ({done[0]} of {done[1]} objects checked)" if done[1] else "")))
    for conflict in report.conflicts:
        print(f"conflict: {conflict}", file=file or sys.stdout)
    for what in report.undecided:
        print(f"undecided within the time limit: {what}", file=file or sys.stdout)
    return report


def _load(args: argparse.Namespace, first: dict | None = None, on_robot: bool = False):
    """The scenario of the command line: ``first`` (overrides the flags may override), then the
    flags' overrides; nothing to keep if a signal stops it."""
    overrides = [first or {}, scenario_overrides(args)]
    return interruptible(lambda: load_scenario(args.scenario, overrides, on_robot=on_robot),
                         tick=heartbeat("reading the scenario"))


def cmd_check(args: argparse.Namespace) -> int:
    scenario = _load(args)
    report = _check(scenario, joint=True)
    if report.conflicts:
        return CONFLICT
    if report.undecided:
        return FAILED
    # the check's programs leave the spacing out (consistency.py): say so where there is one
    clearance = scenario.task.object_clearance
    spacing = (f"; the objects' spacing (object_clearance {clearance:g} m) is not checked"
               if clearance else "")
    print(f"consistent: every object has a plan on its own, and the first step as a whole, "
          f"within {report.horizon} steps{spacing}")
    return OK


def _write(output: outputs.Output | None, save, what: str = "") -> bool:
    """``save(output)`` and say so; a failed write is one line (the path and the OS's reason).
    Whether it was written (or not asked for)."""
    if output is None:
        return True
    if save is not None:  # None: written inside the run (the replay)
        save(output)
    if output.error is not None:
        print(f"error: cannot write {output}: {output.error.strerror}", file=sys.stderr)
        return False
    print(f"wrote {output}{what}")
    return True


def _failed_writes(code: int, written: bool) -> int:
    """An output that could not be written fails a run that would have exited 0; a run that
    ends otherwise keeps its code (the error lines say what is missing)."""
    return FAILED if code == OK and not written else code


def cmd_plan(args: argparse.Namespace) -> int:
    from dualarm_mpc.milp.horizon import HorizonProgram
    from dualarm_mpc.milp.solver import Interrupt
    from dualarm_mpc.planning.sequential import PlanningError
    from dualarm_mpc.planning.task import VerificationError, plan

    scenario = _load(args)
    task = scenario.task
    print(f"{scenario.name}: {scenario.n_objects} objects, rule {task.rule}, "
          f"(m_o, n_o) = ({task.m_o}, {task.n_o}), delivery {task.delivery}")
    if _check(scenario, joint=False, file=sys.stderr).conflicts:
        return CONFLICT
    left = _objects_left(scenario)
    if left:
        print(f"{'step':>4}  {'delivered':<22} {'T':>3} {'binaries':>8}  {'status':<10} "
              f"{'solve [s]':>9}  {'cost':>7}")
    count = [0]
    said = [time.perf_counter()] * 2  # the last line printed, the step's start

    def heartbeat() -> None:  # a long search is never silent
        now = time.perf_counter()
        if now - said[0] >= process.HEARTBEAT_S:
            print(f"{'':>4}  still searching step {count[0] + 1}: {now - said[1]:.0f} s so far",
                  flush=True)
            said[0] = now

    def progress(seg) -> None:
        said[0] = said[1] = time.perf_counter()
        count[0] += 1
        names = ",".join(task.objects[j].name.removeprefix("object") for j in seg.delivered)
        fewer = len(seg.objects) < task.m_o  # the last objects: m_o shrinks to them
        notes = [f"m_o = {len(seg.objects)}: the objects left"] if fewer else []
        if seg.witness_cost is not None:
            notes.append(f"witness {seg.witness_cost:.3f} at T = {seg.witness_horizon}")
        if seg.horizons_proven_by_cpsat:
            notes.append("CP-SAT proved T = " + ", ".join(map(str, seg.horizons_proven_by_cpsat)))
        if seg.shorter_plan is not None:
            notes.append(f"T = {seg.shorter_plan[0]} has a plan at {seg.shorter_plan[1]:.3f}")
        if seg.horizons_undecided:
            notes.append("T = " + ", ".join(map(str, seg.horizons_undecided)) + " undecided")
        print(f"{count[0]:>4}  {names or '-':<22} {seg.horizon:>3} {seg.binaries:>8}  "
              f"{seg.status:<10} {seg.solve_time_s:>9.2f}  {seg.cost:>7.3f}"
              + "".join(f"  ({n})" for n in notes), flush=True)

    export = None
    if args.export:
        from dualarm_mpc.milp.export import MpsExport

        export = MpsExport(scenario, args.export)

    def tried(t) -> None:  # a horizon without a plan: say so, a search is never silent
        res = t.result
        if export is not None and export.error is None:
            step = t.problem
            form = HorizonProgram(step.scenario, step.state, list(step.spec.objects),
                                  res.horizon).standard_form(step.spec)
            export.add(t.step, step.spec, res.horizon, res.status, res.cost, form)
        if not res.status.has_solution:
            said[0] = time.perf_counter()
            by = "  (CP-SAT)" if res.message.startswith("CP-SAT") else ""
            print(f"{'':>4}  {'':<22} {res.horizon:>3} {res.binaries:>8}  "
                  f"{res.status.value:<10} {res.solve_time_s:>9.2f}{by}", flush=True)

    stop = Interrupt()
    problems: list[str] = []
    try:
        result = interruptible(lambda: plan(scenario, check_first=False, progress=progress,
                                            on_try=tried, stop=stop), stop, heartbeat)
    except VerificationError as err:
        result, problems = err.plan, err.problems
    except PlanningError as err:
        print(f"error: {err}", file=sys.stderr)
        written = err.partial is None or not err.partial.segments or \
            _save_plan(err.partial, args, scenario)
        return _failed_writes(CONFLICT if err.proven else FAILED,
                              _exported(export, args) and written)
    exported = _exported(export, args)
    resting = sum(d is not None for d in result.delivered_step)
    already = f" ({scenario.n_objects - left} already there)" if left < scenario.n_objects else ""
    print(f"total: {resting}/{scenario.n_objects} resting in their goals{already}, cost "
          f"{result.total_cost:.3f}, solve time {result.total_solve_time_s:.2f} s "
          f"(CPU {result.total_cpu_time_s:.2f} s)")
    written = _save_plan(result, args, scenario) and exported
    if stop.is_set():  # a signal: planning stopped, or verification was not waited for
        print(f"interrupted by {signal_name()} after {len(result.segments)} step(s): what was "
              "written is " + ("partial" if result.partial else "whole")
              + ("" if result.verified else " and not verified"), file=sys.stderr)
        return stopped()
    if problems:
        print("error: the plan fails verification:\n  " + "\n  ".join(problems),
              file=sys.stderr)
        return FAILED
    print("verified: the replayed trace satisfies every step's specification; "
          "every object rests in its goal")
    return _failed_writes(OK, written)


def _exported(export, args: argparse.Namespace) -> bool:
    """Say what ``--export`` wrote, and whether it wrote every file it tried."""
    if export is None:
        return True
    if export.entries:
        print(f"wrote {len(export.entries)} MILP(s) as MPS, listed in "
              f"{Path(args.export) / 'index.json'}")
    if export.error is not None:
        print(f"error: cannot write {export.error.filename}: {export.error.strerror} "
              "(the export stopped there)", file=sys.stderr)
    return export.error is None


def _save_plan(result, args: argparse.Namespace, scenario) -> bool:
    """Write the plan JSON and the plot asked for (a partial plan is marked so in both);
    whether both were written."""
    from dualarm_mpc.figures.plan import plot_plan

    partial = " (partial)" if result.partial else ""
    title = (f"{scenario.name}, rule {scenario.task.rule}: cost {result.total_cost:.3f}, "
             f"solve {result.total_solve_time_s:.1f} s{partial}")
    written = _write(_output_of(args, "out"), result.save, partial)
    return _write(_output_of(args, "plot"), lambda out: plot_plan(result, out, title),
                  partial) and written


def _output_of(args: argparse.Namespace, flag: str) -> outputs.Output | None:
    path = getattr(args, flag)
    return None if path is None else outputs.Output(path, f"--{flag}")


def cmd_simulate(args: argparse.Namespace) -> int:
    from dualarm_mpc.sim.closed_loop import check_events, simulate

    # before the flags: --set 'solver.realtime: false' wins
    realtime = {"solver": {"realtime": True}} if args.realtime or args.meshcat else None
    scenario = _load(args, realtime, on_robot=True)
    check_events(scenario, args.duration)
    print(f"{scenario.name}: closed loop, {scenario.n_objects} objects, rule {scenario.task.rule}, "
          f"(m_o, n_o) = ({scenario.task.m_o}, {scenario.task.n_o})")
    if _check(scenario, joint=False, file=sys.stderr).conflicts:
        return CONFLICT
    _objects_left(scenario)
    print(f"{'t [s]':>7}  {'delivered':>9}  {'status':<10} {'T':>3}  {'solve [s]':>9}  objects")

    def progress(r) -> None:
        names = ",".join(scenario.task.objects[j].name.removeprefix("object") for j in r.objects)
        print(f"{r.t:>7.1f}  {r.n_delivered:>5}/{scenario.n_objects:<3}  {r.status:<10} "
              f"{r.horizon if r.horizon is not None else '-':>3}  {r.wall_s:>9.3f}  {names}"
              + (f"  ({r.note})" if r.note else ""), flush=True)

    meshcat = None
    if args.meshcat:
        from dualarm_mpc.sim.recording import start_meshcat

        meshcat = start_meshcat(live=True)
        print(f"Meshcat: {meshcat.web_url()} (open it in a browser to watch the run live; "
              "it replays the run when the run ends)", flush=True)
    html = _output_of(args, "html")
    summary = simulate(scenario, args.duration, html, progress, meshcat=meshcat,
                       record_contacts=args.record_contacts)
    n_in = sum(d is not None for d in summary.delivered_time_s)
    wall = summary.wall_clock
    print(f"end: t = {summary.sim_time_s:.1f} s, {n_in}/{scenario.n_objects} objects resting in "
          f"their goals, {summary.mode}; wall time {wall['wall_time_s']:.1f} s, real-time factor "
          f"{wall['realtime_factor']:.2f}")
    partial = " (partial)" if summary.interrupted else ""
    written = _write(_output_of(args, "summary"), summary.save, partial)
    written = _write(html, None, f" ({'partial; ' if summary.interrupted else ''}open it in a "
                     "browser: it plays the run from the start)") and written
    if summary.interrupted:
        print(f"interrupted by {signal_name()} at t = {summary.sim_time_s:.1f} s: the summary "
              "and replay end there", file=sys.stderr)
        return stopped()
    if meshcat is not None:
        _serve_while_watched(meshcat)
    if not summary.all_delivered:
        print("error: not every object ends at rest inside its goal", file=sys.stderr)
        return FAILED
    return _failed_writes(OK, written)


def _serve_while_watched(meshcat) -> None:
    """The live page of a finished run goes on replaying it: keep its server up until the last
    page closes (or a stop signal, which ends only this wait: the run is done and written)."""
    from dualarm_mpc.sim.recording import serve_while_watched

    if meshcat.GetNumActiveConnections() == 0:
        return
    print(f"the run is over: {meshcat.web_url()} replays it until you close the page "
          "(or press Ctrl-C)", flush=True)
    try:
        serve_while_watched(meshcat)
    except KeyboardInterrupt:
        received.clear()
