"""The plan figure a person reads at a glance: every mark in a legend, time in seconds, the
hands' paths one panel per sequential step in the arms' colours, every planned end labelled."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.colors import to_hex

from dualarm_mpc.base.palette import ARM_COLOURS
from dualarm_mpc.figures.plan import plan_figure, plot_plan
from dualarm_mpc.model.plan import Plan, Segment, Trajectory

DT = 0.5


@pytest.fixture(scope="module")
def plan() -> Plan:
    """Two sequential steps of two Δt each; objects 1 and 2 end on one point."""
    hands = np.array([[[0.1, 0.0], [-0.1, 0.0]], [[0.2, 0.3], [-0.2, 0.3]],
                      [[0.2, 0.6], [-0.2, 0.6]], [[0.0, 0.3], [-0.3, 0.3]],
                      [[0.0, 0.6], [-0.3, 0.6]]])
    objects = np.array([[[0.2, 0.3], [-0.2, 0.3], [0.0, 0.3]]] * 5)
    objects[2:, 0] = objects[2:, 1] = [0.0, 1.0]
    objects[4, 2] = [0.1, 1.0]
    grasp = np.zeros((5, 2, 3))
    grasp[1, 0, 0] = grasp[1, 1, 1] = grasp[3, 0, 2] = 1
    trajectory = Trajectory(hands, np.zeros_like(hands), np.zeros((4, 2, 2)), objects,
                            np.zeros_like(objects), grasp)
    return Plan(dt=DT, rule=2, delivery="rest", goals={"red": [-0.2, 0.2, 0.9, 1.1]},
                objects=[{"name": f"object{j + 1}", "goal": "red", "grasp_half_size": 0.05}
                         for j in range(3)],
                workspace=[-0.9, 0.9, 0.0, 0.9], trajectory=trajectory,
                delivered_step=[2, 2, 4],
                segments=[Segment([0, 1], [0, 1], 2, "optimal", 0.1, 1.0),
                          Segment([2], [2], 2, "optimal", 0.1, 1.0)])


@pytest.fixture(scope="module")
def fig(plan):
    fig = plan_figure(plan)
    yield fig
    plt.close(fig)


def test_every_mark_has_a_legend_entry_and_time_is_in_seconds(fig) -> None:
    table, step1, step2, timeline = fig.axes
    labels = [t.get_text() for t in table.get_legend().get_texts()]
    for expected in ("hand range", "goal box", "object path", "object start", "object end",
                     "arm 1 (right) hand", "arm 2 (left) hand"):
        assert any(label.startswith(expected) for label in labels), (expected, labels)
    assert [t.get_text() for t in timeline.get_legend().get_texts()] == [
        "holds object n, in its goal's colour", "end of a sequential step"]
    assert timeline.get_xlabel() == "time [s]"
    assert timeline.get_xlim() == pytest.approx((0, 4 * DT))
    bars = [(b.get_paths()[0].vertices[:, 0].min(), b.get_paths()[0].vertices[:, 0].max())
            for b in timeline.collections]
    assert np.array(sorted(bars)) == pytest.approx(
        np.array([(1 * DT, 2 * DT)] * 2 + [(3 * DT, 4 * DT)]))
    assert [line.get_xdata()[0] for line in timeline.lines] == pytest.approx([2 * DT, 4 * DT])


def test_each_step_has_its_panel_with_the_hands_in_the_arms_colours(plan, fig) -> None:
    _, step1, step2, _ = fig.axes
    for panel, (k0, k1) in ((step1, (0, 2)), (step2, (2, 4))):
        hands = [line for line in panel.lines if line.get_marker() == "."]
        assert [to_hex(line.get_color()) for line in hands] == list(ARM_COLOURS)
        for i, line in enumerate(hands):
            assert np.array(line.get_xydata()) == pytest.approx(
                plan.trajectory.hand_pos[k0:k1 + 1, i])
    assert "delivers 1,2" in step1.get_title() and "delivers 3" in step2.get_title()
    assert f"{2 * DT:g}–{4 * DT:g} s" in step2.get_title()


def test_objects_ending_on_one_point_share_its_label(plan, fig) -> None:
    ends = {tuple(p) for p in plan.trajectory.object_pos[-1]}
    labels = {tuple(t.xy): t.get_text() for t in fig.axes[0].texts
              if hasattr(t, "xy") and tuple(t.xy) in ends}
    assert labels == {(0.0, 1.0): "1,2", (0.1, 1.0): "3"}


def test_plot_plan_writes_a_png(plan, tmp_path) -> None:
    path = tmp_path / "plan.png"
    plot_plan(plan, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --- issue 51: releases and throws marked, the step panels' axes, the steps' ends ---------------


@pytest.fixture(scope="module")
def thrown(plan) -> Plan:
    """``plan`` where hand 1 holds object 1 one Δt past the step that delivered it, and throws
    object 3 (it leaves the hand at 0.3 m/s)."""
    t = plan.trajectory
    grasp, vel = t.grasp.copy(), t.object_vel.copy()
    grasp[2, 0, 0] = 1  # held at step 1's end, delivered: let go in step 2's first Δt
    vel[4, 2] = [0.0, 0.3]
    trajectory = Trajectory(t.hand_pos, t.hand_vel, t.force, t.object_pos, vel, grasp)
    return Plan(dt=plan.dt, rule=plan.rule, delivery=plan.delivery, goals=plan.goals,
                objects=plan.objects, workspace=plan.workspace, trajectory=trajectory,
                delivered_step=plan.delivered_step, segments=plan.segments)


def test_where_a_hand_lets_go_is_marked_a_throw_apart(thrown) -> None:
    fig = plan_figure(thrown)
    table, step1, step2, _ = fig.axes

    def marks(ax, marker):
        return [tuple(line.get_xydata()[0]) for line in ax.lines if line.get_marker() == marker]

    # put down: objects 1 and 2 where they end (1's let go after its step: in step 1's panel)
    assert sorted(marks(table, "x")) == [(0.0, 1.0), (0.0, 1.0)]
    assert marks(table, "*") == [(0.1, 1.0)]  # object 3 thrown where it left the hand
    assert len(marks(step1, "x")) == 2 and marks(step2, "*") == [(0.1, 1.0)]
    labels = [t.get_text() for t in table.get_legend().get_texts()]
    assert "a hand puts the object down" in labels
    assert "a hand throws it (lets go at speed; it slides on)" in labels
    plt.close(fig)


def test_the_step_panels_axes_are_labelled(fig) -> None:
    _, step1, step2, _ = fig.axes
    assert step1.get_ylabel() == "y [m]" and step1.get_xlabel() == "x [m]"
    assert step2.get_xlabel() == "x [m]" and len(step1.get_xticks()) > 1


def test_a_hold_past_its_steps_end_goes_on_hatched(thrown) -> None:
    """Before: the grey end-of-step line fell inside a hold bar (§V-D seed 3: step 1 ends at
    6 s, arm 1 holds an object until 7 s), as if the step ended while its work went on."""
    fig = plan_figure(thrown)
    timeline = fig.axes[-1]
    bars = sorted((b.get_paths()[0].vertices[:, 0].min(), b.get_paths()[0].vertices[:, 0].max(),
                   bool(b.get_hatch())) for b in timeline.collections)
    assert bars == [(1 * DT, 2 * DT, False), (1 * DT, 2 * DT, False), (2 * DT, 3 * DT, True),
                    (3 * DT, 4 * DT, False)]
    assert [line.get_xdata()[0] for line in timeline.lines] == pytest.approx([2 * DT, 4 * DT])
    labels = [t.get_text() for t in timeline.get_legend().get_texts()]
    assert labels == ["holds object n, in its goal's colour",
                      "holds it delivered: lets go in the next step", "end of a sequential step"]
    plt.close(fig)
