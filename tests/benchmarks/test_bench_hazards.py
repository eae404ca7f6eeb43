"""bench_hazards' fused-map summary (shares, lead times and false alarms per speed) and its options."""

from __future__ import annotations

import argparse
from typing import Any

import pytest

from benchmarks.bench_hazards import main, smooth_duration, summarise_map


def _feature(reported: bool, lead: float = 0.0, err: float = 0.0, first: float = 0.0, near: float = 0.0
             ) -> dict[str, Any]:
    row: dict[str, Any] = {"reported": reported}
    if reported:
        row.update(lead_s=lead, height_rel_err=err, first_reported_distance_m=lead * 10.0, first_height_rel_err=first,
                   height_at_near_rel_err=near)
    return row


def test_summary_per_speed() -> None:
    drives = [
        {"speed_mps": 10.0, "features_on_road": True, "window_lead_s": 0.59, "km": 0.1, "false_alarms": 1,
         "features": [_feature(True, 0.5, 0.1, 0.4, 0.2), _feature(True, 1.2, 0.3, 0.2, 0.1), _feature(False)]},
        {"speed_mps": 10.0, "features_on_road": False, "window_lead_s": 0.59, "km": 0.5, "false_alarms": 0,
         "features": []},
    ]
    [row] = summarise_map(drives)
    assert (row["features"], row["reported"]) == (3, 2)
    assert row["reported_pct"] == pytest.approx(200.0 / 3)
    assert row["reported_1s_ahead_pct"] == pytest.approx(100.0 / 3)
    assert row["reported_0.6s_ahead_pct"] == pytest.approx(100.0 / 3)
    assert row["first_height_rel_err_mean"] == pytest.approx(0.3)
    assert row["height_at_near_rel_err_mean"] == pytest.approx(0.15)
    assert row["lead_s_median"] == pytest.approx(0.85) and row["lead_s_min"] == pytest.approx(0.5)
    assert row["height_within_15pct"] == pytest.approx(0.5)
    assert row["false_alarms_per_km_feature_roads"] == pytest.approx(10.0)
    assert (row["false_alarms_smooth"], row["smooth_km"]) == (0, 0.5)


def test_smooth_drives_take_their_own_duration_or_the_features_one() -> None:
    assert smooth_duration(argparse.Namespace(duration=12.0, smooth_duration=None)) == 12.0
    assert smooth_duration(argparse.Namespace(duration=12.0, smooth_duration=50.0)) == 50.0


def test_a_smooth_duration_that_is_not_positive_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--map", "--smooth-duration", "0"])
    assert exc.value.code == 2
    assert "--smooth-duration must be > 0 s" in capsys.readouterr().err
