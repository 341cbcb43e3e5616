"""Interrupts lose nothing: a stop request ends planning with the steps completed so far, marked
partial and still verified step by step; Ctrl-C on the command line does the same, in one line,
and the command has exited within STOP_S of it."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time

import pytest

from dualarm_mpc.horizon import solver_options
from dualarm_mpc.plan import Plan
from dualarm_mpc.scenario import load_scenario
from dualarm_mpc.sequential import plan
from dualarm_mpc.solver import Interrupt
from dualarm_mpc.verify import verify

# Ctrl-C to exit, everything written: about 1 s (plan) and 0.5 s (simulate) here, idle.
STOP_S = 10.0


def ctrl_c(proc: subprocess.Popen) -> tuple[str, str]:
    """SIGINT to ``proc``, and its stdout and stderr once it exited, within STOP_S."""
    proc.send_signal(signal.SIGINT)
    try:
        return proc.communicate(timeout=STOP_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"still running {STOP_S:g} s after Ctrl-C")


def test_a_stop_after_the_first_step_returns_it_as_a_partial_plan() -> None:
    scenario = load_scenario("table1_vd", {"rule": 2, "seed": 1})
    stop = Interrupt()
    options = dataclasses.replace(solver_options(scenario), interrupt=stop)
    result = plan(scenario, options, progress=lambda seg: stop.set())
    assert result.partial and len(result.segments) == 1
    assert result.trajectory.steps == result.segments[0].horizon
    assert verify(scenario, result).ok  # each step completed satisfies its specification
    assert Plan.from_json(json.loads(json.dumps(result.to_json()))).partial


def test_a_stop_before_the_first_step_returns_the_initial_state() -> None:
    scenario = load_scenario("table1_vd", {"rule": 2, "seed": 1})
    stop = Interrupt()
    stop.set()
    result = plan(scenario, dataclasses.replace(solver_options(scenario), interrupt=stop))
    assert result.partial and not result.segments and result.trajectory.steps == 0


@pytest.mark.slow
def test_ctrl_c_during_plan_writes_the_steps_so_far(tmp_path) -> None:
    out = tmp_path / "plan.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "dualarm_mpc.cli", "plan", "table1_vd", "--seed", "3",
         "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stdout:  # the first step's line: its number in the first column
        if line.split() and line.split()[0] == "1":
            break
    stdout, stderr = ctrl_c(proc)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert "interrupted" in stderr
    data = json.loads(out.read_text())
    assert data["partial"] is True and len(data["segments"]) >= 1
    assert "(partial)" in stdout


@pytest.mark.slow
def test_ctrl_c_during_simulate_writes_the_summary_and_replay(tmp_path) -> None:
    summary, html = tmp_path / "summary.json", tmp_path / "replay.html"
    proc = subprocess.Popen(
        [sys.executable, "-m", "dualarm_mpc.cli", "simulate", "table1_vd", "--seed", "0",
         "--summary", str(summary), "--html", str(html)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stdout:  # a replan line: the simulated time in the first column
        if line.split() and line.split()[0].replace(".", "", 1).isdigit():
            break
    stdout, stderr = ctrl_c(proc)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "interrupted at t =" in stderr
    data = json.loads(summary.read_text())
    assert data["interrupted"] is True and data["sim_time_s"] > 0
    assert html.stat().st_size > 0


def test_a_search_without_news_says_it_is_still_searching(tmp_path, capsys, monkeypatch) -> None:
    from dualarm_mpc import cli

    monkeypatch.setattr(cli, "HEARTBEAT_S", 0.0)  # every tick: the line a long search prints
    from dualarm_mpc import sequential

    def slow_first_step(scenario, options, progress, tried):  # a step longer than a 0.1 s tick
        return plan(scenario, options, lambda seg: (time.sleep(0.5), progress(seg)), tried)

    monkeypatch.setattr(sequential, "plan", slow_first_step)
    assert cli.main(["plan", "table1_vd", "--seed", "1", "--set", "random_objects.count: 4"]) == 0
    assert "still searching step 1:" in capsys.readouterr().out
