"""Benchmark sweeps as Dask tasks (bench/benchlib.py ``run_tasks``, bench/table2.py): a local
cluster (``--workers``) and an existing one (``--scheduler``) give the serial run's records —
the same plans, seeds, statuses and costs — apart from the timing columns, which say that the
runs shared the machine."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import benchlib
import pytest
import table2

pytestmark = pytest.mark.slow  # starts Dask clusters

distributed = pytest.importorskip("distributed", reason="dask is not installed "
                                  "(pip install '.[dask]')")

# exact: the witness policy's budget per step is wall time, so under load a step can end
# "feasible" on one run and "optimal" on the other; the sweep, not the policy, is tested here.
GRID = ["--rows", "1,1", "--rules", "2", "--seeds", "0,1", "--time-limit", "20",
        "--horizons", "exact"]
# What only the machine decides: times, load, where a run ran and with how many threads, the
# search's work counts (two workers share it as they come).
TIMING = {"solve_time_s", "cpu_time_s", "wall_time_s", "load_avg_1min", "host", "runs_per_host",
          "shared_machine", "first_plan_s", "search_stats"}


def runs(path: Path) -> list[dict]:
    return json.loads(path.read_text())["runs"]


def without_timing(records: list[dict]) -> list[dict]:
    return [{**{k: v for k, v in r.items() if k not in TIMING},
             "steps": [{k: v for k, v in s.items() if k not in TIMING} for s in r["steps"]]}
            for r in records]


@pytest.fixture(scope="module")
def serial(tmp_path_factory) -> list[dict]:
    path = tmp_path_factory.mktemp("serial") / "table2.json"
    assert table2.main([*GRID, "--json", str(path)]) == 0
    return runs(path)


def test_a_local_cluster_gives_the_serial_results(serial, tmp_path, capsys) -> None:
    path = tmp_path / "table2.json"
    assert table2.main([*GRID, "--workers", "2", "--json", str(path)]) == 0
    parallel = runs(path)
    assert without_timing(parallel) == without_timing(serial)
    assert all(r["status"] == "ok" for r in parallel)
    assert [r["runs_per_host"] for r in serial] == [1, 1]
    assert [r["runs_per_host"] for r in parallel] == [2, 2]
    out, err = capsys.readouterr()
    assert "2 runs per machine at once" in out and "shared" in out
    assert "] 2/2 runs" in err  # the progress bar


def test_an_existing_cluster_gives_the_serial_results(serial, tmp_path) -> None:
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        path = tmp_path / "table2.json"
        assert table2.main([*GRID, "--seeds", "1-1", "--scheduler", cluster.scheduler_address,
                            "--json", str(path)]) == 0
    remote = runs(path)
    assert without_timing(remote) == without_timing(serial[1:])
    assert [r["runs_per_host"] for r in remote] == [1]


def test_the_serial_table_says_the_runs_had_the_machine(serial, tmp_path) -> None:
    text = table2.report(serial, table2.parse_args(GRID))
    assert "one run at a time (the machine to itself)" in text and "| alone |" in text


def test_workers_and_scheduler_exclude_each_other(capsys) -> None:
    with pytest.raises(SystemExit):
        table2.parse_args([*GRID, "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"])
    assert "give one" in capsys.readouterr().err


@pytest.mark.parametrize("factor", ["0.5", "-2", "inf", "nan"])
def test_a_slowdown_is_a_finite_factor_of_at_least_one(factor: str, capsys) -> None:
    with pytest.raises(SystemExit):
        table2.parse_args([*GRID, "--slowdown", factor])
    assert "--slowdown must be a finite factor >= 1" in capsys.readouterr().err


def test_a_slowed_table_says_so(serial) -> None:
    text = table2.report(serial, table2.parse_args([*GRID, "--slowdown", "1.5"]))
    assert "slowed down 1.5×" in text


def test_run_tasks_yields_every_record_once_with_its_index() -> None:
    tasks = [{"n": n} for n in range(5)]
    got = dict(benchlib.run_tasks(lambda t: {"square": t["n"] ** 2}, tasks))
    assert {i: r["square"] for i, r in got.items()} == {n: n * n for n in range(5)}


def test_robustness_takes_the_solver_and_the_cluster_flags() -> None:
    import robustness

    args = robustness.parse_args(["--seeds", "1", "--solver", "scip", "--workers", "2"])
    assert (args.solver, args.workers, args.scheduler) == ("scip", 2, None)
    task = {"time_limit": None, "shared_machine": True, "set": [], "solver": "scip"}
    scenario = robustness.scenario_for(1, 0, task)
    assert scenario.solver.backend == "scip" and scenario.solver.workers == 1
