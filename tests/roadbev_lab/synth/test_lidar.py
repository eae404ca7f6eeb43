"""The simulated LiDAR (roadbev_lab.synth.lidar): ranges where the rays meet the surface."""

from __future__ import annotations

import numpy as np

from roadbev_lab.synth import RoadConfig, build_scene
from roadbev_lab.synth.lidar import LidarPattern, cast_rays, lidar_scan


def test_rays_meet_the_height_field() -> None:
    scene = build_scene(RoadConfig(features=("speed_bump",)), 4, (-4.0, 30.0))
    origin = np.array([0.0, 0.0, 1.5])
    pattern = LidarPattern(rings=8, azimuth_step_deg=2.0, range_noise_m=0.0)
    dirs = pattern.directions()
    ranges = cast_rays(scene, origin, dirs, pattern.max_range_m)
    hit = np.isfinite(ranges)
    assert hit.mean() > 0.95
    p = origin + dirs[hit] * ranges[hit, None]
    np.testing.assert_allclose(p[:, 2], scene.height(p[:, 0], p[:, 1]), atol=1e-5)
    up = cast_rays(scene, origin, np.array([[0.0, 0.0, 1.0]]), 40.0)
    assert np.isnan(up[0])
    scan = lidar_scan(scene, origin, np.eye(3), pattern, np.random.default_rng(0))
    assert scan.shape == (int(hit.sum()), 4) and scan.dtype == np.float32
