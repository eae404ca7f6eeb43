"""bench_hazards' fused-map summary: shares, lead times and false alarms per speed."""

from __future__ import annotations

from typing import Any

import pytest

from benchmarks.bench_hazards import summarise_map


def _feature(reported: bool, lead: float = 0.0, err: float = 0.0) -> dict[str, Any]:
    row: dict[str, Any] = {"reported": reported}
    if reported:
        row.update(lead_s=lead, height_rel_err=err, first_reported_distance_m=lead * 10.0)
    return row


def test_summary_per_speed() -> None:
    drives = [
        {"speed_mps": 10.0, "features_on_road": True, "window_lead_s": 0.59, "km": 0.1, "false_alarms": 1,
         "features": [_feature(True, 0.5, 0.1), _feature(True, 1.2, 0.3), _feature(False)]},
        {"speed_mps": 10.0, "features_on_road": False, "window_lead_s": 0.59, "km": 0.5, "false_alarms": 0,
         "features": []},
    ]
    [row] = summarise_map(drives)
    assert (row["features"], row["reported"]) == (3, 2)
    assert row["reported_pct"] == pytest.approx(200.0 / 3)
    assert row["reported_1s_ahead_pct"] == pytest.approx(100.0 / 3)
    assert row["lead_s_median"] == pytest.approx(0.85) and row["lead_s_min"] == pytest.approx(0.5)
    assert row["height_within_15pct"] == pytest.approx(0.5)
    assert row["false_alarms_per_km_feature_roads"] == pytest.approx(10.0)
    assert (row["false_alarms_smooth"], row["smooth_km"]) == (0, 0.5)
