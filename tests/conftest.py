"""Shared test set-up: deterministic, denormal-free torch; paths to shared data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
RSRD = SHARED / "rsrd"

os.environ.setdefault("MPLBACKEND", "Agg")

try:  # torch is optional for the pure-numpy tests
    import torch

    torch.set_flush_denormal(True)
    torch.set_num_threads(2)
except ImportError:  # pragma: no cover
    pass


@pytest.fixture(scope="session")
def rsrd_dir() -> Path:
    if not RSRD.is_dir():
        pytest.skip(f"real RSRD metadata not found at {RSRD}")
    return RSRD


KITTI = SHARED / "realdata" / "kitti"


@pytest.fixture(scope="session")
def kitti_dir() -> Path:
    """The three real KITTI frames (``../shared/realdata/kitti``, a test set: never tune on it)."""
    if not (KITTI / "stereo_rcnn_demo" / "demo" / "lidar.bin").is_file():
        pytest.skip(f"real KITTI frames not found at {KITTI}")
    return KITTI
