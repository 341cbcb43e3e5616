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
