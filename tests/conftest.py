"""Shared test set-up: deterministic, denormal-free torch; paths to shared data."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

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


@pytest.fixture
def saved_figures(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Every matplotlib Figure saved during the test, drawn first (artists laid out), in order:
    the figure functions return a path, and a test that looks at the artists reads them here."""
    from matplotlib.figure import Figure

    saved: list[Any] = []
    original = Figure.savefig

    def keep(fig: Figure, *args: Any, **kwargs: Any) -> None:
        fig.canvas.draw()
        saved.append(fig)
        original(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    return saved
