"""bench/whole.py: a scene planned as one task and sequentially, both verified, the records and
the tables written; bench/report.py renders them."""

from __future__ import annotations

import json

import whole


def test_two_objects_as_one_task_and_sequentially(tmp_path, capsys) -> None:
    out = tmp_path / "whole-small.json"
    args = ["--objects", "2", "--rules", "1", "--seeds", "1-1", "--sequential", "1,2",
            "--json", str(out)]
    assert whole.main(args) == 0
    data = json.loads(out.read_text())
    assert data["complete"]
    by = {r["method"]: r for r in data["runs"]}
    assert by.keys() == {"whole", "sequential"}
    assert all(r["status"] == "ok" for r in by.values())
    one = by["whole"]
    assert one["steps"] == 1 and one["horizon_proven_minimal"] and one["gap"] <= 1e-4
    assert one["bound"] <= one["cost"] and one["expansions"] >= 1
    assert not one["joined"] and not one["guided"]  # the search's own plan
    assert one["joined_row"] is None
    assert by["sequential"]["steps"] == 2  # m_o = 1: one object a step
    # delivery rest: the sequential steps joined are a plan of the whole task, whose horizon is
    # proven minimal
    assert one["makespan"] <= by["sequential"]["makespan"]
    text = capsys.readouterr().out
    assert "| 2 | 1 | 1/1 | 1/1 |" in text and "Per scene:" in text
    assert whole.report(data) in out.with_suffix(".md").read_text()


def test_a_joined_plan_says_at_which_steps() -> None:
    assert whole.origin({"joined": True, "joined_row": [4, 4]}) == "sequential (4,4), joined"
    assert whole.origin({"joined": True}) == "sequential's, joined"  # records before the row
    assert whole.origin({"joined": False, "joined_row": None}) == "the search's"
