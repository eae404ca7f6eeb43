"""bench_ride's scoring on tiny inputs: shares per row, the summary over drives, road kinds."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from benchmarks.bench_ride import CandidateRows, candidate_makers, road_config, scores, summarise
from benchmarks.preview_budget import FAR_STAGES, LABEL_STAGES, STAGES, Candidate
from roadbev_core.config import GridSpec


def _rows(**wk: float) -> dict[str, dict[str, Any]]:
    return {name: {"mean": {"wk_rms_mps2": v, "peak_travel_m": 0.05, "tyre_load_rms_ratio": 0.1,
                            "force_rms_n": 100.0}} for name, v in wk.items()}


def test_scores_are_shares_of_the_ceilings_gain() -> None:
    rows = _rows(passive=3.0, no_preview=2.0, true_road=1.0, window=1.2, bev_sweep=1.6)
    share = scores(rows)
    assert set(share) == {"true_road", "window", "bev_sweep"}
    assert share["true_road"] == pytest.approx(1.0)
    assert share["window"] == pytest.approx(0.8)
    assert share["bev_sweep"] == pytest.approx(0.4)
    assert math.isnan(scores(_rows(passive=3.0, no_preview=2.0, true_road=2.0, window=1.0))["window"])


def test_summary_groups_drives_and_spreads_the_shares() -> None:
    def cell(rendered: bool, speed: float, window: float) -> dict[str, Any]:
        rows = _rows(passive=3.0, no_preview=2.0, true_road=1.0, window=window)
        return {"rendered": rendered, "speed_mps": speed, "rates": {"5": {"rows": rows, "share": scores(rows)}}}

    table = summarise([cell(False, 10.0, 1.2), cell(False, 10.0, 1.4), cell(True, 10.0, 1.0), cell(False, 5.0, 1.0)])
    assert [(t["rendered"], t["speed_mps"], t["drives"]) for t in table] == [(False, 5.0, 1), (False, 10.0, 2),
                                                                             (True, 10.0, 1)]
    window = table[1]["rows"]["window"]
    assert window["share_mean"] == pytest.approx(0.7)
    assert window["share_std"] == pytest.approx(0.1)
    assert (window["share_min"], window["share_max"]) == pytest.approx((0.6, 0.8))
    assert window["wk_rms_mps2"] == pytest.approx(1.3)
    assert list(table[1]["rows"]) == ["passive", "no_preview", "true_road", "window"]
    assert "share_mean" not in table[1]["rows"]["passive"]


def test_road_kinds() -> None:
    rng = np.random.default_rng(0)
    assert road_config("bumps", rng).features == ("speed_bump", "hump")
    assert road_config("rough", rng).road_class == "D"
    with pytest.raises(ValueError):
        road_config("gravel", rng)


def test_truth_only_drives_are_taken_from_an_earlier_run(tmp_path: Any) -> None:
    import json

    from benchmarks.bench_ride import BenchError, truth_cells_from

    rows = _rows(passive=3.0, no_preview=2.0, true_road=1.0)
    cell = {"road": "bumps", "speed_mps": 5.0, "seed": 7, "duration_s": 20.0, "rendered": False,
            "rates": {"5": {"rows": rows}, "10": {"rows": rows}}}
    path = tmp_path / "ride.json"
    path.write_text(json.dumps({"latency_s": 0.1, "command": "python -m benchmarks.bench_ride", "wall_s": 9.0,
                                "machine": {"git_commit": "abc"}, "cells": [cell, {**cell, "rendered": True}]}))
    cells, where = truth_cells_from(path, [("bumps", 5.0, 7)], 20.0, [5.0, 10.0], 0.1)
    assert cells[("bumps", 5.0, 7)]["rendered"] is False
    assert where["git_commit"] == "abc" and where["command"] == "python -m benchmarks.bench_ride"
    with pytest.raises(BenchError, match="no truth-only drive"):
        truth_cells_from(path, [("bumps", 10.0, 7)], 20.0, [5.0, 10.0], 0.1)
    with pytest.raises(BenchError, match="ridden"):
        truth_cells_from(path, [("bumps", 5.0, 7)], 6.0, [5.0, 10.0], 0.1)
    with pytest.raises(BenchError, match="latency"):
        truth_cells_from(path, [("bumps", 5.0, 7)], 20.0, [5.0, 10.0], 0.2)
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(BenchError, match="not a bench_ride result"):
        truth_cells_from(tmp_path / "bad.json", [], 20.0, [5.0], 0.1)


def test_the_far_field_rows_reach_the_far_edge_and_see_more_at_speed() -> None:
    from benchmarks.bench_ride import run_cell

    cell = run_cell("bumps", 20.0, 7, 2.0, (10.0,), 0.1, {}, far_x_max=15.0)
    data = cell["rates"]["10"]
    assert {"window", "map_plane", "window_far", "map_plane_far", "map_plane_attitude_far"} <= set(data["rows"])
    # at 20 m/s the grid's window leaves the controller a fraction of its horizon; the far edge more
    assert data["share"]["window_far"] > data["share"]["window"]
    assert data["share"]["map_plane_attitude_far"] > data["share"]["map_plane_attitude"]
    plain = run_cell("bumps", 20.0, 7, 2.0, (10.0,), 0.1, {})
    assert "window_far" not in plain["rates"]["10"]["rows"]
    assert plain["rates"]["10"]["share"]["window"] == pytest.approx(data["share"]["window"])


def test_a_drive_is_at_most_what_one_road_strip_holds() -> None:
    from benchmarks.bench_ride import drive_duration, run_cell

    assert drive_duration(20.0, 20.0) == 20.0 and drive_duration(6.0, 30.0) == 6.0
    assert drive_duration(20.0, 30.0) == pytest.approx(17.1)
    cell = run_cell("rough", 40.0, 8, 20.0, (10.0,), 0.1, {})  # 20 s at 40 m/s would leave the strip
    assert cell["duration_s"] == pytest.approx(drive_duration(20.0, 40.0))


def test_a_budgeted_far_field_candidate_gets_every_stage_of_the_budget() -> None:
    far = Candidate("far", "ensemble", {"far_field.enabled": True}, latency_s=0.1)
    near = Candidate("near", "bm", {"far_field.enabled": False}, latency_s=0.1)
    makers = candidate_makers([far, near], ["far"], GridSpec())
    assert {f"far:{stage}" for stage in STAGES[1:]} <= set(makers)
    assert {f"far:{stage}" for stage in LABEL_STAGES} <= set(makers)  # the truth on the far grid as well
    assert "far" in makers and "near" in makers and not any(name.startswith("near:") for name in makers)
    # a budgeted candidate without a far field has every stage but those that change a far field
    both = candidate_makers([far, near], [], GridSpec())
    assert {f"near:{stage}" for stage in STAGES[1:] if stage not in FAR_STAGES} <= set(both)
    assert not {f"near:{stage}" for stage in FAR_STAGES} & set(both)


def test_a_paced_candidate_never_shares_the_estimates_of_its_backend_unpaced() -> None:
    far = Candidate("far", "ensemble", {"far_field.enabled": True}, latency_s=0.1)
    again = Candidate("again", "ensemble", {"far_field.enabled": True, "preview.max_gap_m": 0.0}, latency_s=0.2)
    paced = Candidate("paced", "ensemble", {"far_field.enabled": True, "pace_backend": "bm"}, latency_s=0.1,
                      pace=(0.08, 0.07))
    sgbm_paced = Candidate("sgbm_paced", "ensemble", {"far_field.enabled": True, "pace_backend": "sgbm"},
                           latency_s=0.1, pace=(0.08, 0.07))
    keys = {c.name: CandidateRows(c, {})._key for c in (far, again, paced, sgbm_paced)}
    assert keys["far"] == keys["again"]  # the same estimates: shared
    assert len({keys["far"], keys["paced"], keys["sgbm_paced"]}) == 3
