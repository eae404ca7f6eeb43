"""Training drives: bags the training data path reads, frames spaced along the road, cached."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.training_drives import SEED_BASE, SPEEDS, write_drive
from roadbev_lab.evaluation.evalbag import bag_frames
from roadbev_lab.training.datasets import LabelledFrames


def test_a_training_drive_is_labelled_spaced_and_cached(tmp_path: Path) -> None:
    path = write_drive(tmp_path, 0, frames=2, spacing=2.0)
    assert path.name == f"drive_{SEED_BASE}.mcap" and SPEEDS[0] == 5.0
    grid, frames = bag_frames(path)
    data = LabelledFrames(grid, frames)  # what `roadbev train --bag` builds
    assert len(data) == 2
    (first, truth), (second, _) = data[0], data[1]
    # 5 m/s with frames at least 2 m apart: 2.5 Hz
    assert (second.stamp_ns - first.stamp_ns) == 400_000_000
    assert truth.shape == grid.shape and np.isfinite(truth).mean() > 0.5
    assert first.right is not None and abs(first.attitude.pitch) > 0.1  # the IMU's attitude, not zero
    stamp = path.stat().st_mtime_ns
    assert write_drive(tmp_path, 0, frames=2, spacing=2.0) == path and path.stat().st_mtime_ns == stamp
