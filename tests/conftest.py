"""Fixtures shared by the tests: scenario files written from the shared scenes (scenes.py); and
under CI, no test skipped."""

from __future__ import annotations

import os

import pytest
import yaml
from scenes import TWO_OBJECTS


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
