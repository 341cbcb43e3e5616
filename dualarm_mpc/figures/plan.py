"""Plot a plan: where every object goes, the hands' paths step by step, a grasp timeline."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display on CI or a headless robot PC
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch, Rectangle  # noqa: E402

from dualarm_mpc.base.palette import ARM_COLOURS, goal_colour  # noqa: E402
from dualarm_mpc.figures.output import write_figure  # noqa: E402
from dualarm_mpc.model.plan import Plan  # noqa: E402

ARM_LABELS = ("arm 1 (right)", "arm 2 (left)")
STEPS_PER_ROW = 5
THROW_SPEED = 1e-3  # m/s: an object let go faster than this is thrown (it slides on)


def plot_plan(plan: Plan, path: str | Path, title: str = "") -> None:
    """Write :func:`plan_figure` in the format the suffix of ``path`` names (PNG, PDF, SVG, ...),
    whole or not at all."""
    write_figure(plan_figure(plan, title), path)


def plan_figure(plan: Plan, title: str = "") -> Figure:
    """Three parts, every mark in a legend. Above, the whole plan on the table top: each
    object's path from start to planned end (objects that end on one point share its label).
    In the middle, one panel per sequential step: the hands' paths and the objects moved in it
    (drawn together, the hands' paths of the whole plan are a tangle). Above and in the panels,
    where a hand lets go of an object: puts it down (×) or throws it (★: lets go at speed, and
    the object slides on to its end). Below, which object each hand holds over time, and where
    each step ends: a hand that still holds an object its step delivered (at rest in its goal;
    it lets go in the next step's first Δt) has the bar go on hatched past the step's end."""
    t = plan.trajectory
    ends = np.cumsum([0] + [seg.horizon for seg in plan.segments])
    rows = -(-len(plan.segments) // STEPS_PER_ROW)  # none: nothing to do, no step panels
    # The step panels show where anything moves, goals included, on one scale.
    boxes = np.array(list(plan.goals.values()))
    points = np.concatenate([t.hand_pos.reshape(-1, 2), t.object_pos.reshape(-1, 2),
                             boxes[:, [0, 2]], boxes[:, [1, 3]]])
    lo, hi = points.min(axis=0) - 0.05, points.max(axis=0) + 0.05
    row_height = 10 / STEPS_PER_ROW * (hi - lo)[1] / (hi - lo)[0] + 0.4
    heights = [6.5, *([row_height * rows] if rows else []), 2]
    fig = plt.figure(figsize=(12, sum(heights)))
    grid = fig.add_gridspec(len(heights), 1, height_ratios=heights)
    ax = fig.add_subplot(grid[0])
    _table(ax, plan)
    releases = _releases(plan)
    _mark_releases(ax, releases)
    for j, o in enumerate(plan.objects):
        _object_path(ax, t.object_pos[:, j], goal_colour(o["goal"]))
        ax.annotate(str(j + 1), t.object_pos[0, j], fontsize=7, xytext=(4, -9),
                    textcoords="offset points")
    at_end = defaultdict(list)  # planned end (to 1 mm) → the objects that end there
    for j, p in enumerate(t.object_pos[-1]):
        at_end[tuple(np.round(p, 3))].append(str(j + 1))
    for end, names in at_end.items():
        ax.annotate(",".join(names), end, fontsize=7, xytext=(4, 3), textcoords="offset points")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"rule {plan.rule}, cost {plan.total_cost:.3f}, "
                 f"solve {plan.total_solve_time_s:.1f} s")
    ax.legend(handles=[
        Line2D([], [], ls="--", color="0.5", label="hand range"),
        Patch(color="0.6", alpha=0.3, label="goal box"),
        Line2D([], [], color="0.4", lw=1.5, label="object path, in its goal's colour"),
        Line2D([], [], ls="", marker="s", color="0.4", mfc="white", ms=7,
               label="object start, with its number"),
        Line2D([], [], ls="", marker="s", color="0.4", ms=7, label="object end (planned)"),
        *([Line2D([], [], ls="", marker="x", color="0.2", ms=7, mew=1.5,
                  label="a hand puts the object down")]
          if any(not thrown for *_, thrown in releases) else []),
        *([Line2D([], [], ls="", marker="*", color="0.2", ms=10,
                  label="a hand throws it (lets go at speed; it slides on)")]
          if any(thrown for *_, thrown in releases) else []),
        *(Line2D([], [], color=c, marker=".", lw=1, ms=5,
                 label=f"{name} hand (below), a dot per {plan.dt:g} s")
          for name, c in zip(ARM_LABELS, ARM_COLOURS, strict=True)),
    ], loc="upper left", bbox_to_anchor=(1.02, 1), fontsize=8, frameon=False)
    panels = grid[1].subgridspec(rows, STEPS_PER_ROW) if rows else None
    for s, seg in enumerate(plan.segments):
        p = fig.add_subplot(panels[s // STEPS_PER_ROW, s % STEPS_PER_ROW])
        _table(p, plan, names=False)
        p.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]))
        p.tick_params(labelsize=6, length=2)
        p.locator_params(nbins=4)
        if s % STEPS_PER_ROW == 0:  # the left column names y, the bottom row x
            p.set_ylabel("y [m]", fontsize=7, labelpad=1)
        if s + STEPS_PER_ROW >= len(plan.segments):
            p.set_xlabel("x [m]", fontsize=7, labelpad=1)
        _mark_releases(p, [r for r in releases if ends[s] < r[0] <= ends[s + 1]])
        k = slice(ends[s], ends[s + 1] + 1)
        for j in np.flatnonzero(np.ptp(t.object_pos[k], axis=0).max(axis=1) > 1e-6):
            _object_path(p, t.object_pos[k, j], goal_colour(plan.objects[j]["goal"]))
        for i in range(2):
            p.plot(*t.hand_pos[k, i].T, ".-", color=ARM_COLOURS[i], lw=1, ms=4)
        delivered = ",".join(str(j + 1) for j in seg.delivered) or "none"
        p.set_title(f"step {s + 1}, {ends[s] * plan.dt:g}–{ends[s + 1] * plan.dt:g} s\n"
                    f"delivers {delivered}", fontsize=8)
    tl = fig.add_subplot(grid[-1])
    k = np.arange(len(t.grasp))
    hatched = False
    for i in range(2):
        for j, o in enumerate(plan.objects):
            on = t.grasp[:, i, j].astype(bool)
            if not on.any():
                continue
            # held over [k, k + 1) Δt for each k with η = 1; from the end of the step that
            # delivered it (at rest in its goal) hatched: the hand lets go in the next step
            done = len(k) if plan.delivered_step[j] is None else plan.delivered_step[j]
            colour = goal_colour(o["goal"])
            tl.broken_barh(_bars(k[on & (k < done)], plan.dt), (1 - i - 0.4, 0.8), color=colour)
            after = _bars(k[on & (k >= done)], plan.dt)
            if after:
                hatched = True
                tl.broken_barh(after, (1 - i - 0.4, 0.8), facecolor="white", edgecolor=colour,
                               hatch="////", lw=0.5)
            tl.text((k[on][0] + 0.1) * plan.dt, 1 - i, str(j + 1), va="center", fontsize=7)
    for end in ends[1:]:
        tl.axvline(end * plan.dt, color="0.5", lw=0.8, ls="--")
    tl.legend(handles=[Patch(color="0.6", label="holds object n, in its goal's colour"),
                       *([Patch(facecolor="white", edgecolor="0.5", hatch="////",
                                label="holds it delivered: lets go in the next step")]
                         if hatched else []),
                       Line2D([], [], color="0.5", lw=0.8, ls="--",
                              label="end of a sequential step")],
              loc="upper left", bbox_to_anchor=(1.01, 1), fontsize=8, frameon=False)
    tl.set_yticks([1, 0], ARM_LABELS)
    tl.set_xlabel("time [s]")
    tl.set_xlim(0, max(len(k) - 1, 1) * plan.dt)
    fig.tight_layout()
    return fig


def _table(ax: Axes, plan: Plan, names: bool = True) -> None:
    """Hand range and goal boxes, metres, equal axes."""
    xmin, xmax, ymin, ymax = plan.workspace
    ax.add_patch(Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, ls="--",
                           ec="0.5"))
    for name, (gx0, gx1, gy0, gy1) in plan.goals.items():
        ax.add_patch(Rectangle((gx0, gy0), gx1 - gx0, gy1 - gy0, color=goal_colour(name),
                               alpha=0.2))
        if names:
            ax.text((gx0 + gx1) / 2, gy1 + 0.01, name, ha="center", va="bottom", fontsize=8)
    ax.set_aspect("equal")


def _releases(plan: Plan) -> list[tuple[int, int, np.ndarray, bool]]:
    """Where a hand lets go of an object: (k, hand, where, thrown) for each η that is 1 at
    step k - 1 and 0 at k; the object leaves the hand at its position at k, thrown if it is
    faster than ``THROW_SPEED`` there. An object let go after the step that delivered it (at
    rest in its goal: in the next step's first Δt) counts at that step's end, so that its mark
    is in that step's panel."""
    t = plan.trajectory
    g = t.grasp.astype(bool)
    out = []
    for k, i, j in zip(*np.nonzero(g[:-1] & ~g[1:]), strict=True):
        speed = float(np.linalg.norm(t.object_vel[k + 1, j]))
        done = plan.delivered_step[j]
        at = int(k) + 1 if done is None else min(int(k) + 1, done)
        out.append((at, int(i), t.object_pos[k + 1, j], speed > THROW_SPEED))
    return out


def _mark_releases(ax: Axes, releases: list[tuple[int, int, np.ndarray, bool]]) -> None:
    """× where a hand puts an object down, ★ where it throws one, in the hand's colour."""
    for _, i, where, thrown in releases:
        if thrown:
            ax.plot(*where, "*", color=ARM_COLOURS[i], ms=11, mec="0.15", mew=0.5, zorder=5)
        else:
            ax.plot(*where, "x", color=ARM_COLOURS[i], ms=7, mew=1.5, zorder=5)


def _bars(steps: np.ndarray, dt: float) -> list[tuple[float, float]]:
    """Steps k as bars over [k, k + 1) Δt, consecutive ones joined: (start, width) in s."""
    return [(s * dt, n * dt) for s, n in _runs(steps)]


def _object_path(ax: Axes, p: np.ndarray, c: str) -> None:
    """An object's path (K × 2): hollow square at its start, filled at its end."""
    ax.plot(p[:, 0], p[:, 1], "-", color=c, lw=1.5)
    ax.plot(*p[0], "s", color=c, mfc="white", ms=7)
    ax.plot(*p[-1], "s", color=c, ms=7)


def _runs(steps: np.ndarray) -> list[tuple[int, int]]:
    """Consecutive steps as (start, length) bars."""
    runs = []
    for s in steps:
        if runs and runs[-1][0] + runs[-1][1] == s:
            runs[-1] = (runs[-1][0], runs[-1][1] + 1)
        else:
            runs.append((int(s), 1))
    return runs
