"""RoadBEV-mono and RoadBEV-stereo (paper section 4) as one module with a ``kind`` switch.

backbone (shared by both eyes) -> pyramid fusion (C channels at 1/4 mono, 1/2 stereo) -> voxel
query on the internal grid -> head -> class logits [B, Nc, n_rows, n_cols] on the output grid.

* mono: voxel features [B, C, Nz, Ny, Nx] reshaped to BEV [B, C*Nz, Ny, Nx], a 2-D head to Nc
  logits per cell.
* stereo: left x right voxel features (point-wise product, paper eq. 2; difference as the
  ablation) kept 4-D, a 3-D head down to one channel, the proposal axis interpolated Nz -> Nc.

Coarser internal grids (``ModelConfig.grid_factor`` / ``z_factor``) are upsampled to the output
grid, so callers always see the :class:`GridSpec` they asked for.
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple, Protocol

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import Attitude
from roadbev_core.models.efficientnet import EfficientNetFeatures, input_normalisation
from roadbev_core.models.fpn import PyramidFusion
from roadbev_core.models.heads import MonoHead, StereoHead
from roadbev_core.models.loss import soft_argmin
from roadbev_core.models.presets import ModelConfig
from roadbev_core.models.voxel_query import VoxelLookup, batch_lookup, query_voxels, window_zncc

__all__ = [
    "ModelInputError",
    "Prediction",
    "RoadBEV",
    "VoxelGeometry",
    "needs_full_grey",
    "prepare_grey",
    "prepare_image",
    "voxel_geometry",
]


class ModelInputError(RoadbevError, ValueError):
    """Images or calibration that do not fit the model (size, missing right image)."""


class Prediction(NamedTuple):
    """elevation, uncertainty [B, R, C] metres; observed [B, R, C] bool (voxels seen by the camera)."""

    elevation: torch.Tensor
    uncertainty: torch.Tensor
    observed: torch.Tensor


class InputSize(Protocol):
    """A network's input size (a RoadBEV :class:`ModelConfig`, an image-view baseline's configuration)."""

    @property
    def input_width(self) -> int: ...

    @property
    def input_height(self) -> int: ...


def prepare_image(image: np.ndarray, config: InputSize) -> np.ndarray:
    """RGB (or grey) uint8 [H, W(, 3)] -> uint8 [3, h, w] at the model's input size (area resize)."""
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    size = (config.input_width, config.input_height)
    if image.shape[1::-1] != size:
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(image.transpose(2, 0, 1))


def needs_full_grey(config: ModelConfig) -> bool:
    """Whether the model's forward takes the full-resolution grey frames (``grey``)."""
    return config.kind == "stereo" and config.photometric and config.zncc_full_resolution


def prepare_grey(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """RGB (or grey) uint8 [H, W(, 3)] left and right -> uint8 [2, H, W] grey at their own size."""
    planes = [image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in (left, right)]
    if planes[0].shape != planes[1].shape:
        raise ModelInputError(f"left and right images differ in size: {planes[0].shape} vs {planes[1].shape}")
    return np.stack(planes)


class VoxelGeometry(NamedTuple):
    """Everything a batch's rigs and attitudes give the network: where each voxel is read.

    Attributes:
        left, right: lookups in the feature map of the left / right image (coords
            [B, Nz*Ny, Nx, 2], mask [B, Nz, Ny, Nx] on the internal grid); ``right`` None for mono.
        fine_left, fine_right: lookups of the photometric channel's grey frames on the
            ``zncc_subsamples`` times finer grid (None without ``ModelConfig.photometric``).
    """

    left: VoxelLookup
    right: VoxelLookup | None = None
    fine_left: VoxelLookup | None = None
    fine_right: VoxelLookup | None = None

    def to(self, device: torch.device | str) -> VoxelGeometry:
        """The same lookups on ``device``."""
        def move(look: VoxelLookup | None) -> VoxelLookup | None:
            return None if look is None else VoxelLookup(look.coords.to(device), look.mask.to(device))

        left = move(self.left)
        assert left is not None
        return VoxelGeometry(left, move(self.right), move(self.fine_left), move(self.fine_right))


def voxel_geometry(
    config: ModelConfig, grid: GridSpec, cameras: list[StereoCamera], attitudes: list[Attitude]
) -> VoxelGeometry:
    """The voxel lookups of a batch for a ``config`` model on output ``grid`` (CPU tensors).

    Depends on the rigs and attitudes only, never on the images: the part of the network that
    ``roadbev export`` leaves outside the ONNX graph (its inputs), so one file serves any rig.
    Lookups are cached per (rig, attitude) by :func:`voxel_lookup`.

    Args:
        config, grid: the model and its output grid.
        cameras: B rigs of the ORIGINAL images.
        attitudes: B camera attitudes.
    """
    inner = config.internal_grid(grid)
    cams = [c.resized(config.input_width, config.input_height) for c in cameras]
    stereo = config.kind == "stereo"
    left = batch_lookup(inner, cams, attitudes, config.feature_stride, False, config.sampling)
    right = batch_lookup(inner, cams, attitudes, config.feature_stride, True, config.sampling) if stereo else None
    if not (stereo and config.photometric):
        return VoxelGeometry(left, right)
    fine = replace(inner, resolution=inner.resolution / config.zncc_subsamples)  # n x n samples per cell
    rigs = cameras if config.zncc_full_resolution else cams
    fine_left, fine_right = (batch_lookup(fine, rigs, attitudes, 1, eye, "bilinear") for eye in (False, True))
    return VoxelGeometry(left, right, fine_left, fine_right)


class RoadBEV(nn.Module):
    """The RoadBEV network for one output grid."""

    # buffers (register_buffer), declared for the type checker
    centres: torch.Tensor  # [Nc] class-centre heights (m)
    mean: torch.Tensor  # [1, 3, 1, 1] input normalisation
    std: torch.Tensor  # [1, 3, 1, 1]

    def __init__(self, config: ModelConfig, grid: GridSpec) -> None:
        super().__init__()
        self.config = config
        self.grid = grid
        self.inner = config.internal_grid(grid)
        self.backbone = EfficientNetFeatures(config.backbone)
        self.fusion = PyramidFusion(self.backbone.out_channels, self.backbone.strides,
                                    config.channels, config.feature_stride)
        if config.kind == "stereo":
            self.head: nn.Module = StereoHead(config.channels + int(config.photometric), config.head_width)
        else:
            self.head = MonoHead(config.channels * self.inner.n_z, config.head_width, grid.n_classes)
        self.register_buffer("centres", torch.tensor(grid.class_centres(), dtype=torch.float32), persistent=False)
        mean, std = input_normalisation(config.backbone)  # what pretrained weights of the variant expect
        self.register_buffer("mean", torch.tensor(mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(std).view(1, 3, 1, 1), persistent=False)

    @property
    def is_stereo(self) -> bool:
        return self.config.kind == "stereo"

    def geometry(self, cameras: list[StereoCamera], attitudes: list[Attitude]) -> VoxelGeometry:
        """Where this batch's voxels are read (:func:`voxel_geometry` for the model's grid)."""
        geometry = voxel_geometry(self.config, self.grid, cameras, attitudes)
        return geometry.to(self.centres.device)  # (a buffer: on the model's device)

    def forward(
        self,
        left: torch.Tensor,
        right: torch.Tensor | None,
        cameras: list[StereoCamera],
        attitudes: list[Attitude],
        grey: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Class logits of a batch.

        Args:
            left, right: [B, 3, h, w] uint8 (or float in [0, 1]) at the model's input size;
                ``right`` is required for stereo and ignored for mono.
            cameras: B rigs of the ORIGINAL images (rescaled to the input size here).
            attitudes: B camera attitudes.
            grey: [B, 2, H, W] uint8 grey left / right frames at the ORIGINAL size
                (:func:`prepare_grey`); required when :func:`needs_full_grey`, ignored otherwise.

        Returns:
            logits [B, Nc, n_rows, n_cols] on the output grid, observed [B, n_rows, n_cols] bool.
        """
        cfg = self.config
        b = left.shape[0]
        if left.shape[1:] != (3, cfg.input_height, cfg.input_width):
            raise ModelInputError(
                f"images must be [B, 3, {cfg.input_height}, {cfg.input_width}], got {tuple(left.shape)}"
            )
        if len(cameras) != b or len(attitudes) != b:
            raise ModelInputError(f"need {b} cameras and attitudes, got {len(cameras)} and {len(attitudes)}")
        if self.is_stereo and (right is None or right.shape != left.shape):
            raise ModelInputError("RoadBEV-stereo needs a right image of the left image's shape")
        if needs_full_grey(cfg):
            size = (cameras[0].height, cameras[0].width)
            if grey is None or grey.shape != (b, 2, *size) or any((c.height, c.width) != size for c in cameras):
                raise ModelInputError(
                    f"this model reads the full-resolution grey frames: grey must be [B, 2, {size[0]}, {size[1]}] "
                    f"(prepare_grey), got {None if grey is None else tuple(grey.shape)}"
                )
        return self.logits(left, right, grey, self.geometry(cameras, attitudes))

    def logits(
        self, left: torch.Tensor, right: torch.Tensor | None, grey: torch.Tensor | None, geometry: VoxelGeometry,
        *, gather: bool = False,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`forward` after the geometry: tensors in, tensors out (what ``roadbev export`` traces).

        Args:
            left, right, grey: as :meth:`forward` (checked there).
            geometry: the batch's :class:`VoxelGeometry` on the model's device.
            gather: read voxel features with explicit gathers (``voxel_query.gather_voxels``, the
                ONNX graph's way) instead of grid_sample; the same numbers.

        Returns:
            logits [B, Nc, n_rows, n_cols], observed [B, n_rows, n_cols] bool.
        """
        cfg = self.config
        b = left.shape[0]
        images = torch.cat([left, right]) if self.is_stereo and right is not None else left  # [B or 2B, 3, h, w]
        x = images.float() / 255.0 if images.dtype == torch.uint8 else images.float()
        fused = self.fusion(self.backbone((x - self.mean) / self.std), x.shape[-2:])  # [., C, h/s, w/s]
        look_l = geometry.left
        vox_l = query_voxels(fused[:b], look_l, cfg.sampling, gather=gather)  # [B, C, Nz, Ny, Nx]
        grid = self.grid
        pad_rows, pad_cols = cfg.padding(grid)
        size = (grid.n_rows + pad_rows, grid.n_cols + pad_cols)  # output cells covered by self.inner
        if self.is_stereo:
            look_r = geometry.right
            if look_r is None:
                raise ModelInputError("RoadBEV-stereo needs the right image's voxel lookup")
            vox_r = query_voxels(fused[b:], look_r, cfg.sampling, gather=gather)
            volume = vox_l * vox_r if cfg.volume == "product" else vox_l - vox_r
            if cfg.photometric:  # [B, C + 1, Nz, Ny, Nx]: + the photometric ZNCC channel (ModelConfig)
                seen_both = look_l.mask & look_r.mask  # [B, Nz, Ny, Nx]
                photometric = self._photometric_from(x, grey, geometry, gather=gather) * seen_both
                volume = torch.cat([volume, photometric[:, None]], dim=1)
            score = self.head(volume)  # [B, Nz, Ny, Nx]
            logits = F.interpolate(score[:, None], size=(grid.n_classes, *size),
                                   mode="trilinear", align_corners=False)[:, 0]
            seen = (look_l.mask & look_r.mask).any(dim=1)  # [B, Ny, Nx]
        else:
            logits = self.head(vox_l.flatten(1, 2))  # [B, Nc, Ny, Nx]
            if logits.shape[-2:] != size:
                logits = F.interpolate(logits, size=size, mode="bilinear", align_corners=False)
            seen = look_l.mask.any(dim=1)
        observed = F.interpolate(seen[:, None].float(), size=size, mode="nearest")[:, 0] > 0.5
        # The padding rows / columns lie beyond x_max / y_max, i.e. before row 0 / column 0.
        return logits[..., pad_rows:, pad_cols:], observed[..., pad_rows:, pad_cols:]

    def _photometric(
        self, images: torch.Tensor, grey: torch.Tensor | None, cameras: list[StereoCamera], attitudes: list[Attitude]
    ) -> torch.Tensor:
        """[B, Nz, Ny, Nx] ZNCC of the grey left / right images at the voxels (ModelConfig.photometric)."""
        return self._photometric_from(images, grey, self.geometry(cameras, attitudes))

    def _photometric_from(
        self, images: torch.Tensor, grey: torch.Tensor | None, geometry: VoxelGeometry, *, gather: bool = False
    ) -> torch.Tensor:
        """[B, Nz, Ny, Nx] ZNCC of the grey left / right images at the voxels (ModelConfig.photometric).

        Reads the full-resolution ``grey`` [B, 2, H, W] or, without ``zncc_full_resolution``, the
        mean of the model inputs ``images`` [2B, 3, h, w]; ``zncc_subsamples`` points per cell side
        (``geometry.fine_left`` / ``fine_right``). Voxels outside an image are the caller's to mask.
        """
        cfg = self.config
        if geometry.fine_left is None or geometry.fine_right is None:
            raise ModelInputError("the photometric channel needs the fine voxel lookups")
        if cfg.zncc_full_resolution:
            if grey is None:
                raise ModelInputError("this model reads the full-resolution grey frames (grey)")
            planes = grey.transpose(0, 1).float()  # [2, B, H, W]
            left_grey, right_grey = planes[0][:, None], planes[1][:, None]
        else:
            b = images.shape[0] // 2
            mean = images.mean(dim=1, keepdim=True) * 255.0  # [2B, 1, h, w]
            left_grey, right_grey = mean[:b], mean[b:]
        left = query_voxels(left_grey, geometry.fine_left, "bilinear", gather=gather)[:, 0]  # [B, Nz, n*Ny, n*Nx]
        right = query_voxels(right_grey, geometry.fine_right, "bilinear", gather=gather)[:, 0]
        return window_zncc(left, right, cfg.zncc_window, subsamples=cfg.zncc_subsamples)  # [B, Nz, Ny, Nx]

    def predict(
        self,
        left: torch.Tensor,
        right: torch.Tensor | None,
        cameras: list[StereoCamera],
        attitudes: list[Attitude],
        grey: torch.Tensor | None = None,
    ) -> Prediction:
        """Soft-argmin elevation and the bin distribution's standard deviation."""
        logits, observed = self(left, right, cameras, attitudes, grey)
        elevation, uncertainty = soft_argmin(logits, self.centres)
        return Prediction(elevation, uncertainty, observed)
