"""`make demo` measured: what its run of §V-C produces, for the README's figures.

What it measures: the two commands of ``make demo`` (the Makefile's ``demo`` target: plan
``table1_vc`` under rule 2 on the robot's goal slots, then simulate it closed loop, lockstep),
run here as subprocesses of the installed ``dualarm-mpc``, into a temporary folder. From their
outputs: the plan's cost, steps and verification; the run's simulated length (``sim_time_s``),
objects at rest in their goals, replans, the arms' least clearance, the hands' deepest
penetration into a box, the objects' contacts (where the summary has them); the replay's size;
and the wall time of each command (the only figures that depend on the machine). Lockstep makes
every other figure the same on any machine.

Run it (from the repository root)::

    .venv/bin/python bench/demo.py                       # writes bench/results/demo.json

The JSON holds the figures, the commands and the machine; ``bench/report.py`` renders it.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchlib import fmt, machine, table, write_json_atomic

ROOT = Path(__file__).resolve().parent.parent
DUALARM = Path(sys.executable).parent / "dualarm-mpc"


def demo_commands(out: Path) -> list[list[str]]:
    """The ``demo`` target's commands, read from the Makefile so the two cannot drift apart."""
    lines = (ROOT / "Makefile").read_text().split("\ndemo:", 1)[1].split("\n\n", 1)[0]
    recipe = " ".join(line.strip().rstrip("\\") for line in lines.splitlines()[1:])
    commands = []
    for text in recipe.split("$(BIN)/dualarm-mpc")[1:]:
        text = text.replace("$(OUT)", str(out))
        commands.append([str(DUALARM), *shlex.split(text)])
    return commands


def demo_arguments(out: Path, name: str) -> list[str]:
    """The arguments of ``dualarm-mpc`` in the ``demo`` target's ``name`` command (``plan``,
    ``simulate``), writing into ``out``."""
    (args,) = [c[1:] for c in demo_commands(out) if c[1] == name]
    return args


def measure() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        walls = []
        commands = demo_commands(out)
        for command in commands:
            t0 = time.perf_counter()
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
            walls.append(round(time.perf_counter() - t0, 1))
        plan = json.loads((out / "plan.json").read_text())
        summary = json.loads((out / "summary.json").read_text())
        replay_bytes = (out / "replay.html").stat().st_size
    delivered = sum(1 for t in summary["delivered_time_s"] if t is not None)
    return {
        "commands": [shlex.join(["dualarm-mpc", *c[1:]]).replace(str(out), "out")
                     for c in commands],
        "plan": {"total_cost": plan["total_cost"], "steps": len(plan["segments"]),
                 "verified": plan["verified"]},
        "run": {"sim_time_s": summary["sim_time_s"], "objects": len(summary["objects"]),
                "delivered": delivered, "all_delivered": summary["all_delivered"],
                "replans": len(summary["replans"]),
                "min_arm_clearance_m": summary["min_arm_clearance_m"],
                "max_hand_penetration_m": summary["max_hand_penetration_m"],
                "object_contacts": summary.get("object_contacts")},
        "replay_bytes": replay_bytes,
        "wall_time_s": {"plan": walls[0], "simulate": walls[1]},
    }


def report(data: dict) -> str:
    run, plan = data["run"], data["plan"]
    contacts = run["object_contacts"]
    rows = [
        ["plan", f"{plan['steps']} steps, cost {plan['total_cost']:.3f}, "
                 f"{'verified' if plan['verified'] else 'NOT verified'}"],
        ["simulated run", f"{run['sim_time_s']:.1f} s, {run['replans']} replans"],
        ["objects at rest in their goals", f"{run['delivered']}/{run['objects']}"],
        ["arms' least clearance", f"{100 * run['min_arm_clearance_m']:.1f} cm"],
        ["deepest hand into a box", f"{1000 * run['max_hand_penetration_m']:.1f} mm"],
        *([["objects that touched while one moved", str(len(contacts))]]
          if contacts is not None else []),
        ["replay.html", f"{data['replay_bytes'] / 1e6:.1f} MB"],
        ["wall time (this machine)", f"plan {fmt(data['wall_time_s']['plan'], '.0f')} s, "
                                     f"simulate {fmt(data['wall_time_s']['simulate'], '.0f')} s"],
    ]
    return table(["`make demo`", "measured"], rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--json", type=Path, default=ROOT / "bench" / "results" / "demo.json")
    args = p.parse_args(argv)
    info = machine()
    data = {**measure(), "options": {}, "machine": info}
    write_json_atomic(args.json, data)
    print(report(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
