"""Shared helpers of the benchmark runners (bench/table2.py, bench/closed_loop.py).

The runners import it as ``from benchlib import ...``: run as ``python bench/x.py``, Python puts
the script's folder on ``sys.path``.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import dualarm_mpc

# --- command line ------------------------------------------------------------------------------


def parse_seeds(text: str) -> list[int]:
    """``0-9`` (a range), ``0,3,7`` (a list) or ``10`` (a count: seeds 0..9); never empty."""
    try:
        if "-" in text:
            lo, hi = (int(v) for v in text.split("-"))
            seeds = list(range(lo, hi + 1))
        elif "," in text:
            seeds = [int(v) for v in text.split(",")]
        else:
            seeds = list(range(int(text)))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected 0-9, 0,3,7 or a count, got {text!r}") from err
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in {text!r} (a single number is a count; "
                                         "seed 0 alone is 0-0)")
    return seeds


# --- Markdown ----------------------------------------------------------------------------------


def fmt(value, spec: str = ".2f") -> str:
    return "—" if value is None else format(value, spec)


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


# --- output ------------------------------------------------------------------------------------


def git(package: Path, *args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(package), *args], capture_output=True, text=True)
    except OSError:
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def machine() -> dict:
    """The machine and the code measured: where ``dualarm_mpc`` was imported from, its commit and
    uncommitted changes (None outside a git checkout, e.g. a snapshot)."""
    package = Path(dualarm_mpc.__file__).parent
    return {
        "platform": platform.platform(), "processor": platform.processor(),
        "cpu_count": os.cpu_count(), "python": sys.version.split()[0],
        "highspy": importlib.metadata.version("highspy"),
        "drake": importlib.metadata.version("drake"),
        "dualarm_mpc": str(package), "git_commit": git(package, "rev-parse", "HEAD"),
        "git_changes": git(package, "status", "--porcelain", "--", "."),
    }


def write_json_atomic(path: Path, data) -> None:
    """Write ``data`` as JSON to ``path`` (creating its folder) through a temporary file, so a
    reader never sees a half-written file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    tmp.replace(path)


def write_report(json_path: Path, text: str) -> None:
    """Print the Markdown report and write it next to the JSON (``<json>.md``)."""
    print(text)
    json_path.with_suffix(".md").write_text(text)
    print(f"wrote {json_path} and {json_path.with_suffix('.md')}", file=sys.stderr)
