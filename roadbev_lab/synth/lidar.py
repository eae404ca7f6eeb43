"""A simulated spinning LiDAR: rays cast against a scene's height field, with range noise.

The LiDAR-like sampling of :func:`roadbev_lab.synth.drive.sample_points` puts points straight on
the surface on a jittered grid; a real LiDAR sees the road along rings (one per laser), densest
near the car, with noise along each ray. :func:`lidar_scan` casts such rays: ``rings`` lasers at
elevations evenly spread over ``elevation_deg``, an azimuth step of ``azimuth_step_deg`` over the
field of view, intersected with ``scene.height`` by bisection, range noise added along the ray.
The result is in the LiDAR's own frame (x forward, y left, z up), as a driver publishes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from roadbev_lab.synth.scene import Scene

__all__ = ["LidarPattern", "cast_rays", "lidar_scan"]


@dataclass(frozen=True)
class LidarPattern:
    """The beams of a simulated LiDAR.

    Attributes:
        rings: number of lasers.
        elevation_deg: lowest and highest laser elevation (degrees, negative = down).
        azimuth_deg: field of view (degrees, 0 = forward, positive = left).
        azimuth_step_deg: horizontal angular step.
        range_noise_m: 1-sigma noise along each ray (m).
        max_range_m: rays that hit nothing closer return nothing.
    """

    rings: int = 32
    elevation_deg: tuple[float, float] = (-35.0, -6.0)
    azimuth_deg: tuple[float, float] = (-35.0, 35.0)
    azimuth_step_deg: float = 0.2
    range_noise_m: float = 0.01
    max_range_m: float = 40.0

    def directions(self) -> np.ndarray:
        """[rings * n_azimuth, 3] unit ray directions in the LiDAR frame."""
        el = np.radians(np.linspace(*self.elevation_deg, self.rings))
        az = np.radians(np.arange(self.azimuth_deg[0], self.azimuth_deg[1] + 1e-9, self.azimuth_step_deg))
        e, a = np.meshgrid(el, az, indexing="ij")
        return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)


def cast_rays(scene: Scene, origin: np.ndarray, directions: np.ndarray, max_range_m: float) -> np.ndarray:
    """[N] range (m) at which each world-frame ray meets the surface (NaN: no hit in range).

    Bisection on ``ray z - surface height`` between the origin and the first of 64 coarse steps
    that lies below the surface (32 halvings: below a micrometre).
    """
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)  # [N, 3]

    def below(rays: np.ndarray, t: np.ndarray) -> np.ndarray:
        p = o + d[rays] * t[:, None]
        return cast("np.ndarray", p[:, 2] <= scene.height(p[:, 0], p[:, 1]))

    n = d.shape[0]
    # Coarse steps grow with the range (rays reach the road at grazing angles far away).
    steps = max_range_m * (np.arange(1, 65) / 64.0) ** 2
    hi = np.full(n, np.nan)
    for t in steps:
        todo = np.isnan(hi)
        if not todo.any():
            break
        idx = np.flatnonzero(todo)
        hit = below(idx, np.full(idx.size, t))
        hi[idx[hit]] = t
    found = np.isfinite(hi)
    lo = np.zeros(n)
    prev = np.concatenate([[0.0], steps])
    lo[found] = prev[np.searchsorted(steps, hi[found])]
    idx = np.flatnonzero(found)
    a, b = lo[idx], hi[idx]
    for _ in range(32):
        mid = 0.5 * (a + b)
        under = below(idx, mid)
        b = np.where(under, mid, b)
        a = np.where(under, a, mid)
    out = np.full(n, np.nan)
    out[idx] = 0.5 * (a + b)
    return out


def lidar_scan(
    scene: Scene,
    position: np.ndarray,
    rotation_world_lidar: np.ndarray,
    pattern: LidarPattern,
    rng: np.random.Generator,
) -> np.ndarray:
    """[N, 4] float32 points (x, y, z, intensity 0) in the LiDAR frame of one scan.

    Args:
        scene: the road.
        position: [3] the LiDAR's origin in the scene's world frame.
        rotation_world_lidar: [3, 3] LiDAR axes -> world axes.
        pattern: the beams.
        rng: for the range noise.
    """
    dirs = pattern.directions()  # [N, 3] LiDAR frame
    R = np.asarray(rotation_world_lidar, dtype=np.float64)
    ranges = cast_rays(scene, np.asarray(position, np.float64), dirs @ R.T, pattern.max_range_m)
    hit = np.isfinite(ranges)
    r = ranges[hit] + rng.normal(0.0, pattern.range_noise_m, int(hit.sum()))
    pts = dirs[hit] * r[:, None]
    out = np.zeros((pts.shape[0], 4), np.float32)
    out[:, :3] = pts
    return out
