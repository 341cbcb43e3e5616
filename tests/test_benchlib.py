"""The benchmarks' shared helpers (bench/benchlib.py): the machine record and its calibration."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import benchlib  # noqa: E402


def test_the_machine_record_carries_its_speed_by_two_fixed_workloads() -> None:
    info = benchlib.machine()
    speed = info["calibration"]
    assert set(speed) == {"python_loop_s", "highs_knapsack_s"}
    assert all(0 < s < 60 for s in speed.values())
    line = benchlib.footer(info, 0.0)
    for seconds in speed.values():
        assert f"{seconds:.3f} s" in line
