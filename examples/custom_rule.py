"""A rule of your own: the left arm never touches the red objects.

Loads §V-D (here six random objects), adds the rule as LTL text, checks that the rules and the task
still admit a plan, plans (sequential transportation), verifies the plan against every step's
specification by re-simulation, and plots it.

    python examples/custom_rule.py [OUT.png]
"""

from __future__ import annotations

import sys

from dualarm_mpc.figures.plan import plot_plan
from dualarm_mpc.model.scenario import load_scenario
from dualarm_mpc.model.verify import verify
from dualarm_mpc.planning.consistency import check
from dualarm_mpc.planning.sequential import transport


def main(out: str = "custom_rule.png") -> None:
    task = {"seed": 3, "rule": 2, "random_objects": {"count": 6}}
    scenario = load_scenario("table1_vd", task)
    red = [j + 1 for j, o in enumerate(scenario.task.objects) if o.goal == "red"]
    # eta[2,j]: arm 2 (the left one) holds object j; one rule per red object.
    rules = [f"G !eta[2,{j}]" for j in red]
    scenario = load_scenario("table1_vd", {**task, "rules": rules})
    print(f"the left arm keeps off objects {red}: {rules}")

    report = check(scenario)
    if not report.consistent:
        sys.exit("\n".join(str(c) for c in report.conflicts))
    result = transport(scenario)
    verdict = verify(scenario, result)
    assert verdict.ok, verdict.problems
    for n, seg in enumerate(result.segments, 1):
        names = [scenario.task.objects[j].name for j in seg.delivered]
        print(f"step {n}: T = {seg.horizon:2d}, cost {seg.cost:.3f}, delivered {names}")
    held_by_left = {j + 1 for j in range(scenario.n_objects)
                    if result.trajectory.grasp[:, 1, j].any()}
    print(f"objects the left arm held: {sorted(held_by_left)} (none of {red})")
    plot_plan(result, out, title="left arm keeps off the red objects")
    print(f"verified; wrote {out}")


if __name__ == "__main__":
    main(*sys.argv[1:])
