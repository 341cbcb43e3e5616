"""`make figures`: every image in README.md and docs/*.md, made anew from the code.

It runs the two commands of ``make demo`` (read from the Makefile, :func:`demo.demo_commands`)
into a temporary folder and writes

- ``docs/img/plan.png``: the plan command's ``plan.png``;
- ``docs/img/run.png``: the simulate command's ``run.png`` (the run's timeline);
- ``docs/img/replay.png``: the simulate command's ``replay.html`` opened in headless Chromium
  (Debian's ``chromium`` and ``chromium-driver``, driven by selenium: the ``test`` extra) at a
  1280×800 view, paused at :data:`REPLAY_T_S` seconds of simulated time (``replay.html?t=25``);
- ``docs/img/figures.json``: per image, the data it was made from: the SHA-256 of the plan JSON's
  deterministic part (:func:`plan_sha256`: without its wall and CPU times, which no figure's
  data depends on but plan.png's title prints), of the summary JSON (lockstep: the same bytes on
  any machine, :func:`summary_sha256`), and the replay's simulated time and view.

``tests/test_figures.py`` re-plans (and, marked slow, re-simulates) the demo and compares these
hashes, so a committed figure older than what the code makes fails the tests without comparing
pixels. Run it (from the repository root)::

    .venv/bin/python bench/figures.py          # or: make figures
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from demo import ROOT, demo_commands

IMG = ROOT / "docs" / "img"
SIDECAR = IMG / "figures.json"
REPLAY_T_S = 25.0
# Chromium's own traffic (updates, sync, QUIC probes) off, so any request is the page's; WebGL in
# software (no GPU here), opted in. tests/test_viewer.py opens its replays the same way.
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--enable-unsafe-swiftshader")
VIEW = {"width": 1280, "height": 800, "deviceScaleFactor": 1, "mobile": False}
HUD_JS = "return document.getElementById('hud').textContent"
# The plan JSON's wall and CPU times, and the search's work counted against them (a program a
# time slice cut short is solved again): the machine's, not the plan's.
TIMES = ("solve_time_s", "cpu_time_s", "total_solve_time_s", "total_cpu_time_s", "first_plan_s",
         "search_stats")


def _sha256(data) -> str:
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def plan_sha256(plan: dict) -> str:
    """The SHA-256 of the plan JSON ``plan`` (parsed) less its wall and CPU times (:data:`TIMES`),
    which differ run to run; the rest is the same on every run."""
    def strip(value):
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in TIMES}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value
    return _sha256(strip(plan))


def summary_sha256(summary: dict) -> str:
    """The SHA-256 of the summary JSON ``summary`` (parsed): lockstep, it is whole the same on
    every run (it has no ``wall_clock``)."""
    return _sha256(summary)


def start_chromium(profile: Path):
    """A headless Chromium (selenium's driver) at the 1280×800 :data:`VIEW`, with its profile in
    ``profile``; the caller quits it. Raises ``RuntimeError`` where Chromium, its driver or
    selenium is missing."""
    chromium, chromedriver = shutil.which("chromium"), shutil.which("chromedriver")
    if chromium is None or chromedriver is None:
        raise RuntimeError("Chromium is not installed: apt-get install chromium chromium-driver")
    try:
        from selenium import webdriver
    except ImportError as e:
        raise RuntimeError("selenium is not installed: pip install -e '.[test]'") from e
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={profile}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL", "performance": "ALL"})
    driver = webdriver.Chrome(options=options,
                              service=webdriver.ChromeService(executable_path=chromedriver))
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", VIEW)
    return driver


def screenshot(html: Path, t: float, png: Path, profile: Path) -> None:
    """``html`` (a replay) opened paused at ``t`` seconds of simulated time, its view to ``png``."""
    from selenium.webdriver.support.wait import WebDriverWait
    driver = start_chromium(profile)
    try:
        driver.get(f"{html.as_uri()}?t={t:g}")
        WebDriverWait(driver, 180).until(
            lambda d: d.execute_script(HUD_JS).startswith(f"t = {t:.1f} s"))
        # two animation frames drawn at that time before the picture is taken
        driver.execute_async_script("const done = arguments[0]; "
                                    "requestAnimationFrame(() => requestAnimationFrame(done));")
        png.write_bytes(driver.get_screenshot_as_png())
    finally:
        driver.quit()


def make(img: Path = IMG) -> dict:
    """Run ``make demo``'s commands into a temporary folder and write the figures and the sidecar
    into ``img``; returns the sidecar's data."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        commands = demo_commands(out)
        for command in commands:
            print("$", " ".join(command[1:]).replace(str(out), "out"), flush=True)
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
        plan = json.loads((out / "plan.json").read_text())
        summary = json.loads((out / "summary.json").read_text())
        img.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(out / "plan.png", img / "plan.png")
        shutil.copyfile(out / "run.png", img / "run.png")
        screenshot(out / "replay.html", REPLAY_T_S, img / "replay.png", out / "chromium")
    made_by = {"plan_sha256": plan_sha256(plan), "summary_sha256": summary_sha256(summary)}
    data = {
        "made_by": "make figures (bench/figures.py): make demo's commands, from the Makefile",
        "commands": [shlex.join(["dualarm-mpc", *c[1:]]).replace(str(out), "out")
                     for c in commands],
        "images": {
            "plan.png": {"from": "out/plan.png", "plan_sha256": made_by["plan_sha256"]},
            "run.png": {"from": "out/run.png", "summary_sha256": made_by["summary_sha256"]},
            "replay.png": {"from": f"out/replay.html?t={REPLAY_T_S:g} in headless Chromium",
                           "summary_sha256": made_by["summary_sha256"],
                           "replay_t_s": REPLAY_T_S, "view": [VIEW["width"], VIEW["height"]]},
        },
    }
    (img / "figures.json").write_text(json.dumps(data, indent=2) + "\n")
    return data


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--img", type=Path, default=IMG, help="where the images go (docs/img)")
    args = p.parse_args(argv)
    data = make(args.img)
    for name in data["images"]:
        print(f"wrote {args.img / name}")
    print(f"wrote {args.img / 'figures.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
