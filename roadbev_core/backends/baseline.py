"""What the learned image-view baselines (``gwcnet``, ``adabins``) share: their checkpoint, the
grid and rig it was trained for, and their options."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from roadbev_core.backend_plugins import BackendError
from roadbev_core.backends.learned import checkpoint_dir
from roadbev_core.checkpoint import BaselineNetwork, CheckpointError, load_baseline, training_envelope
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import FrameError

__all__ = ["BaselineBackend", "check_options", "default_checkpoint"]

# the options every baseline takes (see their modules)
COMMON_OPTIONS = frozenset({"checkpoint", "threads", "min_points"})


def default_checkpoint(kind: str) -> Path:
    """The shipped checkpoint of baseline ``kind`` (in :func:`roadbev_core.backends.learned.checkpoint_dir`)."""
    return checkpoint_dir() / f"{kind}_lite.pt"


def check_options(kind: str, options: dict[str, Any], extra: frozenset[str] = frozenset()) -> None:
    """Refuse an option baseline ``kind`` does not take (:class:`BackendError`)."""
    unknown = set(options) - COMMON_OPTIONS - extra
    if unknown:
        raise BackendError(f"{kind} backend: unknown option(s) {', '.join(sorted(unknown))}")


class BaselineBackend:
    """A baseline's network from its checkpoint, refused (:class:`BackendError`) when missing,
    damaged, or trained for another grid; :meth:`check_rig` refuses a frame of another rig."""

    name: str
    needs_stereo: bool

    def __init__(self, grid: GridSpec, *, checkpoint: str | Path | None = None, threads: int | None = None,
                 min_points: int = 1) -> None:
        path = Path(checkpoint) if checkpoint else default_checkpoint(self.name)
        if not path.is_file():
            raise BackendError(f"{self.name} backend: checkpoint {path} not found (train one with "
                               f"`roadbev train --kind {self.name}` or pass checkpoint=PATH)")
        if int(min_points) < 1:
            raise BackendError(f"{self.name} backend: min_points must be >= 1, got {min_points}")
        try:
            network, payload = load_baseline(path, self.name)
            self.envelope = training_envelope(payload)
        except CheckpointError as exc:
            raise BackendError(f"{self.name} backend: {exc}") from exc
        problems = self.envelope.grid_problems(grid)
        if problems:
            raise BackendError(f"{self.name} backend: the grid is outside what {path.name} was trained for: "
                               f"{'; '.join(problems)}")
        if threads:
            torch.set_num_threads(int(threads))
        self.grid = grid
        self.network: BaselineNetwork = network
        self.checkpoint = path
        self.min_points = int(min_points)
        self.meta: dict[str, Any] = dict(payload.get("meta", {}))

    def check_rig(self, camera: StereoCamera) -> None:
        """Refuse (:class:`FrameError`) a frame whose rig is beyond what the network was trained for."""
        problems = self.envelope.rig_problems(camera, self.needs_stereo)
        if problems:
            raise FrameError(f"{self.name} backend: the rig is outside what {self.checkpoint.name} was trained "
                             f"for: {'; '.join(problems)}")

    def describe(self) -> dict[str, Any]:
        """Settings as a JSON-able dict (for benchmark records)."""
        return {"backend": self.name, "checkpoint": str(self.checkpoint), "min_points": self.min_points,
                "model_config": self.network.config.to_dict()}
