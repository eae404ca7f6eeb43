"""Voxel feature query: fill every voxel with the image feature at its centre's projection.

Projection goes through :func:`roadbev_core.geometry.project_voxels` (one definition of the
frames for the whole project). Two ways to read the feature map:

* ``bilinear``: sub-pixel ``grid_sample`` at the continuous projection. At this rig's geometry
  1 cm of elevation moves the right-image match by only 0.15-0.5 px, so centimetre accuracy needs
  sub-pixel sampling (integer sampling at 1/2 feature resolution resolves elevation only in 4-13 cm steps).
* ``integer``: the paper's indexing, the feature cell holding the projected pixel (floor).

Voxels that project outside the image (or behind the camera) get zero features and are masked.
Lookups depend on (grid, camera, attitude, stride, eye) only and are cached; the attitude differs
per frame, so a batch carries one lookup per sample.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple, cast

import numpy as np
import torch
import torch.nn.functional as F

from roadbev_core.box_filter import box_mean
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, project_voxels
from roadbev_core.image_sampling import sample_coordinates

__all__ = ["VoxelLookup", "batch_lookup", "gather_voxels", "query_voxels", "voxel_lookup", "window_zncc"]


class VoxelLookup(NamedTuple):
    """Where one image's feature map is read for every voxel.

    Attributes:
        coords: [Nz * Ny, Nx, 2] float32 (x, y) in grid_sample's [-1, 1] (align_corners=True).
        mask: [Nz, Ny, Nx] bool, the voxel projects inside the image.
    """

    coords: torch.Tensor
    mask: torch.Tensor


@lru_cache(maxsize=32)
def _bilinear_lookups(grid: GridSpec, camera: StereoCamera, attitude: Attitude, stride: int) -> tuple[VoxelLookup, ...]:
    """The left and right bilinear lookups of ``grid`` at ``stride``, from one projection (cached)."""
    # Float32 separable projection (the per-frame hot path: a new attitude every frame), both
    # images at once. The feature coordinate is an affine function of the pixel coordinate
    # (geometry's convention: (u - (s - 1) / 2) / s), hence of the normalised image coordinate c:
    # xy = k c + k - (s - 1) / (s (F - 1)) - 1 with k = (S - 1) / (s (F - 1)), S the image and F
    # the feature map size; one multiply-add per coordinate (none at stride 1, where xy = c).
    heights = torch.from_numpy(grid.z_centres()).float()[:, None, None]
    x, y = torch.from_numpy(grid.x_centres()), torch.from_numpy(grid.y_centres())
    projected = sample_coordinates(x, y, heights, camera, attitude, grid.base_height)
    inside = projected.inside(camera)  # [2, Nz, Ny, Nx]
    coords = projected.coords  # [2, Nz, Ny, Nx, 2] normalised over the whole image
    if stride != 1:
        size = torch.tensor([camera.width, camera.height], dtype=torch.float64)
        span = (-(-size // stride) - 1.0).clamp_min(1.0)  # F - 1 of the feature map's (width, height)
        k = (size - 1.0) / (stride * span)
        offset = k - (stride - 1) / (stride * span) - 1.0
        coords = torch.addcmul(offset.float(), coords, k.float())
    xy = torch.where(inside[..., None], coords, torch.zeros((), dtype=coords.dtype))
    n_z, n_y, n_x = inside.shape[1:]
    return tuple(VoxelLookup(coords=xy[eye].reshape(n_z * n_y, n_x, 2), mask=inside[eye]) for eye in (0, 1))


def voxel_lookup(
    grid: GridSpec, camera: StereoCamera, attitude: Attitude, stride: int, right: bool, sampling: str
) -> VoxelLookup:
    """The (cached) lookup of ``grid``'s voxels in a feature map of ``stride`` of ``camera``'s image."""
    if sampling == "bilinear":
        return _bilinear_lookups(grid, camera, attitude, stride)[int(right)]
    return _integer_lookup(grid, camera, attitude, stride, right, sampling)


@lru_cache(maxsize=32)
def _integer_lookup(
    grid: GridSpec, camera: StereoCamera, attitude: Attitude, stride: int, right: bool, sampling: str
) -> VoxelLookup:
    if sampling != "integer":
        raise ValueError(f"sampling must be 'bilinear' or 'integer', got {sampling!r}")
    proj = project_voxels(grid, camera, attitude, stride=stride, right=right)
    u, v = proj.iu.astype(np.float64), proj.iv.astype(np.float64)
    x_norm = u / max(proj.width - 1, 1) * 2.0 - 1.0  # [Nz, Ny, Nx]
    y_norm = v / max(proj.height - 1, 1) * 2.0 - 1.0
    seen = proj.inside
    xy_int = np.stack([np.where(seen, x_norm, 0.0), np.where(seen, y_norm, 0.0)], axis=-1)  # [Nz, Ny, Nx, 2]
    n_z, n_y, n_x = seen.shape
    coords = torch.from_numpy(xy_int.reshape(n_z * n_y, n_x, 2).astype(np.float32))
    return VoxelLookup(coords=coords, mask=torch.from_numpy(seen.copy()))


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


def query_voxels(features: torch.Tensor, lookup: VoxelLookup, sampling: str, *, gather: bool = False) -> torch.Tensor:
    """Voxel features of one image.

    Args:
        features: [B, C, H, W] feature map.
        lookup: batch lookup (coords [B, Nz*Ny, Nx, 2], mask [B, Nz, Ny, Nx]) on the same device.
        sampling: ``bilinear`` or ``integer`` (nearest cell of the integer indices).
        gather: read the taps with explicit gathers (:func:`gather_voxels`) instead of grid_sample.

    Returns:
        [B, C, Nz, Ny, Nx], zero where the mask is False.
    """
    if gather:
        return gather_voxels(features, lookup, sampling)
    mode = "bilinear" if sampling == "bilinear" else "nearest"
    sampled = F.grid_sample(features, lookup.coords, mode=mode, padding_mode="zeros", align_corners=True)
    b, c = features.shape[:2]
    n_z, n_y, n_x = lookup.mask.shape[1:]
    volume = sampled.view(b, c, n_z, n_y, n_x)  # [B, C, Nz, Ny, Nx]
    return volume * lookup.mask[:, None].to(volume.dtype)


def gather_voxels(features: torch.Tensor, lookup: VoxelLookup, sampling: str) -> torch.Tensor:
    """:func:`query_voxels` as explicit gathers of the 4 bilinear taps (1 for ``integer``).

    The same numbers as ``grid_sample(align_corners=True, padding_mode="zeros")``, written with
    Floor / Gather / Mul only: what the ONNX export traces, because ONNX Runtime's GridSample
    kernel is several times slower than torch's on a CPU, while row gathers of the
    channels-last feature map are plain copies.

    Args / Returns: as :func:`query_voxels`.
    """
    b, c, h, w = features.shape
    n_z, n_y, n_x = lookup.mask.shape[1:]
    xy = lookup.coords.reshape(b, n_z * n_y * n_x, 2)  # [B, N, 2] in [-1, 1]
    px = (xy[..., 0] + 1.0) * (0.5 * (w - 1))  # [B, N] pixel coordinates of the feature map
    py = (xy[..., 1] + 1.0) * (0.5 * (h - 1))
    rows = features.permute(0, 2, 3, 1).reshape(b * h * w, c)  # [B*H*W, C] channels last
    base = (torch.arange(b, device=features.device) * (h * w))[:, None]  # [B, 1] first row of each sample
    taps: tuple[tuple[torch.Tensor, torch.Tensor, torch.Tensor], ...]  # (x, y, weight) [B, N] each
    if sampling == "bilinear":
        x0, y0 = torch.floor(px), torch.floor(py)
        fx, fy = px - x0, py - y0
        taps = ((x0, y0, (1.0 - fx) * (1.0 - fy)), (x0 + 1.0, y0, fx * (1.0 - fy)),
                (x0, y0 + 1.0, (1.0 - fx) * fy), (x0 + 1.0, y0 + 1.0, fx * fy))
    else:
        taps = ((torch.round(px), torch.round(py), torch.ones_like(px)),)
    out = torch.zeros(b, n_z * n_y * n_x, c, dtype=features.dtype, device=features.device)
    for tx, ty, weight in taps:
        valid = (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)  # zero padding outside
        index = ty.clamp(0, h - 1) * w + tx.clamp(0, w - 1)  # [B, N]
        picked = rows[(index.long() + base).reshape(-1)].reshape(b, -1, c)  # [B, N, C]
        out = out + picked * (weight * valid.to(weight.dtype))[..., None]
    volume = out.permute(0, 2, 1).reshape(b, c, n_z, n_y, n_x)  # [B, C, Nz, Ny, Nx]
    return volume * lookup.mask[:, None].to(volume.dtype)


def window_zncc(
    left: torch.Tensor, right: torch.Tensor, window: int, eps: float = 1e-3, *, subsamples: int = 1
) -> torch.Tensor:
    """Zero-mean normalised cross-correlation of two voxel volumes over a BEV window per layer.

    Args:
        left, right: [B, Nz, n * Ny, n * Nx] samples (e.g. grey levels 0..255 at the voxel
            centres of a grid ``n = subsamples`` times finer than the output).
        window: odd BEV window size in output cells; windows are cut at the grid border.
        eps: added to the variance product (grey-level units) so flat texture gives ~0.
        subsamples: n, fine samples per output cell side; all n * n * window * window samples
            of a window enter one correlation.

    Returns:
        [B, Nz, Ny, Nx] in [-1, 1].
    """
    n = subsamples
    b, n_z, fine_y, fine_x = left.shape
    if fine_y % n or fine_x % n:
        raise ValueError(f"a {fine_y} x {fine_x} sample grid does not split into {n} x {n} cells")
    a, c = left.reshape(b * n_z, fine_y, fine_x), right.reshape(b * n_z, fine_y, fine_x)
    moments = torch.stack((a, c, a * a, c * c, a * c)).reshape(5 * b * n_z, fine_y, fine_x)
    if n > 1:  # per-cell means of the n x n samples: one pooling op (an ONNX engine ran the
        # equivalent n*n strided slices with a reference kernel); the same sums in the same order
        moments = F.avg_pool2d(moments[None], n, n)[0]
    # Window means of equal-sized cells = the mean over all the window's samples.
    means = box_mean(moments.float().contiguous(), window)  # [5 * B * Nz, Ny, Nx]
    mean_a, mean_c, mean_aa, mean_cc, mean_ac = means.reshape(5, b * n_z, fine_y // n, fine_x // n)
    cov = mean_ac - mean_a * mean_c
    var_a = (mean_aa - mean_a * mean_a).clamp_min(0)
    var_c = (mean_cc - mean_c * mean_c).clamp_min(0)
    return cast("torch.Tensor", (cov / torch.sqrt(var_a * var_c + eps)).view(b, n_z, fine_y // n, fine_x // n))
