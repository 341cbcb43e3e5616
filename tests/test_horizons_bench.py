"""bench/horizons.py: a step reached by planning the steps before it, solved at horizons below
and above predictT by both methods, which agree; the table and JSON written."""

from __future__ import annotations

import json

import horizons
import pytest


def test_parse_horizons() -> None:
    assert horizons.parse_horizons("12-14") == [12, 13, 14]
    assert horizons.parse_horizons("12,16") == [12, 16]


def test_the_second_step_at_horizons_around_predict_t(tmp_path, capsys) -> None:
    out = tmp_path / "h.json"
    args = ["--row", "1,1", "--rule", "2", "--seed", "0", "--step", "2", "--horizons", "4,6",
            "--time-limit", "30", "--json", str(out)]
    assert horizons.main(args) == 0
    data = json.loads(out.read_text())
    assert len(data["steps_before"]) == 1 and data["step"]["predicted_horizon"] == 5
    by = {(s["horizon"], s["method"]): s for s in data["solves"]}
    # Below predictT (a lower bound on the horizon) neither method finds a plan.
    assert by[4, "search"]["status"] == by[4, "monolithic"]["status"] == "infeasible"
    assert by[4, "search"]["bound"] is None
    assert by[6, "search"]["status"] == by[6, "monolithic"]["status"] == "optimal"
    assert by[6, "search"]["cost"] == pytest.approx(by[6, "monolithic"]["cost"], rel=1e-4)
    assert "| 6 | monolithic | optimal |" in capsys.readouterr().out
    assert out.with_suffix(".md").exists()
