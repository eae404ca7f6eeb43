"""The gwcnet backend: the network's disparities become the grid's elevations as the image-view
protocol says (a known plane comes back), and bad checkpoints, frames and options are refused."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from roadbev_core.backends import BackendError, create
from roadbev_core.backends.gwcnet import GwcNetBackend, gwcnet_inputs, search_window
from roadbev_core.checkpoint import TrainingEnvelope, save_baseline
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Frame, FrameError
from roadbev_core.geometry import Attitude, ray_terms
from roadbev_core.models.gwcnet import GwcNetConfig, GwcNetLite

CAMERA = StereoCamera.rsrd_half()
GRID = GridSpec()
ATTITUDE = Attitude(0.0, math.radians(16.0))
TINY = GwcNetConfig(max_disparity=48, features=16, groups=4, volume_channels=4)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    envelope = TrainingEnvelope(grid=GRID, fx_px=(CAMERA.fx, CAMERA.fx), width_px=CAMERA.width,
                                baseline_m=(CAMERA.baseline, CAMERA.baseline))
    return save_baseline(tmp_path_factory.mktemp("gwc") / "tiny.pt", "gwcnet", GwcNetLite(TINY).eval(), envelope)


def _frame(height: int = CAMERA.height, right: bool = True) -> Frame:
    rng = np.random.default_rng(0)
    left = rng.integers(0, 255, (height, CAMERA.width, 3), dtype=np.uint8)
    return Frame(left=left, right=left.copy() if right else None, camera=CAMERA, attitude=ATTITUDE, stamp_ns=1)


class _PlaneDisparity(nn.Module):
    """Stands in for the network: the disparity of the plane z = height over the search window."""

    def __init__(self, height: float, first: int, rows: np.ndarray, cols: np.ndarray) -> None:
        super().__init__()
        ray = ray_terms(CAMERA, ATTITUDE, rows, cols).rays()  # [h, w, 3]
        with np.errstate(divide="ignore"):
            depth = (height - GRID.base_height) / ray[..., 2]
        disparity = np.where(depth > 0, CAMERA.fx * CAMERA.baseline / depth, 0.0) - first
        self.disparity = torch.from_numpy(disparity.astype(np.float32))

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = torch.zeros(left.shape[0], left.shape[2], left.shape[3])
        h, w = self.disparity.shape
        out[:, :h, :w] = self.disparity
        return out, torch.full_like(out, 0.1)


def test_the_disparities_of_a_plane_come_back_as_its_height(checkpoint: Path) -> None:
    backend = GwcNetBackend(GRID, checkpoint=checkpoint)
    window = search_window(GRID, CAMERA, ATTITUDE)
    rows, cols = np.arange(window.top, window.bottom), np.arange(window.left, window.right)
    backend.model = _PlaneDisparity(0.04, window.min_disparity, rows, cols)  # type: ignore[assignment]
    estimate = backend.estimate(_frame())
    seen = np.isfinite(estimate.elevation)
    assert seen.mean() > 0.9  # cells of the near corners fall outside the image
    np.testing.assert_allclose(estimate.elevation[seen], 0.04, atol=2e-4)
    # the sigma: 0.1 px of disparity at each cell's range, no spread on a plane
    assert np.all(estimate.uncertainty[seen] > 0) and np.all(estimate.uncertainty[seen] < 0.02)
    near, far = estimate.uncertainty[-1][seen[-1]].mean(), estimate.uncertainty[0][seen[0]].mean()
    assert far > 2.5 * near  # sigma_h grows with the range (7.1 m against 2.2 m)


def test_a_trained_shape_network_answers_the_grid(checkpoint: Path) -> None:
    backend = create("gwcnet", GRID, checkpoint=str(checkpoint))
    estimate = backend.estimate(_frame())
    assert estimate.elevation.shape == estimate.uncertainty.shape == GRID.shape
    assert set(estimate.timings_ms) >= {"preprocess", "network", "projection", "post"}


def test_inputs_cover_the_window_padded_to_the_stride() -> None:
    window = search_window(GRID, CAMERA, ATTITUDE)
    frame = _frame()
    left, right = gwcnet_inputs(frame, window)
    assert left.shape[0] % GwcNetLite.stride == 0 and left.shape[1] % GwcNetLite.stride == 0
    h, w = window.bottom - window.top, window.right - window.left
    np.testing.assert_array_equal(left[:h, :w], frame.left[window.top:window.bottom, window.left:window.right])
    assert frame.right is not None
    u = window.left + 100  # the right image moved by the first disparity
    np.testing.assert_array_equal(right[:h, 100], frame.right[window.top:window.bottom, u - window.min_disparity])


def test_bad_checkpoints_options_and_frames_are_refused(checkpoint: Path, tmp_path: Path) -> None:
    with pytest.raises(BackendError, match="not found"):
        create("gwcnet", GRID, checkpoint=str(tmp_path / "missing.pt"))
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a checkpoint")
    with pytest.raises(BackendError, match="unreadable or corrupt"):
        create("gwcnet", GRID, checkpoint=str(corrupt))
    other = tmp_path / "roadbev.pt"
    torch.save({"format": "roadbev-checkpoint/1"}, other)
    with pytest.raises(BackendError, match="not a GwcNet-lite checkpoint"):
        create("gwcnet", GRID, checkpoint=str(other))
    with pytest.raises(BackendError, match="unknown option"):
        create("gwcnet", GRID, checkpoint=str(checkpoint), block_size=5)
    with pytest.raises(BackendError, match="outside what"):
        create("gwcnet", GridSpec(x_min=8.01, x_max=12.0), checkpoint=str(checkpoint))
    backend = create("gwcnet", GRID, checkpoint=str(checkpoint))
    with pytest.raises(FrameError, match="right image"):
        backend.estimate(_frame(right=False))


def test_max_sigma_leaves_out_the_wide_matches(checkpoint: Path) -> None:
    window = search_window(GRID, CAMERA, ATTITUDE)
    rows, cols = np.arange(window.top, window.bottom), np.arange(window.left, window.right)
    answered = {}
    for limit in (0.0, 0.2, 0.05):  # off; wider than the stand-in's 0.1 px; narrower
        backend = GwcNetBackend(GRID, checkpoint=checkpoint, max_sigma_px=limit)
        backend.model = _PlaneDisparity(0.0, window.min_disparity, rows, cols)  # type: ignore[assignment]
        answered[limit] = int(np.isfinite(backend.estimate(_frame()).elevation).sum())
    assert answered[0.0] == answered[0.2] > 0 and answered[0.05] == 0
    with pytest.raises(BackendError, match="max_sigma_px"):
        create("gwcnet", GRID, checkpoint=str(checkpoint), max_sigma_px=-1.0)
