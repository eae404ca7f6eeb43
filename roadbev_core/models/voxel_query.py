"""Voxel feature query: fill every voxel with the image feature at its centre's projection.

Projection goes through :func:`roadbev_core.geometry.project_voxels` (one definition of the
frames for the whole project). Two ways to read the feature map:

* ``bilinear``: sub-pixel ``grid_sample`` at the continuous projection. At this rig's geometry
  1 cm of elevation moves the right-image match by only 0.15-0.5 px, so centimetre accuracy needs
  sub-pixel sampling (``shared/design/cpu-sizing.md``).
* ``integer``: the paper's indexing, the feature cell holding the projected pixel (floor).

Voxels that project outside the image (or behind the camera) get zero features and are masked.
Lookups depend on (grid, camera, attitude, stride, eye) only and are cached; the attitude differs
per frame, so a batch carries one lookup per sample.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, ProjectedVoxels, project_voxels

__all__ = ["VoxelLookup", "batch_lookup", "query_voxels", "voxel_lookup", "window_zncc"]


class VoxelLookup(NamedTuple):
    """Where one image's feature map is read for every voxel.

    Attributes:
        coords: [Nz * Ny, Nx, 2] float32 (x, y) in grid_sample's [-1, 1] (align_corners=True).
        mask: [Nz, Ny, Nx] bool, the voxel projects inside the image.
    """

    coords: torch.Tensor
    mask: torch.Tensor


@lru_cache(maxsize=16)
def _pixel_projection(grid: GridSpec, camera: StereoCamera, attitude: Attitude, right: bool) -> ProjectedVoxels:
    """Voxel centres in one image's pixel coordinates (stride 1), shared by every feature stride."""
    return project_voxels(grid, camera, attitude, stride=1, right=right)


@lru_cache(maxsize=32)
def voxel_lookup(
    grid: GridSpec, camera: StereoCamera, attitude: Attitude, stride: int, right: bool, sampling: str
) -> VoxelLookup:
    """The (cached) lookup of ``grid``'s voxels in a feature map of ``stride`` of ``camera``'s image."""
    if sampling == "bilinear":
        # The feature coordinate is an affine function of the pixel coordinate (geometry's
        # convention: (u - (s - 1) / 2) / s), so one projection per eye serves every stride.
        pixel = _pixel_projection(grid, camera, attitude, right)
        proj = pixel._replace(
            u=(pixel.u - (stride - 1) / 2.0) / stride,
            v=(pixel.v - (stride - 1) / 2.0) / stride,
            width=-(-camera.width // stride),
            height=-(-camera.height // stride),
        )
        u, v = proj.u.astype(np.float64), proj.v.astype(np.float64)
    elif sampling == "integer":
        proj = project_voxels(grid, camera, attitude, stride=stride, right=right)
        u, v = proj.iu.astype(np.float64), proj.iv.astype(np.float64)
    else:
        raise ValueError(f"sampling must be 'bilinear' or 'integer', got {sampling!r}")
    x = u / max(proj.width - 1, 1) * 2.0 - 1.0  # [Nz, Ny, Nx]
    y = v / max(proj.height - 1, 1) * 2.0 - 1.0
    inside = proj.inside
    xy = np.stack([np.where(inside, x, 0.0), np.where(inside, y, 0.0)], axis=-1)  # [Nz, Ny, Nx, 2]
    n_z, n_y, n_x = inside.shape
    coords = torch.from_numpy(xy.reshape(n_z * n_y, n_x, 2).astype(np.float32))
    return VoxelLookup(coords=coords, mask=torch.from_numpy(inside.copy()))


def batch_lookup(
    grid: GridSpec,
    cameras: list[StereoCamera],
    attitudes: list[Attitude],
    stride: int,
    right: bool,
    sampling: str,
) -> VoxelLookup:
    """Stacked lookups of a batch: coords [B, Nz*Ny, Nx, 2], mask [B, Nz, Ny, Nx]."""
    parts = [voxel_lookup(grid, c, a, stride, right, sampling) for c, a in zip(cameras, attitudes, strict=True)]
    return VoxelLookup(torch.stack([p.coords for p in parts]), torch.stack([p.mask for p in parts]))


def query_voxels(features: torch.Tensor, lookup: VoxelLookup, sampling: str) -> torch.Tensor:
    """Voxel features of one image.

    Args:
        features: [B, C, H, W] feature map.
        lookup: batch lookup (coords [B, Nz*Ny, Nx, 2], mask [B, Nz, Ny, Nx]) on the same device.
        sampling: ``bilinear`` or ``integer`` (nearest cell of the integer indices).

    Returns:
        [B, C, Nz, Ny, Nx], zero where the mask is False.
    """
    mode = "bilinear" if sampling == "bilinear" else "nearest"
    sampled = F.grid_sample(features, lookup.coords, mode=mode, padding_mode="zeros", align_corners=True)
    b, c = features.shape[:2]
    n_z, n_y, n_x = lookup.mask.shape[1:]
    volume = sampled.view(b, c, n_z, n_y, n_x)  # [B, C, Nz, Ny, Nx]
    return volume * lookup.mask[:, None].to(volume.dtype)


def window_zncc(left: torch.Tensor, right: torch.Tensor, window: int, eps: float = 1e-3) -> torch.Tensor:
    """Zero-mean normalised cross-correlation of two voxel volumes over a BEV window per layer.

    Args:
        left, right: [B, Nz, Ny, Nx] samples (e.g. grey levels 0..255 at the voxel centres).
        window: odd BEV window size (cells); windows are cut at the grid border.
        eps: added to the variance product (grey-level units) so flat texture gives ~0.

    Returns:
        [B, Nz, Ny, Nx] in [-1, 1].
    """
    shape = left.shape
    a, b = left.flatten(0, 1)[:, None], right.flatten(0, 1)[:, None]  # [B*Nz, 1, Ny, Nx]

    def mean(t: torch.Tensor) -> torch.Tensor:
        return F.avg_pool2d(t, window, stride=1, padding=window // 2, count_include_pad=False)

    mean_a, mean_b = mean(a), mean(b)
    cov = mean(a * b) - mean_a * mean_b
    var_a = (mean(a * a) - mean_a * mean_a).clamp_min(0)
    var_b = (mean(b * b) - mean_b * mean_b).clamp_min(0)
    return (cov / torch.sqrt(var_a * var_b + eps)).view(shape)
