"""Command line: ``dualarm-mpc check``, ``plan`` and ``simulate`` (the closed loop in Drake).

Exit codes, the same for every command (docs/cli.md):

  0    done, consistent, or nothing to do
  2    bad input: a scenario field, flag, formula or path (two outputs on one path, an output
       on an input, a path that is neither a regular file nor a new one), always before any work
  3    conflict: the task provably has no plan (the check's conflict, or every horizon up to
       the cap proven infeasible)
  4    undecided within the time limits, or a failed run (a plan that fails verification, an
       object not delivered), or an output that could not be written (one line: path, reason)
  129 / 130 / 143   stopped by SIGHUP / SIGINT (Ctrl-C) / SIGTERM: what ran is written, partial
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import math
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from dualarm_mpc.base import outputs
from dualarm_mpc.logic.parser import LTLSyntaxError
from dualarm_mpc.model.scenario import (
    SOLVER_BACKENDS,
    ScenarioError,
    load_scenario,
    merge_overrides,
    parse_override,
    scenario_path,
)

HEARTBEAT_S = 15.0  # seconds of a phase without a line before it says it is still going on

OK, BAD_INPUT, CONFLICT, FAILED = 0, 2, 3, 4  # exit codes; a stop signal: 128 + its number
# Each stops a run as Ctrl-C does: the work so far is written, marked partial.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_received: list[int] = []  # the stop signals received by this run, first first


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
    """A file the run writes at its end, checked before the run starts (``outputs.py``): a
    directory that does not exist or a place that cannot be written would lose the work."""
    problem = outputs.output_problem(path)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return path


def _directory(path: str) -> str:
    """A directory the run writes files into, checked before the run starts: made if missing
    (in a directory that exists)."""
    problem = outputs.directory_problem(path)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return path


class _Once(argparse.Action):
    """A flag that names an output: given twice, one of the two would be silently dropped."""

    def __call__(self, parser, namespace, value, option_string=None) -> None:
        if getattr(namespace, self.dest) is not None:
            raise argparse.ArgumentError(self, "given twice: each output is named once")
        setattr(namespace, self.dest, value)


def _plot(path: str) -> str:
    """An output file whose suffix names a format matplotlib writes here (PGF needs a TeX)."""
    from matplotlib import rcParams
    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = Path(path).suffix.lstrip(".").lower()
    if suffix not in formats:
        raise argparse.ArgumentTypeError(f"unknown plot format {suffix or '(no suffix)'!r} "
                                         f"(one of {', '.join(sorted(formats))})")
    tex = rcParams["pgf.texsystem"]
    if suffix == "pgf" and shutil.which(tex) is None:
        raise argparse.ArgumentTypeError(f"plot format 'pgf' needs {tex}, which is not installed")
    return _output(path)


OUTPUT_FLAGS = ("out", "plot", "html", "summary")


def _paths_problem(args: argparse.Namespace) -> str | None:
    """Two outputs on one file, or an output on an input (the scenario file, ``--export``'s
    files): one of them would be lost. Symbolic links, ``..`` and hard links are seen
    through."""
    named = [(f"--{flag}", path) for flag in OUTPUT_FLAGS
             if (path := getattr(args, flag, None)) is not None]
    for i, (flag, path) in enumerate(named):
        for other, other_path in named[:i]:
            if outputs.same_file(path, other_path):
                where = path if path == other_path else f"{other_path} and {path}"
                return f"{other} and {flag} name one file ({where}): give each its own path"
    scenario = scenario_path(args.scenario)
    for flag, path in named:
        if outputs.same_file(path, scenario):
            return f"{flag} is the scenario file ({path}): writing it would destroy the input"
    export = getattr(args, "export", None)
    if export is not None:
        from dualarm_mpc.milp.export import exported_file

        for flag, path in [*named, ("the scenario", str(scenario))]:
            if outputs.same_file(path, export):
                return f"{flag} and --export name one path ({path})"
            if outputs.same_file(os.path.dirname(os.path.realpath(path)), export) and \
                    exported_file(os.path.basename(os.path.realpath(path))):
                return f"{flag} ({path}) is a file --export writes in {export}"
    return None


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


def _check(scenario, joint: bool, file=None):
    """Run the consistency check (``consistency.py``) and print what it found. Nothing of it
    is kept if a signal stops it."""
    from dualarm_mpc.planning.consistency import check

    done = [0, 0]  # objects checked, of how many

    def progress(n: int, total: int) -> None:
        done[:] = max(done[0], n), total

    report = _interruptible(
        lambda: check(scenario, joint=joint, progress=progress),
        tick=_heartbeat(lambda: "checking the task against the rules"
                        + (f" ({done[0]} of {done[1]} objects checked)" if done[1] else "")))
    for conflict in report.conflicts:
        print(f"conflict: {conflict}", file=file or sys.stdout)
    for what in report.undecided:
        print(f"undecided within the time limit: {what}", file=file or sys.stdout)
    return report


def _load(args: argparse.Namespace, overrides: bool = True):
    """The scenario of the command line (with the flags' overrides); nothing to keep if a
    signal stops it."""
    return _interruptible(lambda: load_scenario(args.scenario,
                                                _overrides(args) if overrides else None),
                          tick=_heartbeat("reading the scenario"))


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


class _Abandoned(KeyboardInterrupt):
    """A signal stopped a phase that has nothing to keep; its thread still runs."""


def _interruptible(work, stop=None, tick=lambda: None):
    """``work()`` on a thread, so that a stop signal (SIGINT, SIGTERM, SIGHUP: a
    ``KeyboardInterrupt`` here) reaches the main thread at once (a HiGHS run holds it until it
    returns). With ``stop`` (a ``solver.Interrupt``) the signal stops the solves and ``work``
    returns what it has; without, ``work`` has nothing to keep and is left to run
    (:class:`_Abandoned`: the process ends without waiting for it). ``tick()`` runs every
    0.1 s."""
    out: dict = {}
    done = threading.Event()  # not Thread.join: a join cut short by a signal can lose the thread

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
        if stop is None:
            raise _Abandoned from None
        stop.set()
        print(f"interrupted by {_signal_name()}: stopping the solver", file=sys.stderr,
              flush=True)
        done.wait()
    if "error" in out:
        raise out["error"]
    return out["value"]


def _heartbeat(what: str | Callable[[], str]):
    """A ``tick`` that says ``what`` (or what ``what()`` says now) is still going on every
    ``HEARTBEAT_S``: no phase is silent for long."""
    start = said = time.perf_counter()

    def tick() -> None:
        nonlocal said
        now = time.perf_counter()
        if now - said >= HEARTBEAT_S:
            print(f"{what() if callable(what) else what}: {now - start:.0f} s so far",
                  flush=True)
            said = now

    return tick


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
    from dualarm_mpc.milp.horizon import HorizonProgram, solve_options
    from dualarm_mpc.milp.solver import Interrupt
    from dualarm_mpc.model.verify import verify
    from dualarm_mpc.planning.sequential import PlanningError, transport

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
        if now - said[0] >= HEARTBEAT_S:
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
            form = HorizonProgram(scenario, t.state, list(t.spec.objects),
                                  res.horizon).standard_form(t.spec)
            export.add(t.step, t.spec, res.horizon, res.status, res.cost, form)
        if not res.status.has_solution:
            said[0] = time.perf_counter()
            by = "  (CP-SAT)" if res.message.startswith("CP-SAT") else ""
            print(f"{'':>4}  {'':<22} {res.horizon:>3} {res.binaries:>8}  "
                  f"{res.status.value:<10} {res.solve_time_s:>9.2f}{by}", flush=True)

    stop = Interrupt()
    options = dataclasses.replace(solve_options(scenario), interrupt=stop)
    try:
        result = _interruptible(lambda: transport(scenario, options, progress, tried), stop,
                                heartbeat)
    except PlanningError as err:
        print(f"error: {err}", file=sys.stderr)
        written = err.partial is None or not err.partial.segments or \
            _save_plan(err.partial, args, scenario)
        return _failed_writes(CONFLICT if err.proven else FAILED,
                              _exported(export, args) and written)
    exported = _exported(export, args)
    try:
        check = verify(scenario, result)
    except KeyboardInterrupt:  # a signal while verifying: the plan is written, not verified
        check = None
    result = dataclasses.replace(result, verified=check is not None and check.ok)
    resting = sum(d is not None for d in result.delivered_step)
    already = f" ({scenario.n_objects - left} already there)" if left < scenario.n_objects else ""
    print(f"total: {resting}/{scenario.n_objects} resting in their goals{already}, cost "
          f"{result.total_cost:.3f}, solve time {result.total_solve_time_s:.2f} s "
          f"(CPU {result.total_cpu_time_s:.2f} s)")
    written = _save_plan(result, args, scenario) and exported
    if result.partial or check is None:
        print(f"interrupted by {_signal_name()} after {len(result.segments)} step(s): what was "
              "written is partial"
              + ("" if check is not None else " and not verified"), file=sys.stderr)
        return _stopped()
    if not check.ok:
        print("error: the plan fails verification:\n  " + "\n  ".join(check.problems),
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
    from dualarm_mpc.model.scenario import apply_overrides
    from dualarm_mpc.sim.closed_loop import check_events, on_robot, simulate

    base = _load(args, overrides=False)
    overrides = on_robot(base)
    if args.realtime or args.meshcat:  # before the flags: --set 'solver.realtime: false' wins
        merge_overrides(overrides, {"solver": {"realtime": True}})
    merge_overrides(overrides, _overrides(args))
    scenario = apply_overrides(base, overrides)
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
        print(f"interrupted by {_signal_name()} at t = {summary.sim_time_s:.1f} s: the summary "
              "and replay end there", file=sys.stderr)
        return _stopped()
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
        _received.clear()


def _stopped() -> int:
    """The exit code of a run a signal stopped: 128 + the signal's number (130 for Ctrl-C)."""
    return 128 + (_received[0] if _received else signal.SIGINT)


def _signal_name() -> str:
    return signal.Signals(_stopped() - 128).name


@contextlib.contextmanager
def _stop_signals():
    """SIGTERM and SIGHUP stop the run as SIGINT does: a ``KeyboardInterrupt`` on the main
    thread, the signal noted for the exit code."""
    def stop(signum: int, frame) -> None:
        _received.append(signum)
        raise KeyboardInterrupt

    _received.clear()
    before = {s: signal.signal(s, stop) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)


class _Sturdy:
    """A standard stream whose reader may go (``| head -1``; the terminal, with SIGHUP): once a
    write fails it points at /dev/null and the run goes on to write its files (the recipe of
    Python's ``signal`` docs for BrokenPipeError)."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError:
            self._lost()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError:
            self._lost()

    def _lost(self) -> None:
        with contextlib.suppress(OSError, ValueError):  # ValueError: no file descriptor
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self._stream.fileno())
            os.close(devnull)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


@contextlib.contextmanager
def _sturdy_streams():
    saved = sys.stdout, sys.stderr
    for fd in (1, 2):  # started closed (``>&-``): a file opened later would take its number
        try:
            os.fstat(fd)
        except OSError:
            os.dup2(os.open(os.devnull, os.O_WRONLY), fd)
    # Python leaves a stream that started closed None
    sys.stdout, sys.stderr = (_Sturdy(s or open(os.devnull, "w")) for s in saved)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dualarm-mpc", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("check", help="decide whether the task, the rules and the bounds admit a "
                       "plan; name each conflict (exit 3)")
    _scenario_arguments(p)
    p.set_defaults(run=cmd_check, parser=p)
    p = sub.add_parser("plan", help="plan the whole task (sequential transportation) and verify it")
    _scenario_arguments(p)
    p.add_argument("--out", type=_output, action=_Once, help="write the plan JSON here")
    p.add_argument("--plot", type=_plot, action=_Once,
                   help="write a PNG (or PDF, SVG, ...) of the plan here")
    p.add_argument("--export", type=_directory, action=_Once, metavar="DIR",
                   help="write the monolithic MILP of each horizon tried as an MPS file here, "
                   "with index.json")
    p.set_defaults(run=cmd_plan, parser=p)
    p = sub.add_parser("simulate", help="run the receding-horizon planner on the robot in Drake")
    _scenario_arguments(p)
    p.add_argument("--duration", type=_seconds,
                   help="simulated seconds (default: by object count)")
    p.add_argument("--html", type=_output, action=_Once,
                   help="write the self-contained Meshcat replay here")
    p.add_argument("--summary", type=_output, action=_Once, help="write the summary JSON here")
    p.add_argument("--meshcat", action="store_true",
                   help="start Drake's Meshcat server, print its URL and draw the run there live, "
                   "at real time (implies --realtime)")
    p.add_argument("--record-contacts", action="store_true",
                   help="also draw and record the contact forces and the proximity and inertia "
                   "geometry (hidden at first; a larger replay)")
    p.add_argument("--realtime", action="store_true",
                   help="replan against the wall clock (a replan holds the simulation for "
                   "solver.replan_budget_s at most): the run depends on the machine's speed and "
                   "load. Default: lockstep, the same run on any machine")
    p.set_defaults(run=cmd_simulate, parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    with _stop_signals(), _sturdy_streams():
        try:
            args = _parser().parse_args(argv)
            logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                                format="%(levelname)s %(name)s: %(message)s")
            code = _run(args)
        except _Abandoned:  # its thread still runs (HiGHS, a pool): end without waiting for it
            print(f"interrupted by {_signal_name()}: nothing was written", file=sys.stderr,
                  flush=True)
            sys.stdout.flush()
            os._exit(_stopped())
        except KeyboardInterrupt:  # outside a solve (or a second signal): nothing left to keep
            print(f"interrupted by {_signal_name()}", file=sys.stderr)
            code = _stopped()
    return code


def _run(args: argparse.Namespace) -> int:
    """The command, with bad input (refused before any work) as one line and exit 2."""
    from dualarm_mpc.milp.encoding import EncodingError  # here: it loads pydrake
    from dualarm_mpc.milp.solver import SolverUnavailable

    try:
        problem = _paths_problem(args)
        if problem:
            args.parser.error(problem)
        return args.run(args)
    except (ScenarioError, LTLSyntaxError, EncodingError, SolverUnavailable) as err:  # one line
        print(f"error: {err}", file=sys.stderr)
        return BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
