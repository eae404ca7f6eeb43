"""Vectorized label generation vs. a plain per-point loop (issue 2 target: >= 100x on 1 M points).

Run: ``.venv/bin/python -m benchmarks.bench_labels [--points 1000000]``; writes
``benchmarks/results/labels.json``.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

from roadbev_core.config import GridSpec
from roadbev_core.labels import elevation_map
from roadbev_lab.evaluation.frames import to_json

RESULTS = Path(__file__).resolve().parent / "results"


def per_point_loop(points: np.ndarray, grid: GridSpec) -> np.ndarray:
    """The reference release's approach: visit every point of the array, accumulate into its cell.

    Iterates the NumPy rows as plain code does (no ``tolist()`` trick), like the released
    label script.
    """
    sums = np.zeros(grid.shape)
    counts = np.zeros(grid.shape)
    x_max, y_max, res = grid.x_max, grid.y_max, grid.resolution
    n_rows, n_cols = grid.shape
    for x, y, z in points:
        r = int(np.floor((x_max - x) / res))
        c = int(np.floor((y_max - y) / res))
        if 0 <= r < n_rows and 0 <= c < n_cols:
            sums[r, c] += z
            counts[r, c] += 1
    out = np.full(grid.shape, np.nan)
    np.divide(sums, counts, out=out, where=counts > 0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    grid = GridSpec()
    rng = np.random.default_rng(0)
    pts = rng.uniform([2.0, -1.1, -0.2], [7.3, 1.2, 0.2], size=(args.points, 3))

    t0 = time.perf_counter()
    ref = per_point_loop(pts, grid)
    loop_s = time.perf_counter() - t0
    fast_times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        lab = elevation_map(pts, grid)
        fast_times.append(time.perf_counter() - t0)
    fast_s = float(np.median(fast_times))
    max_diff = float(np.nanmax(np.abs(lab.elevation - ref)))
    same_mask = bool(np.array_equal(np.isfinite(ref), lab.mask))
    result = {
        "benchmark": "labels",
        "points": args.points,
        "loop_s": loop_s,
        "vectorized_s": fast_s,
        "speedup": loop_s / fast_s,
        "max_abs_diff_m": max_diff,
        "same_mask": same_mask,
        "target_speedup": 100.0,
        "machine": f"{platform.processor() or platform.machine()}, {__import__('os').cpu_count()} cores",
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    text = to_json(result)
    (RESULTS / "labels.json").write_text(text)
    print(text, end="")
    if max_diff > 1e-6 or not same_mask:
        raise SystemExit("vectorized labels differ from the per-point loop")


if __name__ == "__main__":
    main()
