"""Drive bags for training: the benchmark drives' distribution, on seeds the benchmarks never use.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.training_drives --out .cache/train_drives --first 0 --count 12
    .venv/bin/roadbev train --kind stereo --bag .cache/train_drives/drive_340000.mcap --bag ...

Each drive is :func:`benchmarks.bench_arrival.make_drive` (a random road of the test-scene
distribution with a speed bump and a pothole every 3 m, the car riding on it) at a speed cycling
through :data:`SPEEDS`, seed ``SEED_BASE + i``. The benchmark drives use seeds 310000+, the datum
calibration 300001-300010 and the demo 330000, so these frames never meet an evaluation. The camera
rate keeps consecutive frames at least ``--spacing`` metres apart (at most 5 Hz), so a slow drive
does not fill the set with near-copies of one stretch of road. ``roadbev train --bag`` reads the
per-frame ground truth and the IMU attitude of each bag as the node would.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from benchmarks.bench_arrival import make_drive

SEED_BASE = 340000
VALIDATION_SEED_BASE = 345000  # held-out drives: to judge a training run, never trained on
SPEEDS = (5.0, 10.0, 15.0, 20.0, 25.0)


def write_drive(out: Path, index: int, frames: int, spacing: float, seed_base: int = SEED_BASE) -> Path:
    """Render drive ``index`` (seed ``seed_base + index``; cached: an existing bag is kept)."""
    from roadbev_lab.evaluation.drivebag import write_drive_bag

    path = out / f"drive_{seed_base + index}.mcap"
    if path.exists():
        return path
    speed = SPEEDS[index % len(SPEEDS)]
    rate = min(5.0, speed / spacing)
    drive = make_drive(speed, rate, frames / rate, seed_base + index)
    tmp = path.with_suffix(".tmp.mcap")
    tmp.unlink(missing_ok=True)
    write_drive_bag(tmp, drive)
    tmp.replace(path)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder of the drive bags (created)")
    parser.add_argument("--first", type=int, default=0, help="first drive index (seed SEED_BASE + index)")
    parser.add_argument("--count", type=int, default=12)
    parser.add_argument("--frames", type=int, default=12, help="camera frames per drive")
    parser.add_argument("--spacing", type=float, default=2.0, help="least distance between frames (m)")
    parser.add_argument("--seed-base", type=int, default=SEED_BASE,
                        help=f"seed of drive 0 (default {SEED_BASE}; e.g. {VALIDATION_SEED_BASE} for held-out drives)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for index in range(args.first, args.first + args.count):
        start = time.perf_counter()
        path = write_drive(args.out, index, args.frames, args.spacing, args.seed_base)
        print(f"{path} ({SPEEDS[index % len(SPEEDS)]:g} m/s) in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
