"""The examples in ``examples/`` run as a user would run them, and do what they say."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def run(script: str, *args: str, cwd: Path | None = None) -> str:
    done = subprocess.run([sys.executable, str(EXAMPLES / script), *args], capture_output=True,
                          text=True, timeout=600, cwd=cwd)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.slow
def test_custom_rule_plans_verifies_and_plots(tmp_path) -> None:
    out = run("custom_rule.py", str(tmp_path / "plan.png"))
    assert "verified" in out and "(none of [1, 4])" in out
    assert (tmp_path / "plan.png").stat().st_size > 0


@pytest.mark.slow
def test_disturbance_knocks_moves_a_goal_and_still_delivers(tmp_path) -> None:
    out = run("disturbance.py", cwd=tmp_path)
    assert "object1 knocked" in out and "the red goal moved" in out
    assert "object1 in its goal, object2 in its goal" in out
    replay = (tmp_path / "out" / "disturbance.html").read_text()
    assert replay.rstrip().endswith("</html>") and "animation" in replay
    # its timeline (issue 51): a picture of the disturbance at a glance
    timeline = tmp_path / "out" / "disturbance.png"
    assert timeline.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "wrote out/disturbance.png" in out
