"""Training of the image-view baselines of Table I (``roadbev train --kind gwcnet|adabins``).

Supervised as image-view methods are, per pixel, on the labelled road surface seen from the
camera (:mod:`roadbev_lab.training.disparity_labels`: each pixel's ray met with the frame's
elevation label):

* GwcNet-lite (stereo) on its disparity, inside the image window that sees the grid (the window
  and the disparity search of :func:`roadbev_core.backends.gwcnet.search_window`, the ones the
  backend runs on); each step takes a random ``crop`` of that window per frame, and the loss is
  GwcNet's smooth L1 over the labelled pixels whose match lies inside the crop and the search;
* AdaBins-lite (mono) on its depth at its output pixels, over the whole image at the network's
  input size; the loss is AdaBins' scale-invariant log loss plus 0.1 x its bin-centre Chamfer
  loss over the labelled pixels.

The optimiser and schedule are the RoadBEV trainer's (AdamW, one-cycle with a linear anneal,
:class:`roadbev_lab.training.train.TrainConfig`), so one budget reads the same for all of them.
Each frame's inputs and labels are made once and kept in memory.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from roadbev_core.backends.adabins import depth_pixels, network_image
from roadbev_core.backends.gwcnet import gwcnet_inputs, search_window
from roadbev_core.checkpoint import BASELINES, TrainingEnvelope, load_baseline, save_baseline
from roadbev_core.config import GridSpec
from roadbev_core.models.adabins import AdaBinsConfig, AdaBinsLite, chamfer_loss, silog_loss
from roadbev_core.models.efficientnet import load_imagenet_weights
from roadbev_core.models.gwcnet import GwcNetConfig, GwcNetLite
from roadbev_lab.training.datasets import FrameSource
from roadbev_lab.training.disparity_labels import surface_depth
from roadbev_lab.training.train import TrainConfig, TrainError

__all__ = ["DEFAULT_CROP", "AdaBinsSample", "GwcSample", "adabins_sample", "gwcnet_sample", "train_image_view",
           "training_phases"]

# (rows, columns) of GwcNet-lite's training crop, multiples of GwcNetLite.stride: the window's
# whole height (430-450 rows on the RSRD half rig), so that each crop holds the grid's near and far rows
DEFAULT_CROP = (448, 384)
# Peak learning rates: GwcNet's own (Adam, 0.001); AdaBins' (AdamW one-cycle, 3.5e-4).
DEFAULT_LR = {"gwcnet": 1e-3, "adabins": 3.5e-4}
CHAMFER_WEIGHT = 0.1  # AdaBins' weight of the bin-centre loss


@dataclass(frozen=True)
class GwcSample:
    """One frame's network inputs over its search window and its label.

    Attributes:
        left, right: [h, w, 3] uint8, the window of the left image and of the right one shifted
            by the search's first disparity.
        target: [h, w] float32 disparity from the search's first one (NaN: no label or no match
            inside the search).
    """

    left: np.ndarray
    right: np.ndarray
    target: np.ndarray


def gwcnet_sample(frame: Any, truth: np.ndarray, grid: GridSpec, config: GwcNetConfig) -> GwcSample:
    """The network's inputs and label for one labelled frame (truth [n_rows, n_cols] metres)."""
    window = search_window(grid, frame.camera, frame.attitude)
    left, right = gwcnet_inputs(frame, window)  # [h, w, 3] each
    rows, cols = np.arange(window.top, window.bottom), np.arange(window.left, window.right)
    depth = surface_depth(truth, grid, frame.camera, frame.attitude, rows, cols)  # [h, w]
    camera = frame.camera
    with np.errstate(invalid="ignore", divide="ignore"):
        target = (camera.fx * camera.baseline) / depth - window.min_disparity
    inside = np.isfinite(target) & (target >= 0) & (target <= config.max_disparity - 1)
    target = np.where(inside, target, np.nan).astype(np.float32)
    h, w = target.shape
    return GwcSample(left[:h, :w], right[:h, :w], target)


def _crop(sample: GwcSample, size: tuple[int, int], rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """A random crop [rows, cols] of a sample, zero / NaN where it reaches beyond the window; labels
    whose match falls left of the crop are dropped.

    A crop at least as large as the window covers it whole; a smaller one may overhang it by half
    its size on either side, so that the window's edge rows (the grid's far and near edge) and
    columns are in a crop about as often as its middle (a crop kept inside the window would see
    its first row once in ``h - rows + 1`` draws).
    """
    rows, cols = size
    h, w = sample.target.shape

    def start(extent: int, size: int) -> int:
        lo, hi = (extent - size, 0) if size >= extent else (-(size // 2), extent - size // 2)
        return int(rng.integers(lo, hi + 1))

    r0, c0 = start(h, rows), start(w, cols)
    left = np.zeros((rows, cols, 3), np.uint8)
    right = np.zeros((rows, cols, 3), np.uint8)
    target = np.full((rows, cols), np.nan, np.float32)
    src_r, src_c = slice(max(r0, 0), min(r0 + rows, h)), slice(max(c0, 0), min(c0 + cols, w))
    dst_r = slice(src_r.start - r0, src_r.stop - r0)
    dst_c = slice(src_c.start - c0, src_c.stop - c0)
    if src_r.stop > src_r.start and src_c.stop > src_c.start:
        left[dst_r, dst_c] = sample.left[src_r, src_c]
        right[dst_r, dst_c] = sample.right[src_r, src_c]
        target[dst_r, dst_c] = sample.target[src_r, src_c]
    u = np.arange(cols, dtype=np.float32)[None, :]
    target = np.where(u - target >= 0, target, np.nan)  # the match must lie in the crop
    return left, right, target


@dataclass(frozen=True)
class AdaBinsSample:
    """One frame's network input and label.

    Attributes:
        image: [3, h, w] uint8 at the network's input size.
        target: [h / 2, w / 2] float32 optical depth (m) at the output pixels (NaN: no label).
    """

    image: np.ndarray
    target: np.ndarray


def adabins_sample(frame: Any, truth: np.ndarray, grid: GridSpec, config: AdaBinsConfig) -> AdaBinsSample:
    """The network's input and label for one labelled frame (truth [n_rows, n_cols] metres)."""
    rows, cols = depth_pixels(config, frame.camera)
    target = surface_depth(truth, grid, frame.camera, frame.attitude, rows, cols)  # [h / 2, w / 2]
    inside = np.isfinite(target) & (target > config.min_depth) & (target < config.max_depth)
    return AdaBinsSample(network_image(frame.left, config), np.where(inside, target, np.nan).astype(np.float32))


def augment_adabins(sample: AdaBinsSample, rng: np.random.Generator) -> AdaBinsSample:
    """AdaBins' own training augmentation (Bhat et al., CVPR 2021, its outdoor settings): the image
    and its label mirrored left to right half of the time, and half of the time the image's gamma,
    brightness and each colour channel scaled by a factor drawn from [0.9, 1.1] (no rotation: the
    label is tied to the rig's rows)."""
    image, target = sample.image, sample.target  # [3, h, w] uint8, [h / 2, w / 2]
    if rng.random() < 0.5:
        image, target = image[:, :, ::-1], target[:, ::-1]
    if rng.random() < 0.5:
        gamma, brightness = rng.uniform(0.9, 1.1, size=2)
        colours = rng.uniform(0.9, 1.1, size=(3, 1, 1))
        scaled = (image.astype(np.float32) / 255.0) ** gamma * brightness * colours
        image = np.round(np.clip(scaled, 0.0, 1.0) * 255.0).astype(np.uint8)
    return AdaBinsSample(np.ascontiguousarray(image), np.ascontiguousarray(target))


def _gwcnet_loss(model: nn.Module, samples: Sequence[GwcSample], crop: tuple[int, int], rng: np.random.Generator
                 ) -> tuple[torch.Tensor, float] | None:
    """GwcNet's smooth L1 over a batch of random crops, and the mean abs. error (pixels)."""
    crops = [_crop(sample, crop, rng) for sample in samples]
    left = torch.from_numpy(np.stack([c[0] for c in crops])).permute(0, 3, 1, 2)  # [B, 3, H, W]
    right = torch.from_numpy(np.stack([c[1] for c in crops])).permute(0, 3, 1, 2)
    target = torch.from_numpy(np.stack([c[2] for c in crops]))  # [B, H, W]
    labelled = torch.isfinite(target)
    if not bool(labelled.any()):
        return None
    disparity, _ = model(left, right)
    loss = F.smooth_l1_loss(disparity[labelled], target[labelled])
    return loss, float((disparity.detach()[labelled] - target[labelled]).abs().mean())


def _adabins_loss(model: nn.Module, samples: Sequence[AdaBinsSample], rng: np.random.Generator, augment: bool = False
                  ) -> tuple[torch.Tensor, float] | None:
    """AdaBins' loss over a batch (each sample augmented with ``augment``: :func:`augment_adabins`),
    and the mean abs. depth error (m)."""
    if augment:
        samples = [augment_adabins(sample, rng) for sample in samples]
    image = torch.from_numpy(np.stack([s.image for s in samples]))  # [B, 3, h, w]
    target = torch.from_numpy(np.stack([s.target for s in samples]))  # [B, h / 2, w / 2]
    labelled = torch.isfinite(target)
    if not bool(labelled.any()):
        return None
    depth, _, centres = model(image)
    generator = torch.Generator().manual_seed(int(rng.integers(2**31)))
    loss = silog_loss(depth, target, labelled) + CHAMFER_WEIGHT * chamfer_loss(centres, target, labelled,
                                                                               generator=generator)
    return loss, float((depth.detach()[labelled] - target[labelled]).abs().mean())


def training_phases(meta: dict[str, Any]) -> list[dict[str, Any]]:
    """The training phases a checkpoint's ``meta`` records, first to last (each: its command,
    per-epoch history, frames, learning rate, batch size, epochs and seconds)."""
    if "phases" in meta:
        return list(meta["phases"])
    return [{k: v for k, v in meta.items() if k != "exported_from"}] if "history" in meta else []


def train_image_view(kind: str, data: FrameSource, config: TrainConfig, out: str | Path, *,
                     model_config: GwcNetConfig | AdaBinsConfig | None = None,
                     init: str | Path | None = None, pretrained: str | Path | None = None,
                     crop: tuple[int, int] = DEFAULT_CROP, augment: bool = False,
                     log: Callable[[str], None] | None = None, meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train baseline ``kind`` (``gwcnet`` or ``adabins``) on ``data`` and write its checkpoint to
    ``out`` after every epoch.

    Args:
        model_config: a fresh network's configuration (default: the kind's defaults).
        init: start from this checkpoint's weights (a fresh schedule).
        pretrained: ImageNet EfficientNet weights for AdaBins-lite's encoder (a fresh network).
        crop: GwcNet-lite's training crop (rows, columns).
        augment: AdaBins' own augmentation of each training sample (:func:`augment_adabins`;
            AdaBins-lite only).

    Returns:
        ``{"checkpoint", "steps", "epochs_done", "history", "stopped_early"}``; the history's
        ``abs_err`` is in pixels of disparity (gwcnet) or metres of depth (adabins).
    """
    if kind not in BASELINES:
        raise TrainError(f"unknown image-view baseline {kind!r}; one of {', '.join(BASELINES)}")
    if crop[0] % GwcNetLite.stride or crop[1] % GwcNetLite.stride:
        raise TrainError(f"the crop's sides must be multiples of {GwcNetLite.stride}, got {crop}")
    if augment and kind != "adabins":
        raise TrainError("the augmentation is AdaBins' (mirrored stereo pairs would swap the cameras)")
    if pretrained is not None and (kind != "adabins" or init is not None):
        raise TrainError("ImageNet weights start a fresh AdaBins-lite only")
    expected = GwcNetConfig if kind == "gwcnet" else AdaBinsConfig
    if model_config is not None and (init is not None or not isinstance(model_config, expected)):
        raise TrainError(f"a fresh {kind} takes a {expected.__name__} (and --init its checkpoint's own)")
    if config.threads:
        torch.set_num_threads(config.threads)
    torch.set_flush_denormal(True)
    torch.manual_seed(config.seed)
    model: GwcNetLite | AdaBinsLite
    earlier: list[dict[str, Any]] = []  # the phases that trained the --init weights
    if init is not None:
        model, payload = load_baseline(init, kind)
        earlier = training_phases(payload.get("meta", {}))
    elif kind == "gwcnet":
        model = GwcNetLite(cast("GwcNetConfig | None", model_config))
    else:
        model = AdaBinsLite(cast("AdaBinsConfig | None", model_config))
        if pretrained is not None:
            load_imagenet_weights(model.backbone, pretrained)
    model.train()
    batches = len(data) // config.batch_size
    if batches == 0:
        raise TrainError(f"{len(data)} frames are fewer than one batch of {config.batch_size}")
    lr = config.lr or DEFAULT_LR[kind]
    optimizer = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.OneCycleLR(optimizer, max_lr=lr, total_steps=batches * config.epochs + 1,
                                                    pct_start=config.pct_start, anneal_strategy="linear")
    rng = np.random.default_rng(config.seed)
    samples: dict[int, Any] = {}
    history: list[dict[str, float]] = []
    start = time.perf_counter()
    step, stopped = 0, False
    camera = data[0][0].camera
    envelope = TrainingEnvelope(grid=data.grid, fx_px=(camera.fx, camera.fx), width_px=camera.width,
                                baseline_m=(camera.baseline, camera.baseline) if kind == "gwcnet" else (0.0, 0.0))

    def sample(index: int) -> Any:
        if index not in samples:
            frame, truth = data[index]
            config = model.config
            samples[index] = (gwcnet_sample(frame, truth, data.grid, config) if isinstance(config, GwcNetConfig)
                              else adabins_sample(frame, truth, data.grid, config))
        return samples[index]

    for epoch in range(config.epochs):
        order = rng.permutation(len(data))
        losses, errors, t_epoch = [], [], time.perf_counter()
        for b in range(batches):
            batch = [sample(int(i)) for i in order[b * config.batch_size:(b + 1) * config.batch_size]]
            result = (_gwcnet_loss(model, batch, crop, rng) if kind == "gwcnet"
                      else _adabins_loss(model, batch, rng, augment))
            if result is None:
                continue
            loss, error = result
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            scheduler.step()
            step += 1
            losses.append(float(loss.detach()))
            errors.append(error)
            if config.max_minutes is not None and time.perf_counter() - start > 60.0 * config.max_minutes:
                stopped = True
                break
        summary = {"epoch": epoch + 1, "step": step, "loss": float(np.mean(losses)) if losses else math.nan,
                   "abs_err": float(np.mean(errors)) if errors else math.nan,
                   "lr": float(scheduler.get_last_lr()[0]), "seconds": time.perf_counter() - t_epoch}
        history.append(summary)
        if log is not None:
            log(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in summary.items()))
        phase = {**(meta or {}), "history": history, "steps": step, "frames": len(data),
                 "crop": list(crop) if kind == "gwcnet" else None, "augment": augment, "lr": lr,
                 "batch_size": config.batch_size,
                 "epochs": config.epochs, "seconds": time.perf_counter() - start}
        save_baseline(out, kind, model.eval(), envelope, meta={**phase, "phases": [*earlier, phase]})
        model.train()
        if stopped:
            break
    return {"checkpoint": Path(out), "steps": step, "epochs_done": len(history), "history": history,
            "stopped_early": stopped}
