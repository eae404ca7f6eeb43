"""The preview-at-arrival benchmark's drives carry the features it scores."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.bench_arrival import make_drive
from roadbev_lab.evaluation.arrival import ArrivalSettings, Trajectory, wheel_paths


@pytest.mark.parametrize(("speed", "seed"), [(10.0, 310001), (20.0, 310002)])
def test_the_kerb_roads_of_the_benchmark_put_features_under_the_wheels(speed: float, seed: int) -> None:
    # These two roads carry kerbs; when a kerb ran along the whole strip they stacked into a
    # clipped plateau and the wheels met no feature point at all (no images rendered here).
    drive = make_drive(speed, 10.0, 3.0, seed)
    assert "kerb" in drive.config.road.features
    gt = drive.ground_truth_poses()
    truth = Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw)
    settings = ArrivalSettings(lead_time_s=0.1, base_height=drive.config.grid.base_height,
                               camera_in_base=drive.base_to_camera)
    stamps = drive.frame_stamps_ns
    paths = wheel_paths(truth, drive.road_map(), settings, stamps[0] + 100_000_000, stamps[-1] + 100_000_000)
    feature_points = sum(int(p.feature.sum()) for p in paths)
    assert feature_points > 100
    for path in paths:  # and the road between the features is rough, not a plane
        assert float(np.std(np.diff(path.height, 2))) > 1e-5


def test_the_summary_pools_drives_by_the_points_they_scored() -> None:
    from benchmarks.bench_arrival import summarise

    def drive(seed: int, err: float, points: int, covered: int, features: float) -> dict[str, object]:
        row = {"abs_err_cm": err, "features_abs_err_cm": features, "smooth_abs_err_cm": err,
               "contact_plane_abs_err_cm": err, "points": points, "covered_points": covered,
               "features_points": 10, "features_coverage_pct": 100.0}
        return {"speed_mps": 10.0, "rate_hz": 10.0, "seed": seed, "rows": {"stereo": row}}

    (cell,) = summarise([drive(1, 0.2, 100, 100, 0.5), drive(2, 0.5, 300, 200, 1.0)])
    row = cell["rows"]["stereo"]
    assert cell["drives"] == 2
    assert row["abs_err_cm"] == pytest.approx((0.2 * 100 + 0.5 * 200) / 300)
    assert row["features_abs_err_cm"] == pytest.approx(0.75)
    assert row["coverage_pct"] == pytest.approx(100.0 * 300 / 400)
