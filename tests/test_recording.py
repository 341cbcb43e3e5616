"""The replay's head-up display as data (``recording.Notes.overlay``), without a run or a browser:
which step a replan belongs to, the kept plan's cost, the deliveries, holds and events it says.
tests/test_viewer.py reads the HUD of a real run in headless Chromium."""

from __future__ import annotations

import json
import re
from types import SimpleNamespace

from dualarm_mpc.sim import recording


def replan(t: float, status: str, objects: list[str], cost: float | None = None,
           adopted: bool = False) -> dict:
    return {"t": t, "status": status, "objects": objects, "cost": cost, "adopted": adopted}


SUMMARY = SimpleNamespace(
    objects=[{"name": "a", "goal": "red"}, {"name": "b", "goal": "blue"},
             {"name": "c", "goal": "red"}],
    replans=[replan(0.0, "optimal", ["a", "b"], 1.5, True), replan(1.0, "kept", ["a", "b"]),
             replan(2.0, "optimal", ["c"], 0.5, True), replan(3.0, "kept", ["c"]),
             replan(4.0, "done", [])],
    delivered_time_s=[2.0, None, 3.5],
    holds=[{"arm": 1, "object": "a", "from": 0.5, "to": 1.8},
           {"arm": 2, "object": "b", "from": 0.6, "to": 1.8},
           {"arm": 2, "object": "c", "from": 1.8, "to": 3.0},
           {"arm": 1, "object": "b", "from": 3.2, "to": 5.0}],  # cut short by the run's end
    sim_time_s=5.0,
    events=[{"time": 2.5, "kind": "move_goal", "target": "red", "box": [0.1, 0.4, 1.0, 1.3],
             "position": []},
            {"time": 1.5, "kind": "move_object", "target": "b", "position": [0.25, 0.5],
             "box": []}],
)


def run_of(html: str) -> dict:
    return json.loads(re.search(r"const run = (.*);\n", html).group(1))


def test_the_hud_counts_a_step_per_run_of_replans_for_the_same_objects() -> None:
    notes = recording.Notes(None, None, None)
    notes.releases = [[1.8, 0, 0, 0.4]]
    run = run_of(notes.overlay(SUMMARY))
    # [t, step, status, cost, the plan in force's cost and time, objects (numbered from 1)]
    assert run["replans"] == [[0.0, 1, "optimal", 1.5, 1.5, 0.0, [1, 2]],
                              [1.0, 1, "kept", None, 1.5, 0.0, [1, 2]],
                              [2.0, 2, "optimal", 0.5, 0.5, 2.0, [3]],
                              [3.0, 2, "kept", None, 0.5, 2.0, [3]],
                              [4.0, 2, "done", None, 0.5, 2.0, []]]
    assert run["delivered"] == [2.0, 3.5] and run["n"] == 3
    assert run["goals"] == ["red", "blue", "red"]
    # [t, arm from 0, object from 0 or -1: free]; at one time an arm lets go, then takes
    assert run["holds"] == [[0.5, 0, 0], [0.6, 1, 1], [1.8, 0, -1], [1.8, 1, -1], [1.8, 1, 2],
                            [3.0, 1, -1], [3.2, 0, 1]]
    assert run["releases"] == [[1.8, 0, 0, 0.4]]
    assert run["arms"] == ["arm 1 (right)", "arm 2 (left)"]
    assert run["events"] == [[1.5, "object 2 knocked to (0.25, 0.50)"],
                             [2.5, "goal red moved to x 0.10\u20130.40, y 1.00\u20131.30"]]


def test_the_hud_cannot_close_its_script() -> None:
    summary = SimpleNamespace(**{**SUMMARY.__dict__,
                                 "objects": [{"name": "a", "goal": "</script>"}],
                                 "replans": [], "delivered_time_s": [None], "events": [],
                                 "holds": []})
    html = recording.Notes(None, None, None).overlay(summary)
    assert html.count("</script>") == 1
    assert run_of(html)["goals"] == ["</script>"]


def test_both_calls_each_observer_given() -> None:
    seen = []
    first, second = (lambda d, c: seen.append(("first", d, c))), \
        (lambda d, c: seen.append(("second", d, c)))
    assert recording.both(None, None) is None
    assert recording.both(None, first) is first
    recording.both(first, None, second)("dual", "context")
    assert seen == [("first", "dual", "context"), ("second", "dual", "context")]
