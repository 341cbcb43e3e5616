"""The committed figures (docs/img, made by ``make figures``, bench/figures.py) are what the code
makes today: their sidecar docs/img/figures.json names the data each was made from, and these
tests make that data again and compare it, not the pixels.

When one fails, run ``make figures``, look at the images, re-read the text beside them in
README.md and docs/, and commit."""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import figures
import pytest
from demo import demo_arguments, demo_commands

from dualarm_mpc.cli.app import main

ROOT = Path(__file__).resolve().parents[1]
REGENERATE = "the code makes another figure than the committed one: run `make figures` and commit"


@pytest.fixture(scope="module")
def sidecar() -> dict:
    return json.loads(figures.SIDECAR.read_text())


def test_every_image_of_the_readme_and_docs_is_made_by_make_figures(sidecar) -> None:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    shown = {name for page in pages
             for name in re.findall(r"\]\((?:docs/)?img/([^)\s]+)\)", page.read_text())}
    assert shown, "no image found in README.md or docs/*.md"
    made = set(sidecar["images"])
    assert shown <= made, f"not made by make figures: {shown - made}"
    for name in sidecar["images"]:
        assert (figures.IMG / name).is_file(), name
    # made by the commands `make demo` runs today
    commands = [shlex.join(["dualarm-mpc", *c[1:]]) for c in demo_commands(Path("out"))]
    assert sidecar["commands"] == commands, REGENERATE


def test_plan_png_is_made_from_the_plan_the_code_makes(sidecar, tmp_path) -> None:
    """The demo's plan made again (in process, about 6 s): its JSON less the wall and CPU times
    is what docs/img/plan.png was drawn from."""
    assert main(demo_arguments(tmp_path, "plan")) == 0
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert figures.plan_sha256(plan) == sidecar["images"]["plan.png"]["plan_sha256"], REGENERATE


@pytest.mark.slow  # the demo's closed-loop run, lockstep (about 40 s on 2 cores)
def test_the_run_figures_are_made_from_the_run_the_code_makes(sidecar, demo_run) -> None:
    """The demo's run made again: its summary JSON (lockstep: the same bytes on any machine) is
    what docs/img/run.png was drawn from and docs/img/replay.png's replay recorded."""
    summary = json.loads((demo_run / "summary.json").read_text())
    assert "wall_clock" not in summary  # lockstep: nothing of the machine in it
    for name in ("run.png", "replay.png"):
        assert figures.summary_sha256(summary) == sidecar["images"][name]["summary_sha256"], \
            f"{name}: {REGENERATE}"
    assert sidecar["images"]["replay.png"]["replay_t_s"] == figures.REPLAY_T_S
