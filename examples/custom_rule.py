"""A rule of your own: the left arm never touches the red objects.

Loads §V-D (here six random objects), adds the rule as LTL text, checks that the rules and the task
still admit a plan, plans (sequential transportation), verifies the plan against every step's
specification by re-simulation, and plots it.

    python examples/custom_rule.py [OUT.png]   (default out/custom_rule.png)
"""

from __future__ import annotations

import sys
from pathlib import Path

import dualarm_mpc as dm


def main(out: str = "out/custom_rule.png") -> None:
    task = {"seed": 3, "rule": 2, "random_objects": {"count": 6}}
    scenario = dm.load_scenario("table1_vd", task)
    red = [j + 1 for j, o in enumerate(scenario.task.objects) if o.goal == "red"]
    # eta[2,j]: arm 2 (the left one) holds object j; one rule per red object.
    rules = [f"G !eta[2,{j}]" for j in red]
    scenario = dm.load_scenario("table1_vd", {**task, "rules": rules})
    print(f"the left arm keeps off objects {red}: {rules}")

    report = dm.check(scenario)
    if not report.consistent:
        sys.exit("\n".join(str(c) for c in report.conflicts))
    plan = dm.plan(scenario)  # verified: re-simulated, every step's specification checked
    for n, seg in enumerate(plan.segments, 1):
        names = [scenario.task.objects[j].name for j in seg.delivered]
        print(f"step {n}: T = {seg.horizon:2d}, cost {seg.cost:.3f}, delivered {names}")
    held_by_left = {j + 1 for j in range(scenario.n_objects)
                    if plan.trajectory.grasp[:, 1, j].any()}
    print(f"objects the left arm held: {sorted(held_by_left)} (none of {red})")
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    dm.plot_plan(plan, out, title="left arm keeps off the red objects")
    print(f"verified; wrote {out}")


if __name__ == "__main__":
    main(*sys.argv[1:])
