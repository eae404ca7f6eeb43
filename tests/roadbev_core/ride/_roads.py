"""Small straight drives on analytic roads for the ride tests (no rendering)."""

from __future__ import annotations

import math

import numpy as np

from roadbev_lab.evaluation.arrival import RoadMap, Trajectory

S = 1_000_000_000
T0 = 1_700_000_000 * S


def bump_map(height: float = 0.05, at: float | tuple[float, ...] = 20.0, length: float = 0.6,
             grade: float = 0.0) -> RoadMap:
    """A road with cosine bumps ``length`` long across it at x = ``at`` (2 cm cells; x in [-5, 75],
    y in [-2, 2]), on a plane rising ``grade`` along x."""
    res, n_rows, n_cols = 0.02, 4000, 200
    x = 75.0 - (np.arange(n_rows) + 0.5) * res
    prof = grade * x
    for centre in (at,) if isinstance(at, float) else at:
        prof = prof + np.where(np.abs(x - centre) < length / 2,
                               0.5 * height * (1 + np.cos(2 * math.pi * (x - centre) / length)), 0.0)
    return RoadMap(np.repeat(prof[:, None], n_cols, 1).astype(np.float32), res, (35.0, 0.0))


def straight(speed: float, seconds: float, pitch: float = 0.0) -> Trajectory:
    """base_link along x at ``speed`` from x = 0, every 10 ms, optionally pitched (rad, nose down > 0)."""
    t = np.arange(0.0, seconds + 1e-9, 0.01)
    pos = np.stack([speed * t, np.zeros_like(t), np.zeros_like(t)], 1)
    q = np.tile([0.0, math.sin(pitch / 2), 0.0, math.cos(pitch / 2)], (t.size, 1))
    return Trajectory(T0 + np.rint(t * S).astype(np.int64), pos, q)
