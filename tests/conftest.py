"""Fixtures shared by the tests: scenario files written from the shared scenes (scenes.py)."""

from __future__ import annotations

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

