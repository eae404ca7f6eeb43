"""Training loop for RoadBEV-mono / RoadBEV-stereo (paper section 5.1 settings).

AdamW (weight decay 1e-4), a one-cycle schedule with linear annealing, learning rate 8e-4 for mono
and 5e-4 for stereo, masked cross-entropy on elevation bins. Single process or distributed through
``torchrun`` (DistributedDataParallel; NCCL on GPUs, gloo on CPUs). A distributed run with global
batch B gives the same steps as one process with batch B: every rank draws the same global batch
order and takes its slice, BatchNorm statistics are reduced over all ranks (SyncBatchNorm on GPUs,
:class:`CpuSyncBatchNorm` on CPUs) and the loss is divided by the global labelled-cell count.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, cast

import torch
import torch.distributed as dist
import torch.distributed.nn.functional as dist_fn
from torch import nn
from tqdm import tqdm

from roadbev_core.checkpoint import read_checkpoint, save_checkpoint
from roadbev_core.config import GridSpec
from roadbev_core.errors import RoadbevError
from roadbev_core.models.efficientnet import load_imagenet_weights
from roadbev_core.models.loss import class_targets, masked_cross_entropy, soft_argmin
from roadbev_core.models.presets import ModelConfig
from roadbev_core.models.roadbev import RoadBEV
from roadbev_lab.training.datasets import FrameSource, ModelInputs, collate

__all__ = ["DEFAULT_LR", "CpuSyncBatchNorm", "TrainConfig", "TrainError", "TrainResult", "train"]

DEFAULT_LR = {"mono": 8e-4, "stereo": 5e-4}


class TrainError(RoadbevError, RuntimeError):
    """Training cannot start or continue (bad settings, incompatible resume checkpoint)."""


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings.

    Attributes:
        epochs: passes over the data.
        batch_size: GLOBAL batch size (split evenly over distributed ranks).
        lr: peak learning rate; None = the paper's per kind (8e-4 mono, 5e-4 stereo).
        weight_decay: AdamW weight decay.
        pct_start: share of the steps spent warming up in the one-cycle schedule.
        seed: model initialisation and data order.
        max_minutes: wall-clock cap; the run stops after the step that crosses it and saves.
        threads: torch intra-op threads (None = torch's default).
    """

    epochs: int = 10
    batch_size: int = 2
    lr: float | None = None
    weight_decay: float = 1e-4
    pct_start: float = 0.1
    seed: int = 0
    max_minutes: float | None = None
    threads: int | None = None

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1:
            raise TrainError(f"epochs and batch size must be >= 1, got {self.epochs} and {self.batch_size}")
        if self.lr is not None and not (self.lr > 0):
            raise TrainError(f"learning rate must be positive, got {self.lr}")
        if not 0 < self.pct_start < 1:
            raise TrainError(f"pct_start must lie in (0, 1), got {self.pct_start}")


@dataclass
class TrainResult:
    """What a run did: steps taken, per-epoch summaries, where the checkpoint is."""

    steps: int
    epochs_done: float
    history: list[dict[str, float]] = field(default_factory=list)
    checkpoint: Path | None = None
    stopped_early: bool = False


class CpuSyncBatchNorm(nn.modules.batchnorm._BatchNorm):
    """BatchNorm whose training statistics are summed over all ranks (CPU / gloo DDP).

    torch's SyncBatchNorm runs on GPUs only. The all-reduce is autograd-aware, so gradients flow
    through the global mean and variance exactly as through a single process's batch.
    """

    def _check_input_dim(self, x: torch.Tensor) -> None:
        if x.dim() < 3:
            raise ValueError(f"expected a [B, C, ...] input, got {tuple(x.shape)}")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (self.training and dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1):
            return super().forward(x)
        c = x.shape[1]
        dims = [0, *range(2, x.dim())]
        count = torch.full((1,), x.numel() / c, dtype=x.dtype)
        stats = dist_fn.all_reduce(torch.cat([x.sum(dims), (x * x).sum(dims), count]))  # [2C + 1]
        n = stats[-1]
        mean = stats[:c] / n
        var = (stats[c:2 * c] / n - mean * mean).clamp_min(0)
        with torch.no_grad():
            m = self.momentum if self.momentum is not None else 0.1
            if self.running_mean is not None and self.running_var is not None:  # track_running_stats
                self.running_mean.mul_(1 - m).add_(m * mean.detach())
                self.running_var.mul_(1 - m).add_(m * var.detach() * n / max(float(n) - 1, 1.0))
            if self.num_batches_tracked is not None:
                self.num_batches_tracked.add_(1)
        shape = (1, c, *([1] * (x.dim() - 2)))
        scale = (self.weight / torch.sqrt(var + self.eps)).view(shape)
        return cast("torch.Tensor", (x - mean.view(shape)) * scale + self.bias.view(shape))


def _to_cpu_sync_bn(module: nn.Module) -> nn.Module:
    for name, child in module.named_children():
        if isinstance(child, nn.modules.batchnorm._BatchNorm):
            sync = CpuSyncBatchNorm(child.num_features, child.eps, child.momentum, child.affine,
                                    child.track_running_stats)
            sync.load_state_dict(child.state_dict())
            setattr(module, name, sync)
        else:
            _to_cpu_sync_bn(child)
    return module


@dataclass(frozen=True)
class _Dist:
    rank: int = 0
    world: int = 1
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def main(self) -> bool:
        return self.rank == 0


def _init_distributed() -> _Dist:
    """Join the process group when launched by torchrun (WORLD_SIZE > 1)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return _Dist(device=torch.device("cuda" if torch.cuda.is_available() else "cpu"))
    rank = int(os.environ["RANK"])
    if torch.cuda.is_available():
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        device, backend = torch.device("cuda", local), "nccl"
    else:
        device, backend = torch.device("cpu"), "gloo"
    if not dist.is_initialized():
        dist.init_process_group(backend)
    return _Dist(rank=rank, world=world, device=device)


def _global_batches(n: int, batch: int, seed: int, epoch: int) -> list[list[int]]:
    """The epoch's batches of sample indices, identical on every rank (last partial one dropped)."""
    gen = torch.Generator().manual_seed(seed * 100_003 + epoch)
    order = torch.randperm(n, generator=gen).tolist()
    return [order[i:i + batch] for i in range(0, n - batch + 1, batch)]


def build_model(config: ModelConfig, grid: GridSpec, *, seed: int = 0, pretrained: str | Path | None = None) -> RoadBEV:
    """A freshly initialised network (seeded), with ImageNet backbone weights if given."""
    torch.manual_seed(seed)
    model = RoadBEV(config, grid)
    if pretrained is not None:
        load_imagenet_weights(model.backbone, pretrained)
    return model


def train(
    model_config: ModelConfig,
    grid: GridSpec,
    data: FrameSource,
    config: TrainConfig,
    out: str | Path,
    *,
    resume: str | Path | None = None,
    init: str | Path | None = None,
    model_overrides: Mapping[str, Any] | None = None,
    pretrained: str | Path | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> TrainResult:
    """Train a RoadBEV model and write its checkpoint to ``out`` (after every epoch and at the end).

    Args:
        model_config: the network (ignored when resuming: the checkpoint's is used).
        grid: the output grid; ``data`` must carry labels on it.
        data: the training frames.
        config: optimisation settings.
        out: checkpoint path.
        resume: continue from this checkpoint (weights, optimizer, schedule, position).
        init: start from this checkpoint's weights (and model config) with a fresh schedule, e.g.
            to fine-tune synthetic-trained weights on RSRD or to train a finished run further.
        model_overrides: ModelConfig fields to change in ``model_config`` or, with ``init``, in
            the checkpoint's config (e.g. a sharper photometric channel for the same weights);
            the weights must still fit. Not with ``resume``.
        pretrained: ImageNet EfficientNet weights (torchvision or lukemelas layout) for a fresh run.
        progress: show a tqdm bar (rank 0 only).
        log: receives one summary line per epoch (rank 0 only).
    """
    env = _init_distributed()
    if config.threads:
        torch.set_num_threads(config.threads)
    torch.set_flush_denormal(True)
    state: dict[str, Any] | None = None
    if resume is not None and init is not None:
        raise TrainError("give either resume (same run) or init (new run from weights), not both")
    overrides = dict(model_overrides or {})
    if resume is not None and overrides:
        raise TrainError("a resumed run keeps its model; model overrides need init or a fresh run")
    if resume is not None:
        payload = read_checkpoint(resume)
        if "train_state" not in payload:
            raise TrainError(f"{resume} holds no training state (an exported checkpoint cannot be resumed)")
        model_config = ModelConfig.from_dict(payload["model_config"])
        if GridSpec.from_dict(payload["grid"]) != grid:
            raise TrainError(f"{resume} was trained on another grid")
        state = payload["train_state"]
    elif init is not None:
        payload = read_checkpoint(init)
        model_config = ModelConfig.from_dict(payload["model_config"])
    if overrides:
        model_config = ModelConfig.from_dict({**model_config.to_dict(), **overrides})
    if config.batch_size % env.world:
        raise TrainError(f"global batch {config.batch_size} does not split over {env.world} processes")
    dataset = ModelInputs(data, model_config, grid)
    batches_per_epoch = len(dataset) // config.batch_size
    if batches_per_epoch == 0:
        raise TrainError(f"{len(dataset)} frames are fewer than one batch of {config.batch_size}")
    total_steps = batches_per_epoch * config.epochs

    model = build_model(model_config, grid, seed=config.seed, pretrained=None if state or init else pretrained)
    if state is not None or init is not None:
        try:
            model.load_state_dict({k: v.float() if v.is_floating_point() else v
                                   for k, v in payload["state_dict"].items()})
        except RuntimeError as exc:
            raise TrainError(f"{init or resume}: weights do not fit the model {model_config}: "
                             f"{str(exc).splitlines()[0]}") from exc
    model.to(env.device).train()
    net: nn.Module = model
    if env.world > 1:
        # torch's SyncBatchNorm needs GPUs; ours does the same over gloo on CPUs.
        net = nn.SyncBatchNorm.convert_sync_batchnorm(net) if env.device.type == "cuda" else _to_cpu_sync_bn(net)
        net = nn.parallel.DistributedDataParallel(
            net, device_ids=[env.device.index] if env.device.type == "cuda" else None
        )
    lr = config.lr or DEFAULT_LR[model_config.kind]
    optimizer = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=config.weight_decay)
    # One step more than taken, so that the rate after the last step is still >= 0.
    scheduler = torch.optim.lr_scheduler.OneCycleLR(
        optimizer, max_lr=lr, total_steps=total_steps + 1, pct_start=config.pct_start, anneal_strategy="linear"
    )
    step, start_epoch, start_batch, history = 0, 0, 0, []
    if state is not None:
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        step, history = int(state["step"]), list(state["history"])
        start_epoch, start_batch = divmod(step, batches_per_epoch)
        if start_epoch >= config.epochs:
            raise TrainError(f"{resume} already finished {start_epoch} epoch(s); ask for more epochs")

    def save(stopped: bool) -> Path | None:
        if not env.main:
            return None
        train_state = {
            "optimizer": optimizer.state_dict(),
            "scheduler": scheduler.state_dict(),
            "step": step,
            "history": history,
            "train_config": {k: v for k, v in asdict(config).items() if v is not None},
            "stopped_early": stopped,
        }
        return save_checkpoint(out, model, train_state=train_state,
                               meta={"steps": step, "frames": len(dataset), "world_size": env.world,
                                     "init": str(init) if init else ""})

    deadline = time.monotonic() + 60 * config.max_minutes if config.max_minutes else math.inf
    per_rank = config.batch_size // env.world
    stopped = False
    bar = None
    if progress and env.main:

        bar = tqdm(total=total_steps, initial=step, desc=f"train {model_config.kind}", unit="step",
                   disable=None)  # None: only on a terminal
    for epoch in range(start_epoch, config.epochs):
        batches = _global_batches(len(dataset), config.batch_size, config.seed, epoch)
        loss_sum, err_sum, cells, seen, t0 = 0.0, 0.0, 0.0, 0, time.perf_counter()
        for batch_idx in range(start_batch if epoch == start_epoch else 0, batches_per_epoch):
            indices = batches[batch_idx][env.rank * per_rank:(env.rank + 1) * per_rank]
            batch = collate([dataset[i] for i in indices])
            loss, err_cm, n_cells = _step(net, model, batch, env, optimizer)
            scheduler.step()
            step += 1
            loss_sum += loss * n_cells
            err_sum += err_cm * n_cells
            cells += n_cells
            seen += config.batch_size
            if bar is not None:
                rate = seen / max(time.perf_counter() - t0, 1e-9)
                bar.set_postfix(epoch=epoch + 1, loss=f"{loss:.3f}", err_cm=f"{err_cm:.2f}", fps=f"{rate:.2f}")
                bar.update(1)
            if time.monotonic() > deadline:
                stopped = True
                break
        summary = {
            "epoch": epoch + 1,
            "step": step,
            "loss": loss_sum / max(cells, 1.0),
            "abs_err_cm": err_sum / max(cells, 1.0),
            "lr": scheduler.get_last_lr()[0],
            "seconds": time.perf_counter() - t0,
        }
        history.append(summary)
        if env.main and log is not None:
            log(" ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in summary.items()))
        save(stopped)
        if stopped:
            break
    if bar is not None:
        bar.close()
    return TrainResult(steps=step, epochs_done=step / batches_per_epoch, history=history,
                       checkpoint=Path(out) if env.main else None, stopped_early=stopped)


def _step(
    net: nn.Module, model: RoadBEV, batch: dict[str, Any], env: _Dist, optimizer: torch.optim.Optimizer
) -> tuple[float, float, float]:
    """One optimisation step; returns the global loss, abs. error (cm) and labelled cells."""
    left = batch["left"].to(env.device)
    right = batch["right"].to(env.device) if "right" in batch else None
    grey = batch["grey"].to(env.device) if "grey" in batch else None
    elevation = batch["elevation"].to(env.device)
    logits, _ = net(left, right, batch["camera"], batch["attitude"], grey)
    target, mask = class_targets(elevation, model.grid, model.config.label)
    local = torch.tensor([float(mask.sum())], device=env.device)
    with torch.no_grad():
        pred, _ = soft_argmin(logits.detach(), model.centres)
        err_sum = torch.abs(pred - torch.nan_to_num(elevation))[mask].sum() * 100.0
    loss_sum = masked_cross_entropy(logits, target, mask, normaliser=1.0)  # summed over cells
    totals = torch.stack([local[0], loss_sum.detach(), err_sum])
    if env.world > 1:
        dist.all_reduce(totals)
    n_cells = float(totals[0])
    # DDP averages gradients over ranks: scale by world / global cells for the global mean.
    loss = loss_sum * (env.world / max(n_cells, 1.0))
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    return float(totals[1]) / max(n_cells, 1.0), float(totals[2]) / max(n_cells, 1.0), n_cells
