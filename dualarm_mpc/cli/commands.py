"""The commands ``check``, ``plan`` and ``simulate``: each prints what it does and returns its
exit code (the table in :mod:`dualarm_mpc.cli.app`)."""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

from dualarm_mpc.base import outputs
from dualarm_mpc.cli import process
from dualarm_mpc.cli.arguments import ALL, scenario_overrides
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
    from dualarm_mpc.planning.consistency import check, grouped

    done = [0, 0]  # objects checked, of how many

    def progress(n: int, total: int) -> None:
        done[:] = max(done[0], n), total

    report = interruptible(
        lambda: check(scenario, joint=joint, progress=progress),
        tick=heartbeat(lambda: "checking the task against the rules"
                        + (f" ({done[0]} of {done[1]} objects checked)" if done[1] else "")))
    for conflict in grouped(report.conflicts):  # objects that conflict alike: one line
        print(f"conflict: {conflict}", file=file or sys.stdout)
    for what in report.undecided:
        print(f"undecided within the time limit: {what}", file=file or sys.stdout)
    return report


def _load(args: argparse.Namespace, first: dict | None = None, on_robot: bool = False):
    """The scenario of the command line: ``first`` (overrides the flags may override), then the
    flags' overrides; nothing to keep if a signal stops it."""
    overrides = [first or {}, scenario_overrides(args)]
    scenario = interruptible(lambda: load_scenario(args.scenario, overrides, on_robot=on_robot),
                             tick=heartbeat("reading the scenario"))
    if getattr(args, "mo", None) == ALL:
        from dualarm_mpc.planning.task import whole_task

        scenario = whole_task(scenario)
    if scenario.robot.robot_model is not None:  # before any planning (docs/robots.md)
        from dualarm_mpc.sim.reach import check_robot

        interruptible(lambda: check_robot(scenario), tick=heartbeat("checking the robot's reach"))
    return scenario


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
    process.written.append(output.path)
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
    from dualarm_mpc.planning.task import VerificationError, first_pass, plan

    scenario = _load(args)
    task = scenario.task
    print(f"{scenario.name}: {scenario.n_objects} objects, rule {task.rule}, "
          f"(m_o, n_o) = ({task.m_o}, {task.n_o}), delivery {task.delivery}")
    if _check(scenario, joint=False, file=sys.stderr).conflicts:
        return CONFLICT
    left = _objects_left(scenario)
    if left:  # a header per step, its horizons tried under it, its plan last
        print("the horizons T each sequential step tried, the step's plan last:")
        print(f"{'T':>7} {'binaries':>8}  {'status':<10} {'solve [s]':>9}  {'cost':>7}  "
              "delivered")
    count = [0]
    said = [time.perf_counter()] * 2  # the last line printed, the step's start
    headed = [0]  # the last step whose header is printed
    sequential = first_pass(scenario)  # the whole task's first plan's steps, if any
    whole = [False]  # the whole task's search has begun (past its first plan's steps)

    def numbers(objects) -> str:
        return ",".join(task.objects[j].name.removeprefix("object") for j in objects)

    def header(step: int, objects) -> None:
        # a step of every object, more than the first pass's steps take: the whole search's
        whole[0] = whole[0] or len(objects) == scenario.n_objects > (
            0 if sequential is None else sequential.task.n_o)
        if headed[0] < step:
            headed[0] = step
            print(f"step {step}: objects {numbers(objects)}", flush=True)

    def heartbeat() -> None:  # a long search is never silent
        now = time.perf_counter()
        if now - said[0] >= process.HEARTBEAT_S:
            print(f"{'':>4}still searching step {count[0] + 1}: {now - said[1]:.0f} s so far",
                  flush=True)
            said[0] = now

    def progress(seg) -> None:
        said[0] = said[1] = time.perf_counter()
        count[0] += 1
        header(count[0], seg.objects)
        names = numbers(seg.delivered)
        m_o = task.m_o if sequential is None or whole[0] else sequential.task.m_o
        fewer = len(seg.objects) < m_o  # the last objects: m_o shrinks to them
        notes = [f"m_o = {len(seg.objects)}: the objects left"] if fewer else []
        if seg.witness_cost is not None:
            notes.append(f"witness {seg.witness_cost:.3f} at T = {seg.witness_horizon}")
        if seg.horizons_proven_by_cpsat:
            notes.append("CP-SAT proved T = " + ", ".join(map(str, seg.horizons_proven_by_cpsat)))
        if seg.shorter_plan is not None:
            notes.append(f"T = {seg.shorter_plan[0]} has a plan at {seg.shorter_plan[1]:.3f}")
        if seg.horizons_undecided:
            notes.append("T = " + ", ".join(map(str, seg.horizons_undecided)) + " undecided")
        print(f"{'':>4}{seg.horizon:>3} {seg.binaries:>8}  {seg.status:<10} "
              f"{seg.solve_time_s:>9.2f}  {seg.cost:>7.3f}  {names or '-'}"
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
            header(t.step, t.problem.spec.objects)
            by = "  (CP-SAT)" if res.message.startswith("CP-SAT") else ""
            print(f"{'':>4}{res.horizon:>3} {res.binaries:>8}  {res.status.value:<10} "
                  f"{res.solve_time_s:>9.2f}{by}", flush=True)

    def first_plan(first) -> None:  # the anytime plan's first pass: its steps again, searched
        joined = first.segments[0].sequential_steps
        how = (f"sequential transportation's {joined} steps, joined); searching on for a "
               "better plan" if joined else
               "each step's no-throw witness); Algorithm 1 on each step now")
        print(f"first verified plan: cost {first.total_cost:.3f}, {first.makespan} steps, after "
              f"{first.first_plan_s:.2f} s ({how}", flush=True)
        count[0] = headed[0] = 0

    def shorter_plan(better) -> None:  # the whole task's first plan replaced before the search
        step = better.segments[0]
        how = ("the route-guided plan" if step.guided else
               f"sequential transportation in steps of {step.sequential_row[0]}, joined")
        if step.shortened:
            how += f", re-timed: {step.shortened} Δt shorter"
        print(f"a shorter verified plan: cost {better.total_cost:.3f}, {better.makespan} steps "
              f"({how}); searching on", flush=True)

    stop = Interrupt()
    problems: list[str] = []
    budget = None if args.budget is None else threading.Timer(args.budget, stop.set)
    if budget is not None:
        budget.daemon = True
        budget.start()
    try:
        result = interruptible(lambda: plan(scenario, check_first=False, progress=progress,
                                            on_try=tried, stop=stop, on_first_plan=first_plan,
                                            on_shorter_plan=shorter_plan),
                               stop, heartbeat)
    except VerificationError as err:
        result, problems = err.plan, err.problems
    except PlanningError as err:
        print(f"error: {err}", file=sys.stderr)
        written = err.partial is None or not err.partial.segments or \
            _save_plan(err.partial, args, scenario)
        return _failed_writes(CONFLICT if err.proven else FAILED,
                              _exported(export, args) and written)
    finally:
        if budget is not None:
            budget.cancel()
    exported = _exported(export, args)
    resting = sum(d is not None for d in result.delivered_step)
    already = f" ({scenario.n_objects - left} already there)" if left < scenario.n_objects else ""
    print(f"total: {resting}/{scenario.n_objects} resting in their goals{already}, cost "
          f"{result.total_cost:.3f}, solve time {result.total_solve_time_s:.2f} s "
          f"(CPU {result.total_cpu_time_s:.2f} s)")
    written = _save_plan(result, args, scenario) and exported
    if stop.is_set() and not received:  # --budget spent: the best complete plan, or none
        print(f"budget of {args.budget:g} s spent: "
              + ("the best complete plan so far" if not result.partial else
                 f"no complete plan, {len(result.segments)} step(s) written"), flush=True)
        if result.partial:
            return FAILED
    elif stop.is_set():  # a signal: planning stopped, or verification was not waited for
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
    print(certificate(result))
    return _failed_writes(OK, written)


def certificate(result) -> str:
    """The plan's certificate in one line: its cost against its proven bound, whether every
    step's horizon is proven minimal, and when the first verified plan existed."""
    minimal = ("every step's horizon proven minimal" if result.horizon_proven_minimal else
               "not every step's horizon proven minimal")
    return (f"certificate: cost {result.total_cost:.3f}, proven bound {result.total_bound:.3f} "
            f"(gap {100 * result.gap:.2f} %), {minimal}; first verified plan after "
            f"{result.first_plan_s:.2f} s")


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
    from dualarm_mpc.sim.closed_loop import check_events, default_duration, simulate

    # before the flags: --set 'solver.realtime: false' wins
    realtime = {"solver": {"realtime": True}} if args.realtime or args.meshcat else None
    scenario = _load(args, realtime, on_robot=True)
    check_events(scenario, args.duration)
    print(f"{scenario.name}: closed loop, {scenario.n_objects} objects, rule {scenario.task.rule}, "
          f"(m_o, n_o) = ({scenario.task.m_o}, {scenario.task.n_o})")
    if _check(scenario, joint=False, file=sys.stderr).conflicts:
        return CONFLICT
    _objects_left(scenario)
    progress = _ReplanTable(scenario, args.duration or default_duration(scenario))
    meshcat = None
    if args.meshcat:
        from dualarm_mpc.sim.recording import start_meshcat

        meshcat = start_meshcat(live=True)
        print(f"Meshcat: {meshcat.web_url()} (open it in a browser to watch the run live; "
              "it replays the run when the run ends)", flush=True)
    html = _output_of(args, "html")
    try:
        summary = simulate(scenario, args.duration, html, progress, meshcat=meshcat,
                           record_contacts=args.record_contacts)
    finally:
        progress.finish()
    n_in = sum(d is not None for d in summary.delivered_time_s)
    wall = summary.wall_clock
    print(f"end: t = {summary.sim_time_s:.1f} s, {n_in}/{scenario.n_objects} objects resting in "
          f"their goals, {summary.mode}; wall time {wall['wall_time_s']:.1f} s, real-time factor "
          f"{wall['realtime_factor']:.2f}")
    partial = " (partial)" if summary.interrupted else ""
    written = _write(_output_of(args, "summary"), summary.save, partial)
    written = _write(_output_of(args, "plot"), lambda out: _plot_run(summary, out, scenario),
                     partial) and written
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


def _plot_run(summary, path, scenario) -> None:
    """``--plot``: the run's timeline (``figures/timeline.py``), from its summary."""
    from dualarm_mpc.figures.timeline import plot_timeline

    data = summary.to_json()
    delivered = sum(d is not None for d in summary.delivered_time_s)
    plot_timeline(data, path, f"{scenario.name}, rule {scenario.task.rule}, closed loop "
                  f"({summary.mode}): {delivered}/{scenario.n_objects} delivered, t = "
                  f"{summary.sim_time_s:.1f} s" + (" (partial)" if summary.interrupted else ""))


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


class _ReplanTable:
    """``simulate``'s table, told of each replan: a line per replan, a run of replans that
    change nothing (no new plan adopted, or the same hold at rest of ``done`` and ``stuck``;
    status, horizon, objects, note and objects delivered alike) one line with the run's times,
    its count and its longest solve. On a terminal, one line
    below the table, rewritten in place, says how far the run is: the sequential step (counted
    as the replans' objects change), objects delivered, simulated time, the real-time factor
    and the wall time left at it (the run ends about when the objects left are delivered at the
    pace so far, at ``duration`` at the latest)."""

    def __init__(self, scenario, duration: float) -> None:
        self.scenario, self.duration = scenario, duration
        self.tty = sys.stdout.isatty()
        self.run: list = []  # replans not printed yet: a run of alike ones
        self.step, self.objects = 0, None
        self.wall0: float | None = None
        self.shown = False  # the progress line is on the screen
        print(f"{'t [s]':>11}  {'delivered':>9}  {'status':<10} {'T':>3}  {'solve [s]':>9}  "
              "objects")

    @staticmethod
    def _key(r) -> tuple:
        return r.status, r.horizon, r.objects, r.note, r.n_delivered

    @staticmethod
    def _new_plan(r) -> bool:
        return r.adopted and r.status not in ("done", "stuck")

    def __call__(self, r) -> None:
        if self.wall0 is None:
            self.wall0 = time.perf_counter() - r.wall_s
        if r.objects and r.objects != self.objects:
            self.step, self.objects = self.step + 1, r.objects
        if self.run and not self._new_plan(r) and self._key(r) == self._key(self.run[-1]):
            self.run.append(r)
        else:
            self._print_run()
            self.run = [r]
        if self._new_plan(r):  # never the start of a run
            self._print_run()
        if self.tty:
            self._progress(r)

    def finish(self) -> None:
        """The run is over: the replans not yet printed, and no progress line."""
        self._print_run()
        self._clear()

    def _clear(self) -> None:
        if self.shown:
            sys.stdout.write("\r\x1b[K")
            self.shown = False

    def _print_run(self) -> None:
        if not self.run:
            return
        self._clear()
        first, last, n = self.run[0], self.run[-1], len(self.run)
        when = f"{first.t:.1f}" if n == 1 else f"{first.t:.1f}–{last.t:.1f}"
        status = first.status if n == 1 else f"{first.status} ×{n}"
        names = ",".join(self.scenario.task.objects[j].name.removeprefix("object")
                         for j in first.objects)
        line = (f"{when:>11}  {first.n_delivered:>5}/{self.scenario.n_objects:<3}  "
                f"{status:<10} {first.horizon if first.horizon is not None else '-':>3}  "
                f"{max(r.wall_s for r in self.run):>9.3f}  {names}"
                + (f"  ({first.note})" if first.note else ""))
        print(line.rstrip(), flush=True)
        self.run = []

    def _progress(self, r) -> None:
        wall = time.perf_counter() - self.wall0
        n, k = self.scenario.n_objects, r.n_delivered
        text = f"step {self.step}, delivered {k}/{n}, t = {r.t:.1f} s"
        if r.t > 0 and wall > 0:
            factor = r.t / wall
            end = min(self.duration, r.t * n / k) if k else self.duration
            text += (f", real-time factor {factor:.2f}, {'about' if k else 'at most'} "
                     f"{max(end - r.t, 0) / factor:.0f} s left")
        sys.stdout.write(f"\r\x1b[K{text}")
        sys.stdout.flush()
        self.shown = True
