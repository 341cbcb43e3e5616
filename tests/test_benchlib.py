"""The benchmarks' shared helpers (bench/benchlib.py): the machine record and its calibration."""

from __future__ import annotations

import time
from pathlib import Path

import benchlib
import demo

ROOT = Path(__file__).resolve().parents[1]


def test_the_machine_record_carries_its_speed_by_two_fixed_workloads() -> None:
    info = benchlib.machine()
    speed = info["calibration"]
    assert set(speed) == {"python_loop_s", "highs_knapsack_s"}
    assert all(0 < s < 60 for s in speed.values())
    line = benchlib.footer(info, 0.0)
    for seconds in speed.values():
        assert f"{seconds:.3f} s" in line


def test_a_slowed_bench_gets_a_share_of_the_wall_time_and_is_left_running() -> None:
    """``slowed(2)`` stops this process half the time: a busy loop inside gets at most about
    half its wall time as CPU time (less on a loaded machine, never more); afterwards the
    process runs on, not left stopped."""
    def cpu_share(seconds: float) -> float:
        wall0, cpu0 = time.perf_counter(), time.process_time()
        while time.perf_counter() - wall0 < seconds:
            pass
        return (time.process_time() - cpu0) / (time.perf_counter() - wall0)

    with benchlib.slowed(2.0):
        assert cpu_share(1.0) < 0.75
    assert cpu_share(0.2) > 0  # running


def test_demo_bench_runs_the_makefiles_demo_commands():
    """bench/demo.py reads `make demo`'s commands from the Makefile: plan, then simulate, with
    every flag the Makefile gives, its outputs in the folder asked for."""
    plan, simulate = demo.demo_commands(Path("/tmp/x"))
    recipe = (ROOT / "Makefile").read_text().split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    assert plan[1:4] == ["plan", "table1_vc", "--rule"] and simulate[1] == "simulate"
    for flag in ("--out", "--plot", "--set"):
        assert flag in plan
    assert "/tmp/x/replay.html" in simulate and "/tmp/x/summary.json" in simulate
    assert recipe.count("\t$(BIN)/dualarm-mpc") == 2  # the prerequisite line aside
