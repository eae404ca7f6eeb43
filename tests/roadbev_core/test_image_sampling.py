"""grid_sample coordinates of road-frame samples agree with the geometry module's projection."""

from __future__ import annotations

import numpy as np
import torch

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, project_voxels
from roadbev_core.image_sampling import sample_coordinates

CAMERA = StereoCamera.rsrd_half()
ATTITUDE = Attitude.from_degrees(-0.6, 18.9)


def test_separable_projection_matches_project_voxels_in_both_images() -> None:
    grid = GridSpec().scaled(2)
    heights = torch.from_numpy(grid.z_centres()).float()[:, None, None]
    x, y = torch.from_numpy(grid.x_centres()), torch.from_numpy(grid.y_centres())
    projected = sample_coordinates(x, y, heights, CAMERA, ATTITUDE, grid.base_height)
    assert projected.coords.shape == (2, grid.n_z, grid.n_rows, grid.n_cols, 2)
    for eye, right in ((0, False), (1, True)):
        reference = project_voxels(grid, CAMERA, ATTITUDE, right=right)
        pixels = (projected.coords[eye] + 1.0) * 0.5 * torch.tensor([CAMERA.width - 1.0, CAMERA.height - 1.0])
        np.testing.assert_allclose(pixels[..., 0].numpy(), reference.u, atol=2e-3)
        np.testing.assert_allclose(pixels[..., 1].numpy(), reference.v, atol=2e-3)
        assert np.array_equal(projected.inside(CAMERA)[eye].numpy(), reference.inside)
    assert bool((projected.inv_depth > 0).all())
    # a surface [K, Rs, Cs] is the same as the planes it is made of
    surface = heights.expand(-1, grid.n_rows, grid.n_cols).contiguous()
    again = sample_coordinates(x, y, surface, CAMERA, ATTITUDE, grid.base_height)
    torch.testing.assert_close(again.coords, projected.coords)
