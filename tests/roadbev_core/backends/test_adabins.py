"""The adabins backend: the network's depths become the grid's elevations as the image-view
protocol says (a known plane comes back), and bad checkpoints, frames and options are refused."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from roadbev_core.backends import BackendError, create
from roadbev_core.backends.adabins import AdaBinsBackend, depth_pixels, grid_window
from roadbev_core.checkpoint import TrainingEnvelope, save_baseline
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Frame, FrameError
from roadbev_core.geometry import Attitude, ray_terms
from roadbev_core.models.adabins import AdaBinsConfig, AdaBinsLite

CAMERA = StereoCamera.rsrd_half()
GRID = GridSpec()
ATTITUDE = Attitude(0.0, math.radians(16.0))
SMALL = AdaBinsConfig(channels=8, n_bins=16, embedding=16, heads=2, layers=1, queries=8)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    envelope = TrainingEnvelope(grid=GRID, fx_px=(CAMERA.fx, CAMERA.fx), width_px=CAMERA.width, baseline_m=(0.0, 0.0))
    return save_baseline(tmp_path_factory.mktemp("ada") / "small.pt", "adabins", AdaBinsLite(SMALL).eval(), envelope)


def _frame(camera: StereoCamera = CAMERA) -> Frame:
    left = np.random.default_rng(0).integers(0, 255, (camera.height, camera.width, 3), dtype=np.uint8)
    return Frame(left=left, right=None, camera=camera, attitude=ATTITUDE, stamp_ns=1)


class _PlaneDepth(nn.Module):
    """Stands in for the network: the depth of the plane z = height at its output pixels."""

    def __init__(self, height: float) -> None:
        super().__init__()
        self.config = SMALL
        rows, cols = depth_pixels(SMALL, CAMERA)
        ray = ray_terms(CAMERA, ATTITUDE, rows, cols).rays()  # [h, w, 3]
        with np.errstate(divide="ignore"):
            depth = (height - GRID.base_height) / ray[..., 2]
        self.depth = torch.from_numpy(np.where(depth > 0, depth, 50.0).astype(np.float32))

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.depth[None], torch.full_like(self.depth, 0.05)[None], torch.zeros(1, SMALL.n_bins)


def test_the_depths_of_a_plane_come_back_as_its_height(checkpoint: Path) -> None:
    backend = AdaBinsBackend(GRID, checkpoint=checkpoint)
    backend.model = _PlaneDepth(-0.03)  # type: ignore[assignment]
    estimate = backend.estimate(_frame())
    seen = np.isfinite(estimate.elevation)
    assert seen.mean() > 0.9  # cells of the near corners fall outside the image
    # the depth map is resampled from a quarter of the image's size: a plane's depth is not
    # linear in the pixel, so it comes back to within a millimetre
    np.testing.assert_allclose(estimate.elevation[seen], -0.03, atol=1e-3)
    near, far = estimate.uncertainty[-1][seen[-1]].mean(), estimate.uncertainty[0][seen[0]].mean()
    assert 0 < far < near  # 5 cm of depth is a smaller height error where the ray is flatter


def test_the_network_answers_the_grid_and_needs_no_right_image(checkpoint: Path) -> None:
    backend = create("adabins", GRID, checkpoint=str(checkpoint))
    assert not backend.needs_stereo
    estimate = backend.estimate(_frame())
    assert estimate.elevation.shape == estimate.uncertainty.shape == GRID.shape


def test_the_window_is_the_rows_and_columns_that_see_the_grid() -> None:
    rows, cols = grid_window(GRID, CAMERA, ATTITUDE)
    assert 0 <= rows.start < rows.stop <= CAMERA.height and 0 <= cols.start < cols.stop <= CAMERA.width
    assert rows.stop - rows.start > 200 and cols.stop - cols.start > 600


def test_bad_checkpoints_options_and_rigs_are_refused(checkpoint: Path, tmp_path: Path) -> None:
    with pytest.raises(BackendError, match="not found"):
        create("adabins", GRID, checkpoint=str(tmp_path / "missing.pt"))
    gwc = tmp_path / "gwc.pt"
    torch.save({"format": "roadbev-gwcnet-checkpoint/1"}, gwc)
    with pytest.raises(BackendError, match="not an AdaBins-lite checkpoint"):
        create("adabins", GRID, checkpoint=str(gwc))
    with pytest.raises(BackendError, match="unknown option"):
        create("adabins", GRID, checkpoint=str(checkpoint), runtime="openvino")
    backend = create("adabins", GRID, checkpoint=str(checkpoint))
    with pytest.raises(FrameError, match="rig is outside"):
        backend.estimate(_frame(replace(CAMERA, fx=2.0 * CAMERA.fx, fy=2.0 * CAMERA.fy)))  # a longer lens
