"""Plot a plan: hand and object paths over the goal boxes, and a grasp timeline per arm."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display on CI or a headless robot PC
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from dualarm_mpc.plan import Plan  # noqa: E402

GOAL_COLOURS = {"red": "tab:red", "green": "tab:green", "blue": "tab:blue"}
ARM_NAMES = ("arm 1 (right)", "arm 2 (left)")


def colour(goal: str) -> str:
    return GOAL_COLOURS.get(goal, "tab:gray")


def plot_plan(plan: Plan, path: str | Path, title: str = "") -> None:
    """Write a PNG: the table top (paths, goals, hand range) above the grasp timelines."""
    t = plan.trajectory
    fig = plt.figure(figsize=(9, 10))
    grid = fig.add_gridspec(2, 1, height_ratios=[3, 1])
    ax = fig.add_subplot(grid[0])
    xmin, xmax, ymin, ymax = plan.workspace
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, ls="--",
                           ec="0.5", label="hand range"))
    for name, (gx0, gx1, gy0, gy1) in plan.goals.items():
        ax.add_patch(Rectangle((gx0, gy0), gx1 - gx0, gy1 - gy0, color=colour(name), alpha=0.2))
        ax.text((gx0 + gx1) / 2, gy1 + 0.01, name, ha="center", va="bottom", fontsize=8)
    for i, style in enumerate(("-", "--")):
        ax.plot(t.hand_pos[:, i, 0], t.hand_pos[:, i, 1], style, color="k", lw=1, alpha=0.6,
                label=ARM_NAMES[i])
    for j, o in enumerate(plan.objects):
        p = t.object_pos[:, j]
        c = colour(o["goal"])
        ax.plot(p[:, 0], p[:, 1], "-", color=c, lw=1.5)
        ax.plot(*p[0], "s", color=c, mfc="none")
        ax.plot(*p[-1], "s", color=c)
        ax.annotate(str(j + 1), p[0], fontsize=7, xytext=(3, -8), textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title or f"rule {plan.rule}, cost {plan.total_cost:.3f}, "
                 f"solve {plan.total_solve_time_s:.1f} s")
    tl = fig.add_subplot(grid[1])
    k = np.arange(len(t.grasp))
    for i in range(2):
        for j, o in enumerate(plan.objects):
            on = t.grasp[:, i, j].astype(bool)
            if on.any():
                tl.broken_barh(_runs(k[on]), (1 - i - 0.4, 0.8), color=colour(o["goal"]))
                first = k[on][0]
                tl.text(first + 0.1, 1 - i, str(j + 1), va="center", fontsize=7)
    start = 0
    for seg in plan.segments:
        start += seg.horizon
        tl.axvline(start, color="0.7", lw=0.8)
    tl.set_yticks([1, 0], ARM_NAMES)
    tl.set_xlabel("step k (grey lines: ends of sequential steps)")
    tl.set_xlim(0, max(len(k) - 1, 1))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _runs(steps: np.ndarray) -> list[tuple[int, int]]:
    """Consecutive steps as (start, length) bars."""
    runs = []
    for s in steps:
        if runs and runs[-1][0] + runs[-1][1] == s:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((int(s), 1))
    return runs
