"""Interrupts lose nothing: a stop request ends planning with the steps completed so far, marked
partial and still verified step by step (the stop signals on the command line, each within
seconds of the signal: test_outputs.py)."""

from __future__ import annotations

import dataclasses
import json
import time

from dualarm_mpc.milp.horizon import solve_options
from dualarm_mpc.milp.solver import Interrupt
from dualarm_mpc.model.plan import Plan
from dualarm_mpc.model.scenario import load_scenario
from dualarm_mpc.model.verify import verify
from dualarm_mpc.planning.sequential import transport


def test_a_stop_after_the_first_step_returns_it_as_a_partial_plan() -> None:
    scenario = load_scenario("table1_vd", {"rule": 2, "seed": 1})
    stop = Interrupt()
    options = dataclasses.replace(solve_options(scenario), interrupt=stop)
    result = transport(scenario, options, progress=lambda seg: stop.set())
    assert result.partial and len(result.segments) == 1
    assert result.trajectory.steps == result.segments[0].horizon
    assert verify(scenario, result).ok  # each step completed satisfies its specification
    assert Plan.from_json(json.loads(json.dumps(result.to_json()))).partial


def test_a_stop_before_the_first_step_returns_the_initial_state() -> None:
    scenario = load_scenario("table1_vd", {"rule": 2, "seed": 1})
    stop = Interrupt()
    stop.set()
    result = transport(scenario, dataclasses.replace(solve_options(scenario), interrupt=stop))
    assert result.partial and not result.segments and result.trajectory.steps == 0


def test_a_search_without_news_says_it_is_still_searching(tmp_path, capsys, monkeypatch) -> None:
    from dualarm_mpc.cli import app as cli
    from dualarm_mpc.cli import process

    monkeypatch.setattr(process, "HEARTBEAT_S", 0.0)  # every tick: the line a long search prints
    from dualarm_mpc.planning import task

    def slow_first_step(scenario, options, progress, tried, *args, **kwargs):  # a step longer
        return transport(scenario, options,  # than a 0.1 s tick
                         lambda seg: (time.sleep(0.5), progress(seg)), tried, *args, **kwargs)

    monkeypatch.setattr(task, "transport", slow_first_step)
    assert cli.main(["plan", "table1_vd", "--seed", "1", "--set", "random_objects.count: 4"]) == 0
    assert "still searching step 1:" in capsys.readouterr().out
