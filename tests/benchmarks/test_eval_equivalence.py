"""The behaviour check of refactors: what counts as the same eval JSON."""

from __future__ import annotations

from benchmarks.eval_equivalence import differing_keys, without_timings


def test_timings_and_the_bag_path_are_left_out_at_every_depth() -> None:
    doc = {"abs_err_cm": 0.3, "fps": 4.2, "bag": "/a.mcap", "stage_ms": {"post": 1.0},
           "map": {"frames": 20, "pipeline_ms": 3.0, "timed_frames": 19}}
    assert without_timings(doc) == {"abs_err_cm": 0.3, "map": {"frames": 20}}


def test_a_changed_metric_is_named_and_a_changed_timing_is_not() -> None:
    before = {"abs_err_cm": 0.3, "coverage_pct": 90.0, "fps": 4.0}
    assert differing_keys(before, {**before, "fps": 9.0}) == []
    assert differing_keys(before, {**before, "coverage_pct": 89.9}) == ["coverage_pct"]
    assert differing_keys(before, {"abs_err_cm": 0.3, "fps": 4.0}) == ["coverage_pct"]
