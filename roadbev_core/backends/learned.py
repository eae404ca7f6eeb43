"""Learned backends ``stereo`` and ``mono``: RoadBEV networks from a checkpoint.

Options:
    checkpoint: path of a RoadBEV checkpoint (``roadbev train`` / ``roadbev export``); default the
        shipped ``checkpoints/roadbev_{stereo,mono}_lite.pt`` of this repository.
    threads: torch intra-op threads (default: torch's choice).
    out_of_distribution: ``refuse`` (default): a grid (at creation) or a rig (per frame) beyond
        the checkpoint's training envelope (:class:`roadbev_core.checkpoint.TrainingEnvelope`) is
        refused with the reason; ``flag``: run anyway and mark every cell out of distribution with
        a sigma of the grid's whole height range.

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
from roadbev_core.checkpoint import CheckpointError, load_model, training_envelope
from roadbev_core.config import GridSpec
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.models.efficientnet import fold_batchnorm
from roadbev_core.models.roadbev import needs_full_grey, prepare_grey, prepare_image

__all__ = ["DEFAULT_CHECKPOINT_DIR", "OOD_MODES", "LearnedBackend", "OutOfDistributionError", "default_checkpoint"]

OOD_MODES = ("refuse", "flag")


class OutOfDistributionError(FrameError):
    """A frame whose rig lies beyond what the checkpoint was trained for (refused)."""

DEFAULT_CHECKPOINT_DIR = Path(__file__).resolve().parents[2] / "checkpoints"


def default_checkpoint(kind: str) -> Path:
    """The shipped checkpoint of ``kind`` (may not exist in a stripped install)."""
    return DEFAULT_CHECKPOINT_DIR / f"roadbev_{kind}_lite.pt"


class LearnedBackend:
    """A RoadBEV network behind the backend protocol."""

    def __init__(self, kind: str, grid: GridSpec, *, checkpoint: str | Path | None = None,
                 threads: int | None = None, out_of_distribution: str = "refuse") -> None:
        if out_of_distribution not in OOD_MODES:
            raise BackendError(f"{kind} backend: out_of_distribution must be one of {', '.join(OOD_MODES)}, "
                               f"got {out_of_distribution!r}")
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
        try:
            self.envelope = training_envelope(payload)
        except CheckpointError as exc:
            raise BackendError(f"{kind} backend: {path}: {exc}") from exc
        self.flag_out_of_distribution = out_of_distribution == "flag"
        problems = self.envelope.grid_problems(grid)
        if problems and not self.flag_out_of_distribution:
            raise BackendError(
                f"{kind} backend: the grid is outside what {path.name} was trained for: {'; '.join(problems)} "
                "(train for this grid, or pass out_of_distribution=flag to run with every cell flagged)"
            )
        self.grid_out_of_distribution = bool(problems)
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
            part.to(memory_format=torch.channels_last)  # 2-D convs only (the 3-D head stays NCDHW)
        self.config = model.config

    @torch.inference_mode()
    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and 1-sigma uncertainty for one frame (NaN where the camera sees no voxel)."""
        if self.needs_stereo and frame.right is None:
            raise FrameError("the stereo backend needs a right image")
        rig_problems = self.envelope.rig_problems(frame.camera, self.needs_stereo)
        if rig_problems and not self.flag_out_of_distribution:
            raise OutOfDistributionError(
                f"{self.name} backend: the rig is outside what {self.checkpoint.name} was trained for: "
                f"{'; '.join(rig_problems)} (or run with out_of_distribution=flag)"
            )
        outside = self.grid_out_of_distribution or bool(rig_problems)
        t0 = time.perf_counter()
        left = torch.from_numpy(prepare_image(frame.left, self.config))[None]
        right = torch.from_numpy(prepare_image(frame.right, self.config))[None] if self.needs_stereo else None
        grey = torch.from_numpy(prepare_grey(frame.left, frame.right))[None] if needs_full_grey(self.config) else None
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
        if outside:  # every cell as unsure as the grid's whole height range
            uncertainty = np.where(seen, self.grid.z_max - self.grid.z_min, np.nan).astype(np.float32)
        t3 = time.perf_counter()
        timings = {"preprocess": 1e3 * (t1 - t0), "network": 1e3 * (t2 - t1), "post": 1e3 * (t3 - t2)}
        return Estimate(elevation=elevation, uncertainty=uncertainty, timings_ms=timings,
                        out_of_distribution=outside)


@register("stereo")
def _stereo(grid: GridSpec, **options: Any) -> LearnedBackend:
    return LearnedBackend("stereo", grid, **options)


@register("mono")
def _mono(grid: GridSpec, **options: Any) -> LearnedBackend:
    return LearnedBackend("mono", grid, **options)
