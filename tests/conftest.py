"""Fixtures shared by the tests: scenario files written from the shared scenes (scenes.py),
`make demo`'s run made once a session; and under CI, no test skipped."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

import pytest
import yaml
from demo import demo_arguments
from scenes import TWO_OBJECTS

from dualarm_mpc.cli.app import main


@pytest.fixture
def scenario_file(tmp_path):
    """``write(data, **overrides)`` → the path of a scenario YAML file of ``data`` (a dict, or
    YAML text) with top-level ``overrides``."""
    def write(data: dict | str = TWO_OBJECTS, name: str = "scenario.yaml", **overrides):
        if isinstance(data, str):
            data = yaml.safe_load(data)
        path = tmp_path / name
        path.write_text(yaml.safe_dump({**data, **overrides}, sort_keys=False))
        return path

    return write


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory) -> Path:
    """The directory of `make demo`'s closed-loop run (its ``simulate`` command, read from the
    Makefile): replay.html, summary.json, run.png. Made once a session, by the first xdist
    worker to ask (about 35 s); the others wait for it: the run is lockstep, the same bytes
    wherever it is made."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the session's directory, above each worker's own
    out = root / "demo-run"
    with open(root / "demo-run.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (out / "made").exists():
            out.mkdir(exist_ok=True)
            assert main(demo_arguments(out, "simulate")) == 0
            (out / "made").touch()
    return out



# Under CI (CI=true, as .ci/run is run) every test must run: a skip there (Chromium, a solver or
# Dask missing) would leave a claim of the README untested while CI stays green, so it fails,
# with the skip's reason. Elsewhere a test whose tool is missing is skipped and says why.
IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")


def _fail_if_skipped(report) -> None:
    if IN_CI and report.skipped and not hasattr(report, "wasxfail"):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else report.longrepr
        report.outcome = "failed"
        report.longrepr = f"skipped under CI, where every test must run: {reason}"


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    _fail_if_skipped(report)
    return report


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector):
    report = yield
    _fail_if_skipped(report)
    return report
