"""Plot a closed-loop run from its summary (the summary JSON's fields, docs/formats.md): which
object each hand held over time, the replans by status, the deliveries, the environment's events
and the arms' clearance."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display on CI or a headless robot PC
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from dualarm_mpc.base.palette import ARM_COLOURS, goal_colour  # noqa: E402
from dualarm_mpc.figures.output import write_figure  # noqa: E402

ARM_LABELS = ("arm 1 (right)", "arm 2 (left)")
# A replan's mark by its status: a new plan (greens), the plan in force kept (greys), waiting
# for a search (oranges), the task over (black), a failure (reds).
STATUS_COLOURS = {
    "optimal": "#2ca02c",
    "feasible": "#98c379",
    "kept": "#9e9e9e",
    "over_budget": "#8c564b",
    "searching": "#ff7f0e",
    "done": "#000000",
    "stuck": "#d62728",
    "infeasible": "#d62728",
    "time_limit": "#e377c2",
    "no_horizon": "#bcbd22",
    "unbounded": "#7f7f7f",
    "error": "#9467bd",
}
EVENT_STYLES = {"move_object": ("#d62728", "--"), "move_goal": ("#9467bd", "-.")}
# The rows of the upper panel, top down.
ROWS = {"arm 1 (right)": 4, "arm 2 (left)": 3, "delivered": 2, "replans": 1}


def plot_timeline(summary: dict, path: str | Path, title: str = "") -> None:
    """Write :func:`timeline_figure` in the format the suffix of ``path`` names (PNG, PDF,
    SVG, ...), whole or not at all."""
    write_figure(timeline_figure(summary, title), path)


def timeline_figure(summary: dict, title: str = "") -> Figure:
    """A closed-loop run over simulated time, from ``summary`` (``Summary.to_json()``, or the
    summary JSON read back). Above, one row per arm: a bar while it holds an object, in the
    colour of the object's goal, with the object's number (``holds``); a row with each object's
    delivery (``delivered_time_s``); a row with a mark per replan, coloured by its status, filled
    where it put a new plan in force (``replans``), and the sequential step each step's first
    replan starts. Every event (``events``: an object knocked, a goal moved) is a vertical line
    through both panels. Below, the least distance between the arms since the replan before,
    at each replan (``clearance``), where the summary has it. Every mark is in a legend."""
    end = float(summary.get("sim_time_s") or 0.0)
    objects = summary.get("objects", [])
    number = {o["name"]: k + 1 for k, o in enumerate(objects)}
    goal = {o["name"]: o["goal"] for o in objects}
    clearance = summary.get("clearance") or []
    heights = [3.2, 1.6] if clearance else [3.2]
    fig = plt.figure(figsize=(12, sum(heights) + 0.8))
    grid = fig.add_gridspec(len(heights), 1, height_ratios=heights, hspace=0.08)
    ax = fig.add_subplot(grid[0])
    legend: list = []

    for hold in summary.get("holds", []):  # which object each hand holds
        y = ROWS[ARM_LABELS[hold["arm"] - 1]]
        width = max(hold["to"] - hold["from"], 1e-3)
        ax.broken_barh([(hold["from"], width)], (y - 0.35, 0.7),
                       color=goal_colour(goal.get(hold["object"], "")), alpha=0.85)
        ax.text(hold["from"] + width / 2, y, str(number.get(hold["object"], hold["object"])),
                ha="center", va="center", fontsize=7, color="white", fontweight="bold")
    legend.append(Patch(color="0.6", label="holds object n, in its goal's colour"))

    y = ROWS["delivered"]  # deliveries; those at one time (to 10 ms) stacked, numbered together
    at: dict[float, list[str]] = {}
    for name, when in zip((o["name"] for o in objects), summary.get("delivered_time_s", []),
                          strict=False):
        if when is not None:
            at.setdefault(round(when, 2), []).append(name)
    for when, names in at.items():
        for k, name in enumerate(names):
            ax.plot(when, y + 0.22 * ((len(names) - 1) / 2 - k), "v", ms=7, mec="0.2", mew=0.5,
                    color=goal_colour(goal[name]))
        ax.annotate(",".join(str(number[n]) for n in names), (when, y + 0.11 * len(names)),
                    xytext=(0, 5), textcoords="offset points", ha="center", fontsize=7)
    legend.append(Line2D([], [], ls="", marker="v", color="0.6", mec="0.2", mew=0.5, ms=8,
                         label="object n delivered (at rest in its goal)"))

    y = ROWS["replans"]  # replans, by status; the steps
    seen: dict[str, None] = {}
    step, objects_before = 0, None
    for r in summary.get("replans", []):
        colour = STATUS_COLOURS.get(r["status"], "0.5")
        seen.setdefault(r["status"])
        ax.plot(r["t"], y, "o", ms=6, color=colour, mfc=colour if r.get("adopted") else "white")
        if r.get("objects") and r["objects"] != objects_before:
            step, objects_before = step + 1, r["objects"]
            ax.annotate(f"step {step}", (r["t"], y), xytext=(0, -14), textcoords="offset points",
                        ha="left", fontsize=7, color="0.3")
    legend += [Line2D([], [], ls="", marker="o", ms=6, color=STATUS_COLOURS.get(s, "0.5"),
                      label=f"replan: {s.replace('_', ' ')}") for s in seen]
    if seen:
        legend.append(Line2D([], [], ls="", marker="o", ms=6, color="0.4", mfc="white",
                             label="hollow: no new plan adopted"))

    axes = [ax]
    if clearance:
        cl = fig.add_subplot(grid[1], sharex=ax)
        axes.append(cl)
        t, m = zip(*clearance, strict=True)
        cl.plot(t, [v * 100 for v in m], ".-", color="0.3", lw=1, ms=4)
        cl.set_ylabel("arm clearance\n[cm]")
        cl.set_ylim(bottom=min(0.0, min(m) * 100))
        least = summary.get("min_arm_clearance_m")
        if least is not None:
            cl.axhline(least * 100, color="0.6", lw=0.8, ls=":")
        legend.append(Line2D([], [], color="0.3", marker=".", lw=1, ms=4,
                             label="arms' least distance since the last replan"))
        if least is not None:
            legend.append(Line2D([], [], color="0.6", lw=0.8, ls=":",
                                 label=f"least over the run, {least * 100:.1f} cm"))
        cl.set_xlabel("simulated time [s]")
        cl.grid(axis="y", color="0.9")
    else:
        ax.set_xlabel("simulated time [s]")

    for e in summary.get("events", []):  # the environment's changes, through every panel
        colour, ls = EVENT_STYLES.get(e.get("kind"), ("0.3", ":"))
        for a in axes:
            a.axvline(e["time"], color=colour, ls=ls, lw=1)
        what = (f"object {number.get(e['target'], e['target'])} knocked"
                if e.get("kind") == "move_object" else f"goal {e['target']} moved")
        ax.annotate(what, (e["time"], 4.55), xytext=(3, 0), textcoords="offset points",
                    fontsize=7, color=colour, va="bottom")
    for kind, what in (("move_object", "an object knocked away"), ("move_goal", "a goal moved")):
        if any(e.get("kind") == kind for e in summary.get("events", [])):
            colour, ls = EVENT_STYLES[kind]
            legend.append(Line2D([], [], color=colour, ls=ls, lw=1, label=what))

    ax.set_yticks(list(ROWS.values()), list(ROWS))
    for label, c in zip(ax.get_yticklabels(), [*ARM_COLOURS, "0.2", "0.2"], strict=True):
        label.set_color(c)
    ax.set_ylim(0.4, 5.0)
    ax.set_xlim(0, max(end, 1.0))
    ax.grid(axis="x", color="0.92")
    if clearance:
        ax.tick_params(labelbottom=False)
    delivered = sum(d is not None for d in summary.get("delivered_time_s", []))
    ax.set_title(title or f"closed loop, {summary.get('mode', '')}: {delivered}/{len(objects)} "
                 f"objects delivered, t = {end:.1f} s"
                 + (" (interrupted)" if summary.get("interrupted") else ""))
    ax.legend(handles=legend, loc="upper left", bbox_to_anchor=(1.01, 1), fontsize=8,
              frameon=False)
    fig.subplots_adjust(left=0.1, right=0.68, top=0.93, bottom=0.1)
    return fig
