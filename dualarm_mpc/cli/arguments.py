"""The command line's flags: their types (a bad value is an argparse error naming the flag, exit
2, before any work), the scenario's overrides they name, and the paths checked before a run."""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

from dualarm_mpc.base import outputs
from dualarm_mpc.model.scenario import (
    SOLVER_BACKENDS,
    merge_overrides,
    parse_override,
    scenario_path,
    seconds_problem,
)


def scenario_overrides(args: argparse.Namespace) -> dict:
    """Scenario fields named by flags; ``--set`` YAML comes last and wins."""
    out: dict = {}
    for flag, field in (("rule", "rule"), ("mo", "m_o"), ("no", "n_o"), ("seed", "seed"),
                        ("delivery", "delivery")):
        value = getattr(args, flag, None)
        if value is not None and value != ALL:  # --mo all: once the objects are known
            out[field] = value
    solver = {key: value for key, value in (("time_limit_s", getattr(args, "time_limit", None)),
                                            ("mip_rel_gap", getattr(args, "gap", None)),
                                            ("search", getattr(args, "search", None)),
                                            ("backend", getattr(args, "solver", None)))
              if value is not None}
    if solver:
        out["solver"] = solver
    for text in args.set or []:
        merge_overrides(out, parse_override(text, f"--set {text!r}"))
    return out


ALL = "all"  # --mo all: every object in one step (task.whole_task)


def count(minimum: int):
    def count(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
        return value

    return count


def objects_per_step(text: str) -> int | str:
    """``--mo``: a count, or ``all`` (m_o = n_o = every object of the scenario)."""
    if text == ALL:
        return ALL
    if not text.lstrip("+-").isdigit():
        raise argparse.ArgumentTypeError(f"expected an integer or all, got {text!r}")
    return count(1)(text)


def fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a relative gap, got {text!r}") from None
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"must be between 0 and 1, got {text}")
    return value


def seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    problem = seconds_problem(value)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return value


def output(path: str) -> str:
    """A file the run writes at its end, checked before the run starts (``outputs.py``): a
    directory that does not exist or a place that cannot be written would lose the work."""
    problem = outputs.output_problem(path)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return path


def directory(path: str) -> str:
    """A directory the run writes files into, checked before the run starts: made if missing
    (in a directory that exists)."""
    problem = outputs.directory_problem(path)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return path


class Once(argparse.Action):
    """A flag that names an output: given twice, one of the two would be silently dropped."""

    def __call__(self, parser, namespace, value, option_string=None) -> None:
        if getattr(namespace, self.dest) is not None:
            raise argparse.ArgumentError(self, "given twice: each output is named once")
        setattr(namespace, self.dest, value)


def plot(path: str) -> str:
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
    return output(path)


OUTPUT_FLAGS = ("out", "plot", "html", "summary")


def flags_problem(args: argparse.Namespace) -> str | None:
    """Flags that contradict each other: ``--no`` with ``--mo all``, which considers every
    object (n_o = m_o = all) and would silently drop it."""
    if getattr(args, "mo", None) == ALL and getattr(args, "no", None) is not None:
        return (f"argument --no: not with --mo all, which considers every object (n_o = all); "
                f"got --no {args.no}")
    return None


def paths_problem(args: argparse.Namespace) -> str | None:
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


def scenario_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", help="a scenario YAML file, or table1_vc / table1_vd")
    p.add_argument("--rule", type=int, choices=(1, 2), help="1: no-throw; 2: no-juggle, no-swap")
    p.add_argument("--mo", type=objects_per_step,
                   help="m_o, objects delivered per sequential step; all: every object in one "
                   "search (sets n_o too)")
    p.add_argument("--no", type=count(1), help="n_o, objects considered per sequential step")
    p.add_argument("--seed", type=count(0), help="seed of random objects (table1_vd)")
    p.add_argument("--delivery", choices=("reach", "rest"), help="what 'delivered' means")
    p.add_argument("--time-limit", type=seconds, help="seconds per horizon of a step")
    p.add_argument("--gap", type=fraction,
                   help="stop a step's optimisation at this relative gap (solver.mip_rel_gap; "
                   "the plan reports the gap it proved)")
    p.add_argument("--search", choices=("skeleton", "monolithic"),
                   help="solve each horizon by the skeleton search (default) or as one MILP")
    p.add_argument("--solver", choices=SOLVER_BACKENDS,
                   help="the MILP solver (default highs; the others where installed)")
    p.add_argument("--set", action="append", metavar="YAML",
                   help="override any scenario field, e.g. --set 'max_speed: 0.3' or "
                   "--set 'solver.time_limit_s: 5' (repeatable)")
