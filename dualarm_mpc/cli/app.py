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
import logging
import os
import sys

from dualarm_mpc import __version__
from dualarm_mpc.cli.arguments import (
    OUTPUT_FLAGS,
    Once,
    directory,
    flags_problem,
    output,
    paths_problem,
    plot,
    scenario_arguments,
    seconds,
)
from dualarm_mpc.cli.commands import cmd_check, cmd_plan, cmd_simulate
from dualarm_mpc.cli.process import (
    BAD_INPUT,
    Abandoned,
    outputs_left,
    signal_name,
    stop_signals,
    stopped,
    sturdy_streams,
)
from dualarm_mpc.logic.parser import LTLSyntaxError
from dualarm_mpc.model.scenario import ScenarioError


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dualarm-mpc", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("check", help="decide whether the task, the rules and the bounds admit a "
                       "plan; name each conflict (exit 3)")
    scenario_arguments(p)
    p.set_defaults(run=cmd_check, parser=p)
    p = sub.add_parser("plan", help="plan the whole task (sequential transportation) and verify it")
    scenario_arguments(p)
    p.add_argument("--out", type=output, action=Once, help="write the plan JSON here")
    p.add_argument("--plot", type=plot, action=Once,
                   help="write a PNG (or PDF, SVG, ...) of the plan here")
    p.add_argument("--export", type=directory, action=Once, metavar="DIR",
                   help="write the monolithic MILP of each horizon tried as an MPS file here, "
                   "with index.json")
    p.add_argument("--budget", type=seconds, action=Once, metavar="S",
                   help="stop searching after S wall seconds: the best complete plan so far is "
                   "written, with its certificate")
    p.set_defaults(run=cmd_plan, parser=p)
    p = sub.add_parser("simulate", help="run the receding-horizon planner on the robot in Drake")
    scenario_arguments(p)
    p.add_argument("--duration", type=seconds,
                   help="simulated seconds (default: by object count)")
    p.add_argument("--html", type=output, action=Once,
                   help="write the self-contained Meshcat replay here")
    p.add_argument("--summary", type=output, action=Once, help="write the summary JSON here")
    p.add_argument("--plot", type=plot, action=Once,
                   help="write a PNG (or PDF, SVG, ...) of the run's timeline here: what each "
                   "hand held, the replans, deliveries, events and the arms' clearance")
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
    args = None
    with stop_signals(), sturdy_streams():
        try:
            args = _parser().parse_args(argv)
            logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                                format="%(levelname)s %(name)s: %(message)s")
            code = _run(args)
        except Abandoned:  # its thread still runs (HiGHS, a pool): end without waiting for it
            print(f"interrupted by {signal_name()}: nothing was written", file=sys.stderr,
                  flush=True)
            sys.stdout.flush()
            os._exit(stopped())
        except KeyboardInterrupt:  # outside a solve (or a second signal): nothing left to keep
            asked = [path for flag in OUTPUT_FLAGS if (path := getattr(args, flag, None))]
            print(f"interrupted by {signal_name()}{outputs_left(asked)}", file=sys.stderr)
            code = stopped()
    return code


def _run(args: argparse.Namespace) -> int:
    """The command, with bad input (refused before any work) as one line and exit 2."""
    from dualarm_mpc.milp.encoding import EncodingError  # here: it loads pydrake
    from dualarm_mpc.milp.solver import SolverUnavailable

    try:
        problem = flags_problem(args) or paths_problem(args)
        if problem:
            args.parser.error(problem)
        return args.run(args)
    except (ScenarioError, LTLSyntaxError, EncodingError, SolverUnavailable) as err:  # one line
        print(f"error: {err}", file=sys.stderr)
        return BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
