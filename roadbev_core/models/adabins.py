"""AdaBins-lite: a learned monocular depth network, the paper's Table I image-view mono class.

Follows Bhat et al., "AdaBins: Depth Estimation using Adaptive Bins" (CVPR 2021), scaled to the
size of the project's ``lite`` RoadBEV-mono (the same EfficientNet-Lite0 trunk and input size):

* encoder-decoder: the EfficientNet trunk's 1/2-1/16 maps fused to one ``channels`` map at 1/2
  of the input (:class:`roadbev_core.models.fpn.PyramidFusion`);
* the mini-ViT: the decoded map cut into ``patch_size`` patches, embedded, with learned positions,
  through a small transformer encoder; the first output token gives the image's ``n_bins`` bin
  widths over [``min_depth``, ``max_depth``] (adaptive: each image places its own bins), the next
  ``queries`` tokens are dotted with every pixel's embedding (range-attention maps);
* per pixel a softmax over the bins from the range-attention maps, the depth the expectation of
  the bin centres, and (not in the paper) the distribution's spread about it as its 1-sigma.

Trained with AdaBins' losses (:func:`silog_loss`, :func:`chamfer_loss`). Images are RGB ``uint8``
at the input size, normalised inside as the trunk's ImageNet weights expect.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import nn

from roadbev_core.config import ConfigError
from roadbev_core.models.efficientnet import SCALING, EfficientNetFeatures, input_normalisation
from roadbev_core.models.fpn import PyramidFusion
from roadbev_core.models.settings import StoredSettings

__all__ = ["AdaBinsConfig", "AdaBinsLite", "chamfer_loss", "silog_loss"]

# positions the learned embedding holds (tokens of the largest input it takes)
_MAX_TOKENS = 1024


@dataclass(frozen=True)
class AdaBinsConfig(StoredSettings):
    """What defines an AdaBins-lite network (stored in its checkpoint).

    Attributes:
        backbone: EfficientNet variant of the encoder (``lite0``: RoadBEV-mono's).
        input_width, input_height: the size images are resized to (RoadBEV-mono's).
        channels: width of the decoded 1/2-resolution map.
        n_bins: depth bins per image.
        min_depth, max_depth: the range the bins divide (m, optical depth).
        patch_size: side of the mini-ViT's patches (pixels of the decoded map).
        embedding, heads, layers: the mini-ViT's token width, attention heads and encoder layers.
        queries: range-attention maps (tokens after the first).
    """

    SETTINGS: ClassVar[str] = "AdaBins"

    backbone: str = "lite0"
    input_width: int = 480
    input_height: int = 264
    channels: int = 32
    n_bins: int = 64
    min_depth: float = 1.0
    max_depth: float = 20.0
    patch_size: int = 8
    embedding: int = 64
    heads: int = 4
    layers: int = 2
    queries: int = 32

    def __post_init__(self) -> None:
        if self.backbone not in SCALING:
            raise ConfigError(f"unknown backbone {self.backbone!r}; choose from {', '.join(SCALING)}")
        if not 0 < self.min_depth < self.max_depth:
            raise ConfigError(f"need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.embedding % self.heads:
            raise ConfigError(f"embedding ({self.embedding}) must be a multiple of heads ({self.heads})")
        tokens = (self.input_height // 2 // self.patch_size) * (self.input_width // 2 // self.patch_size)
        if not self.queries + 1 <= tokens <= _MAX_TOKENS:
            raise ConfigError(f"{tokens} mini-ViT tokens; need between queries + 1 ({self.queries + 1}) and "
                              f"{_MAX_TOKENS} (input size / patch_size)")
        for name in ("channels", "n_bins", "patch_size", "layers", "queries"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")


class _EncoderLayer(nn.Module):
    """A transformer encoder layer (post-norm, as AdaBins' ``nn.TransformerEncoderLayer``), written
    out so that every runtime's graph has it: [B, N, E] -> [B, N, E]."""

    def __init__(self, embedding: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(embedding, 3 * embedding)
        self.project = nn.Linear(embedding, embedding)
        self.norm1, self.norm2 = nn.LayerNorm(embedding), nn.LayerNorm(embedding)
        self.feed = nn.Sequential(nn.Linear(embedding, 2 * embedding), nn.ReLU(), nn.Linear(2 * embedding, embedding))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, n, e = x.shape
        q, k, v = self.qkv(x).view(b, n, 3, self.heads, e // self.heads).permute(2, 0, 3, 1, 4)  # [B, H, N, e/H] each
        attention = torch.softmax(q @ k.transpose(-1, -2) * (e // self.heads) ** -0.5, dim=-1)  # [B, H, N, N]
        mixed = (attention @ v).transpose(1, 2).reshape(b, n, e)
        x = self.norm1(x + self.project(mixed))
        return self.norm2(x + self.feed(x))  # type: ignore[no-any-return]


class _MiniViT(nn.Module):
    """Decoded map [B, C, h, w] -> bin centres [B, n_bins] and range-attention maps [B, Q, h, w]."""

    def __init__(self, config: AdaBinsConfig) -> None:
        super().__init__()
        e = config.embedding
        self.config = config
        self.patches = nn.Conv2d(config.channels, e, config.patch_size, config.patch_size)
        self.positions = nn.Parameter(torch.randn(1, _MAX_TOKENS, e) * 0.02)
        self.encoder = nn.Sequential(*(_EncoderLayer(e, config.heads) for _ in range(config.layers)))
        self.pixels = nn.Conv2d(config.channels, e, 3, padding=1)
        self.widths = nn.Sequential(nn.Linear(e, e), nn.LeakyReLU(), nn.Linear(e, config.n_bins))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        tokens = self.patches(x).flatten(2).transpose(1, 2)  # [B, N, E]
        tokens = self.encoder(tokens + self.positions[:, : tokens.shape[1]])
        c = self.config
        widths = torch.relu(self.widths(tokens[:, 0])) + 0.1  # [B, n_bins] (AdaBins' ReLU + eps, normalised)
        widths = widths / widths.sum(dim=1, keepdim=True)
        edges = c.min_depth + (c.max_depth - c.min_depth) * torch.cumsum(
            F.pad(widths, (1, 0)), dim=1)  # [B, n_bins + 1]
        centres = 0.5 * (edges[:, :-1] + edges[:, 1:])  # [B, n_bins]
        queries = tokens[:, 1: 1 + c.queries]  # [B, Q, E]
        maps = torch.einsum("behw,bqe->bqhw", self.pixels(x), queries)  # [B, Q, h, w]
        return centres, maps


class AdaBinsLite(nn.Module):
    """Adaptive-bins monocular depth (see the module docstring)."""

    mean: torch.Tensor  # [1, 3, 1, 1] the trunk's input normalisation, on the 0-255 scale
    std: torch.Tensor

    def __init__(self, config: AdaBinsConfig | None = None) -> None:
        super().__init__()
        self.config = config or AdaBinsConfig()
        c = self.config
        self.backbone = EfficientNetFeatures(c.backbone)
        self.decoder = PyramidFusion(self.backbone.out_channels, self.backbone.strides, c.channels, 2)
        self.vit = _MiniViT(c)
        self.bins = nn.Conv2d(c.queries, c.n_bins, 1)
        mean, std = input_normalisation(c.backbone)
        self.register_buffer("mean", torch.tensor(mean).view(1, 3, 1, 1) * 255.0, persistent=False)
        self.register_buffer("std", torch.tensor(std).view(1, 3, 1, 1) * 255.0, persistent=False)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Depth, its 1-sigma and the bin centres.

        Args:
            image: [B, 3, H, W] uint8 or float in [0, 255] at the input size.

        Returns:
            depth [B, H/2, W/2] and sigma [B, H/2, W/2] (m, optical depth), centres [B, n_bins].
        """
        x = (image.float() - self.mean) / self.std
        decoded = self.decoder(self.backbone(x), (image.shape[2], image.shape[3]))  # [B, C, H/2, W/2]
        centres, maps = self.vit(decoded)
        prob = torch.softmax(self.bins(maps), dim=1)  # [B, n_bins, H/2, W/2]
        c = centres[:, :, None, None]
        depth = (prob * c).sum(dim=1)
        sigma = torch.sqrt((prob * (c - depth[:, None]) ** 2).sum(dim=1).clamp_min(1e-8))
        return depth, sigma, centres


def silog_loss(depth: torch.Tensor, target: torch.Tensor, labelled: torch.Tensor, variance_focus: float = 0.85
               ) -> torch.Tensor:
    """AdaBins' scale-invariant log loss, ``10 sqrt(mean(g^2) - 0.85 mean(g)^2)``, g = log d - log d*,
    over the ``labelled`` pixels (all [B, h, w])."""
    g = torch.log(depth[labelled].clamp_min(1e-3)) - torch.log(target[labelled])
    return 10.0 * torch.sqrt((g * g).mean() - variance_focus * g.mean() ** 2 + 1e-8)


def chamfer_loss(centres: torch.Tensor, target: torch.Tensor, labelled: torch.Tensor, samples: int = 2048,
                 generator: torch.Generator | None = None) -> torch.Tensor:
    """AdaBins' bin-centre loss: the symmetric Chamfer distance between each image's bin centres
    [B, n_bins] and (up to ``samples`` of) its labelled depths (target, labelled [B, h, w])."""
    losses = []
    for b in range(centres.shape[0]):
        depths = target[b][labelled[b]]
        if depths.numel() == 0:
            continue
        if depths.numel() > samples:
            depths = depths[torch.randperm(depths.numel(), generator=generator)[:samples]]
        gap = (centres[b][:, None] - depths[None, :]) ** 2  # [n_bins, n]
        losses.append(gap.min(dim=0).values.mean() + gap.min(dim=1).values.mean())
    return torch.stack(losses).mean() if losses else centres.sum() * 0.0
