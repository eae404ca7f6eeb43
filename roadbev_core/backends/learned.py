"""Learned backends ``stereo`` and ``mono``: RoadBEV networks from a checkpoint.

Options:
    checkpoint: path of a RoadBEV checkpoint (``roadbev train`` / ``roadbev export``); default the
        shipped ``checkpoints/roadbev_{stereo,mono}_lite.pt`` of this repository.
    threads: torch intra-op threads (default: torch's choice).

Inference folds BatchNorm into the convolutions and runs channels-last with denormals flushed
(``shared/design/cpu-sizing.md``: both roughly halve CPU time). Cells whose voxels the camera(s) do
not see get NaN elevation and uncertainty.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from roadbev_core.backends import BackendError, register
from roadbev_core.checkpoint import CheckpointError, load_model
from roadbev_core.config import GridSpec
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.models.efficientnet import fold_batchnorm
from roadbev_core.models.roadbev import needs_full_grey, prepare_grey, prepare_image

__all__ = ["DEFAULT_CHECKPOINT_DIR", "LearnedBackend", "default_checkpoint"]

DEFAULT_CHECKPOINT_DIR = Path(__file__).resolve().parents[2] / "checkpoints"


def default_checkpoint(kind: str) -> Path:
    """The shipped checkpoint of ``kind`` (may not exist in a stripped install)."""
    return DEFAULT_CHECKPOINT_DIR / f"roadbev_{kind}_lite.pt"


class LearnedBackend:
    """A RoadBEV network behind the backend protocol."""

    def __init__(self, kind: str, grid: GridSpec, *, checkpoint: str | Path | None = None,
                 threads: int | None = None) -> None:
        path = Path(checkpoint) if checkpoint else default_checkpoint(kind)
        if not path.is_file():
            raise BackendError(
                f"{kind} backend: checkpoint {path} not found (train one with `roadbev train --kind {kind}` "
                "or pass checkpoint=PATH)"
            )
        try:
            model, payload = load_model(path, grid=grid)
        except CheckpointError as exc:
            raise BackendError(f"{kind} backend: {exc}") from exc
        if model.config.kind != kind:
            raise BackendError(f"{kind} backend: {path} holds a RoadBEV-{model.config.kind} model")
        if threads:
            torch.set_num_threads(int(threads))
        torch.set_flush_denormal(True)
        self.name = kind
        self.grid = grid
        self.needs_stereo = kind == "stereo"
        self.checkpoint = path
        self.meta: dict[str, Any] = dict(payload.get("meta", {}))
        self.model = fold_batchnorm(model.eval())
        for part in (self.model.backbone, self.model.fusion) if self.needs_stereo else (self.model,):
            # 2-D convs only (the 3-D head stays NCDHW). Module.to takes memory_format at run time;
            # torch's overloads of it do not list the keyword.
            part.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        self.config = model.config

    @torch.inference_mode()
    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and 1-sigma uncertainty for one frame (NaN where the camera sees no voxel)."""
        if self.needs_stereo and frame.right is None:
            raise FrameError("the stereo backend needs a right image")
        t0 = time.perf_counter()
        left = torch.from_numpy(prepare_image(frame.left, self.config))[None]
        right = (
            torch.from_numpy(prepare_image(frame.right, self.config))[None]
            if self.needs_stereo and frame.right is not None  # (checked above)
            else None
        )
        grey = (
            torch.from_numpy(prepare_grey(frame.left, frame.right))[None]
            if frame.right is not None and needs_full_grey(self.config)
            else None
        )
        t1 = time.perf_counter()
        pred = self.model.predict(
            left.contiguous(memory_format=torch.channels_last),
            None if right is None else right.contiguous(memory_format=torch.channels_last),
            [frame.camera], [frame.attitude], grey,
        )
        t2 = time.perf_counter()
        seen = pred.observed[0].numpy()
        elevation = np.where(seen, pred.elevation[0].numpy(), np.nan).astype(np.float32)
        uncertainty = np.where(seen, pred.uncertainty[0].numpy(), np.nan).astype(np.float32)
        t3 = time.perf_counter()
        timings = {"preprocess": 1e3 * (t1 - t0), "network": 1e3 * (t2 - t1), "post": 1e3 * (t3 - t2)}
        return Estimate(elevation=elevation, uncertainty=uncertainty, timings_ms=timings)


@register("stereo")
def _stereo(grid: GridSpec, **options: Any) -> LearnedBackend:
    return LearnedBackend("stereo", grid, **options)


@register("mono")
def _mono(grid: GridSpec, **options: Any) -> LearnedBackend:
    return LearnedBackend("mono", grid, **options)
