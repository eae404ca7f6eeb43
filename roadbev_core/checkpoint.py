"""RoadBEV checkpoints: weights plus the model configuration and grid they were trained for.

A checkpoint is a plain dict of tensors, numbers and strings saved with ``torch.save`` and read
back with ``torch.load(weights_only=True)``, which refuses to run code from the file (unlike a
pickle). Keys: ``format``, ``model_config`` (:class:`ModelConfig` dict), ``grid`` (GridSpec dict),
``state_dict``, and optionally ``train_state`` (optimizer, schedule, position) and ``meta``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from roadbev_core.config import ConfigError, GridSpec
from roadbev_core.errors import RoadbevError
from roadbev_core.models.presets import ModelConfig
from roadbev_core.models.roadbev import RoadBEV

__all__ = ["FORMAT", "CheckpointError", "load_model", "read_checkpoint", "save_checkpoint"]

FORMAT = "roadbev-checkpoint/1"


class CheckpointError(RoadbevError, ValueError):
    """A checkpoint that is missing, unreadable, or does not fit the requested model."""


def save_checkpoint(
    path: str | Path,
    model: RoadBEV,
    *,
    train_state: dict[str, Any] | None = None,
    meta: dict[str, Any] | None = None,
    half: bool = False,
) -> Path:
    """Write ``model`` (unwrapped, not DDP) to ``path`` atomically; ``half`` stores fp16 weights."""
    path = Path(path)
    state = {k: (v.half() if half and v.is_floating_point() else v).detach().cpu()
             for k, v in model.state_dict().items()}
    payload: dict[str, Any] = {
        "format": FORMAT,
        "model_config": model.config.to_dict(),
        "grid": model.grid.to_dict(),
        "state_dict": state,
        "meta": dict(meta or {}),
    }
    if train_state is not None:
        payload["train_state"] = train_state
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict at ``path`` (loaded with ``weights_only=True``).

    Raises:
        CheckpointError: missing file, unreadable or foreign content.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt files (pickle, zip, runtime)
        raise CheckpointError(f"checkpoint {path} is unreadable or corrupt: {exc.__class__.__name__}") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a RoadBEV checkpoint (format {FORMAT!r})")
    for key in ("model_config", "grid", "state_dict"):
        if key not in payload:
            raise CheckpointError(f"checkpoint {path} lacks {key!r}")
    return payload


def load_model(path: str | Path, *, grid: GridSpec | None = None) -> tuple[RoadBEV, dict[str, Any]]:
    """Rebuild the network of a checkpoint, for its own grid or another one of the same shape class.

    A different ``grid`` (e.g. another ``base_height`` or window) works whenever the weights fit
    it: the projection is recomputed from the grid, the layers only need the same voxel and class
    counts.

    Returns:
        the model in eval mode (fp32) and the checkpoint dict.
    """
    payload = read_checkpoint(path)
    try:
        config = ModelConfig.from_dict(payload["model_config"])
        trained_grid = GridSpec.from_dict(payload["grid"])
    except (ConfigError, TypeError) as exc:
        raise CheckpointError(f"checkpoint {path} has a bad configuration: {exc}") from exc
    model = RoadBEV(config, grid or trained_grid)
    state = {k: v.float() if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointError(
            f"checkpoint {path} does not fit a {config.kind} model on this grid: {str(exc).splitlines()[0]}"
        ) from exc
    return model.eval(), payload
