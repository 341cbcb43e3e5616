"""The closed-loop timeline (figures/timeline.py) from a summary's fields: a bar per hold in its
object's goal colour, a mark per replan by status, each delivery, each event through every
panel, the arms' clearance where the summary has it; every mark in a legend."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.colors import to_hex

from dualarm_mpc.base.palette import goal_colour
from dualarm_mpc.figures.timeline import STATUS_COLOURS, plot_timeline, timeline_figure

SUMMARY = {
    "mode": "lockstep",
    "objects": [{"name": "object1", "goal": "red"}, {"name": "object2", "goal": "green"}],
    "delivered_time_s": [4.0, None],
    "replans": [
        {"t": 0.0, "status": "optimal", "adopted": True, "objects": ["object1", "object2"]},
        {"t": 1.0, "status": "kept", "adopted": False, "objects": ["object1", "object2"]},
        {"t": 2.0, "status": "optimal", "adopted": True, "objects": ["object2"]},
        {"t": 3.0, "status": "searching", "adopted": False, "objects": ["object2"]},
        {"t": 4.0, "status": "done", "adopted": True, "objects": []},
    ],
    "holds": [{"arm": 1, "object": "object1", "from": 0.5, "to": 2.0},
              {"arm": 2, "object": "object2", "from": 2.5, "to": 3.5}],
    "clearance": [[0.0, 0.2], [1.0, 0.15], [2.0, 0.1], [3.0, 0.12], [4.0, 0.3]],
    "min_arm_clearance_m": 0.09,
    "events": [{"time": 1.5, "kind": "move_object", "target": "object2", "position": [0, 0]},
               {"time": 3.2, "kind": "move_goal", "target": "red", "box": [0, 1, 0, 1]}],
    "sim_time_s": 5.0,
}


@pytest.fixture(scope="module")
def fig():
    fig = timeline_figure(SUMMARY)
    yield fig
    plt.close(fig)


def test_a_bar_per_hold_in_its_objects_goal_colour_on_its_arms_row(fig) -> None:
    top = fig.axes[0]
    boxes = [(b.get_paths()[0].vertices, to_hex(b.get_facecolor()[0][:3]))
             for b in top.collections]
    bars = sorted(((v[:, 0].min(), v[:, 0].max(), (v[:, 1].min() + v[:, 1].max()) / 2, c)
                   for v, c in boxes), key=lambda b: b[0])
    rows = dict(zip([t.get_text() for t in top.get_yticklabels()], top.get_yticks(),
                    strict=True))
    assert np.array([(a, b) for a, b, _, _ in bars]) == pytest.approx(
        np.array([(0.5, 2.0), (2.5, 3.5)]))
    assert [y for _, _, y, _ in bars] == pytest.approx([rows["arm 1 (right)"],
                                                        rows["arm 2 (left)"]])
    assert [c for *_, c in bars] == [to_hex(goal_colour("red")), to_hex(goal_colour("green"))]
    assert {"1", "2"} <= {t.get_text() for t in top.texts}


def test_replans_by_status_deliveries_and_events(fig) -> None:
    top, below = fig.axes
    marks = [line for line in top.lines if line.get_marker() == "o"]
    assert [line.get_xdata()[0] for line in marks] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert [to_hex(line.get_color()) for line in marks] == [
        STATUS_COLOURS[r["status"]] for r in SUMMARY["replans"]]
    hollow = [line.get_markerfacecolor() == "white" for line in marks]
    assert hollow == [not r["adopted"] for r in SUMMARY["replans"]]
    steps = sorted(t.get_text() for t in top.texts if t.get_text().startswith("step"))
    assert steps == ["step 1", "step 2"]  # where the replans' objects change
    delivered = [line for line in top.lines if line.get_marker() == "v"]
    assert [line.get_xdata()[0] for line in delivered] == [4.0]  # object2 never was
    for ax in (top, below):  # each event through both panels
        verticals = [line.get_xdata()[0] for line in ax.lines if line.get_linestyle() in
                     ("--", "-.")]
        assert verticals == [1.5, 3.2]
    texts = {t.get_text() for t in top.texts}
    assert "object 2 knocked" in texts and "goal red moved" in texts
    labels = [t.get_text() for t in top.get_legend().get_texts()]
    for expected in ("holds object n", "object n delivered", "replan: optimal", "replan: kept",
                     "replan: searching", "replan: done", "hollow: no new plan adopted",
                     "arms' least distance", "least over the run, 9.0 cm",
                     "an object knocked away", "a goal moved"):
        assert any(label.startswith(expected) for label in labels), (expected, labels)


def test_the_arms_clearance_in_centimetres_over_simulated_time(fig) -> None:
    below = fig.axes[1]
    line = next(line for line in below.lines if line.get_marker() == ".")
    assert np.array(line.get_xydata()) == pytest.approx(
        np.array([[t, 100 * m] for t, m in SUMMARY["clearance"]]))
    assert below.get_xlabel() == "simulated time [s]" and "[cm]" in below.get_ylabel()
    assert fig.axes[0].get_xlim() == pytest.approx((0, 5.0))


def test_a_summary_without_clearance_or_replans_has_one_panel(tmp_path) -> None:
    """An old summary (no ``holds`` nor ``clearance``), or a run stopped before its first
    replan, is still drawn."""
    fig = timeline_figure({"objects": [], "replans": [], "sim_time_s": 0.0})
    assert len(fig.axes) == 1 and fig.axes[0].get_xlabel() == "simulated time [s]"
    plt.close(fig)
    path = tmp_path / "run.png"
    plot_timeline(SUMMARY, path, "a title")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
