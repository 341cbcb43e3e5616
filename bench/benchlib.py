"""Shared helpers of the benchmark runners (bench/table2.py, bench/closed_loop.py,
bench/robustness.py).

The runners import it as ``from benchlib import ...``: run as ``python bench/x.py``, Python puts
the script's folder on ``sys.path``.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import logging
import os
import platform
import signal
import subprocess
import sys
import time
import timeit
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import scipy.sparse as sp

import dualarm_mpc
from dualarm_mpc.milp.backends import highs_model
from dualarm_mpc.milp.solver import BACKENDS, StandardForm, installed_backends

# --- command line ------------------------------------------------------------------------------


def options_json(args: argparse.Namespace) -> dict:
    """The command line's options as the JSON records keep them (paths as text)."""
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}


def parse_numbers(text: str) -> list[int]:
    """``12-17`` (a range) or ``12,14,16`` (a list; one number is a list of one)."""
    if "-" in text:
        lo, hi = (int(v) for v in text.split("-"))
        return list(range(lo, hi + 1))
    return [int(v) for v in text.split(",")]


def parse_seeds(text: str) -> list[int]:
    """``0-9`` (a range), ``0,3,7`` (a list) or ``10`` (a count: seeds 0..9); never empty."""
    try:
        seeds = parse_numbers(text) if "-" in text or "," in text else list(range(int(text)))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected 0-9, 0,3,7 or a count, got {text!r}") from err
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in {text!r} (a single number is a count; "
                                         "seed 0 alone is 0-0)")
    return seeds


def cluster_arguments(p: argparse.ArgumentParser) -> None:
    """``--workers N`` (a local Dask cluster) and ``--scheduler ADDRESS`` (an existing one)."""
    p.add_argument("--workers", "--jobs", dest="workers", type=int, default=1,
                   help="run the runs as Dask tasks on a local cluster of N worker processes, "
                        "one run each at a time (default 1: one run at a time in this process, "
                        "without Dask; a run then has the machine to itself)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the runs as Dask tasks on the cluster whose scheduler is at ADDRESS "
                        "(e.g. tcp://10.0.0.5:8786); its workers need dualarm_mpc installed")


def check_cluster_arguments(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.workers < 1:
        p.error("--workers must be >= 1")
    if args.scheduler and args.workers > 1:
        p.error("--workers starts a local cluster and --scheduler uses another: give one")


# --- runs: in this process, or as Dask tasks ---------------------------------------------------


def run_tasks(fn: Callable[[dict], dict], tasks: list[dict], workers: int = 1,
              scheduler: str | None = None, modules: tuple[Path, ...] = ()
              ) -> Iterator[tuple[int, dict]]:
    """``fn(task)`` for every task, yielded as ``(index, record)`` as the runs finish: one after
    the other in this process (``workers`` 1, no ``scheduler``; Dask is not needed), or as Dask
    tasks on a local cluster of ``workers`` processes with one thread each, or on the cluster at
    ``scheduler``, whose workers get ``modules`` (the helper modules ``fn`` imports) uploaded.

    Each record gets ``host`` (where it ran) and ``runs_per_host``: how many runs that host ran
    at once (its worker threads); above 1 the runs shared the machine, and their times show it.
    """
    if workers <= 1 and scheduler is None:
        for i, task in enumerate(tasks):
            yield i, {**fn(task), "host": platform.node(), "runs_per_host": 1}
        return
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise SystemExit("--workers and --scheduler run on Dask: pip install "
                         "'dualarm_mpc[dask]'") from None
    cluster = None if scheduler else LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
        silence_logs=logging.ERROR)
    with Client(scheduler or cluster) as client:
        if scheduler:
            for path in modules:
                client.upload_file(str(path))
        hosts = client.run(platform.node)  # worker address → its machine's name
        slots: dict[str, int] = {}
        for address, info in client.scheduler_info()["workers"].items():
            slots[hosts[address]] = slots.get(hosts[address], 0) + info["nthreads"]
        futures = {client.submit(fn, task, pure=False): i for i, task in enumerate(tasks)}
        for future in as_completed(futures):
            host = hosts.get(client.who_has(future)[future.key][0], "?")
            yield futures[future], {**future.result(), "host": host,
                                    "runs_per_host": slots.get(host, 1)}
    if cluster is not None:
        cluster.close()


class Progress:
    """A progress bar on stderr under the lines of the finished runs: redrawn in place on a
    terminal, printed after each run's line otherwise (a log)."""

    def __init__(self, total: int, width: int = 30) -> None:
        self.total, self.width, self.done = total, width, 0
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()

    def advance(self, line: str) -> None:
        self.done += 1
        elapsed = time.perf_counter() - self.t0
        left = elapsed / self.done * (self.total - self.done)
        filled = self.width * self.done // self.total
        bar = (f"[{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total} runs, "
               f"{elapsed:.0f} s, about {left:.0f} s left")
        if self.tty:
            end = "\n" if self.done == self.total else ""
            sys.stderr.write(f"\r\033[K{line}\n{bar}{end}")
        else:
            sys.stderr.write(f"{line}\n{bar}\n")
        sys.stderr.flush()


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


def calibration() -> dict[str, float]:
    """How fast the machine is now, by two fixed workloads that no change of ours affects (best
    of three, seconds): a pure-Python loop, and HiGHS on a fixed 60-item, 8-row 0-1 knapsack
    (one thread, 27 nodes with HiGHS 1.16). The same code measured 20–27 % apart on different
    days of this machine; runs of different days compare only against these."""
    rng = np.random.default_rng(0)
    weight = rng.integers(10, 100, (8, 60)).astype(float)
    value = rng.integers(10, 100, 60).astype(float)
    knapsack = StandardForm(c=-value, c0=0.0, A=sp.csr_matrix(weight),
                            row_lb=np.full(8, -np.inf), row_ub=weight.sum(axis=1) / 2,
                            col_lb=np.zeros(60), col_ub=np.ones(60), integer=np.ones(60, bool))

    def loop() -> None:
        total = 0
        for i in range(3_000_000):
            total += i * i % 7

    def milp() -> None:
        h = highs_model(knapsack)
        h.setOptionValue("threads", 1)
        h.run()

    def best(work: Callable[[], None]) -> float:
        return round(min(timeit.repeat(work, number=1, repeat=3)), 4)

    return {"python_loop_s": best(loop), "highs_knapsack_s": best(milp)}


def footer(info: dict, t0: float) -> str:
    """The report's last lines: the machine's speed at the start (``info["calibration"]``) and
    the wall time since ``t0`` (``time.perf_counter()``)."""
    c = info["calibration"]
    return (f"\nMachine speed at the start (lower is faster; `benchlib.calibration`): Python loop "
            f"{c['python_loop_s']:.3f} s, HiGHS knapsack {c['highs_knapsack_s']:.3f} s\n"
            f"\nTotal wall time: {time.perf_counter() - t0:.0f} s\n")


# The child process that slows this one down (slowed): it stops the process for a share of
# every period (SIGSTOP, SIGCONT) until the process is gone.
_THROTTLE = """
import os, signal, sys, time
pid, period, stopped = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
while os.getppid() == pid:
    time.sleep(period - stopped)
    os.kill(pid, signal.SIGSTOP)
    time.sleep(stopped)
    os.kill(pid, signal.SIGCONT)
"""


@contextmanager
def slowed(factor: float | None, period_s: float = 0.02) -> Iterator[None]:
    """This process as on a machine ``factor`` times slower, for the length of a ``with``: a
    child stops it for 1 − 1/factor of every ``period_s`` (all its threads: HiGHS's and
    CP-SAT's too; wall-clock limits then buy 1/factor of the work, as on the slower machine).
    :func:`calibration`, measured inside, says how much slower. None: as it is."""
    if factor is None or factor <= 1:
        yield
        return
    child = subprocess.Popen([sys.executable, "-c", _THROTTLE, str(os.getpid()),
                              str(period_s), str(period_s * (1 - 1 / factor))])
    try:
        yield
    finally:
        child.kill()
        child.wait()
        os.kill(os.getpid(), signal.SIGCONT)  # in case it was killed between its two signals


def machine() -> dict:
    """The machine and the code measured: when (UTC), where ``dualarm_mpc`` was imported from, its
    commit and uncommitted changes (None outside a git checkout, e.g. a snapshot), and its speed
    now (:func:`calibration`)."""
    package = Path(dualarm_mpc.__file__).parent
    return {
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "platform": platform.platform(), "processor": platform.processor(),
        "cpu_count": os.cpu_count(), "python": sys.version.split()[0],
        "highspy": importlib.metadata.version("highspy"),
        "drake": importlib.metadata.version("drake"),
        "solvers": {name: importlib.metadata.version(BACKENDS[name][0])
                    for name in installed_backends()},
        "dualarm_mpc": str(package), "git_commit": git(package, "rev-parse", "HEAD"),
        "git_changes": git(package, "status", "--porcelain", "--", "."),
        "calibration": calibration(),
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
