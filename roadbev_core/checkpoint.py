"""RoadBEV checkpoints: weights plus the model configuration and grid they were trained for.

A checkpoint is a plain dict of tensors, numbers and strings saved with ``torch.save`` and read
back with ``torch.load(weights_only=True)``, which refuses to run code from the file (unlike a
pickle). Keys: ``format``, ``model_config`` (:class:`ModelConfig` dict), ``grid`` (GridSpec dict),
``state_dict``, and optionally ``train_state`` (optimizer, schedule, position), ``meta`` and
``envelope`` (:class:`TrainingEnvelope`: the grid window and the rig the network was trained for;
checkpoints without one were trained on the RSRD half-resolution rig and their own grid).
Checkpoints with a non-finite weight are refused at load.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.errors import RoadbevError
from roadbev_core.models.adabins import AdaBinsConfig, AdaBinsLite
from roadbev_core.models.gwcnet import GwcNetConfig, GwcNetLite
from roadbev_core.models.presets import ModelConfig
from roadbev_core.models.roadbev import RoadBEV

__all__ = [
    "ADABINS_FORMAT",
    "BASELINES",
    "FORMAT",
    "GWCNET_FORMAT",
    "BaselineNetwork",
    "CheckpointError",
    "TrainingEnvelope",
    "baseline_kind",
    "checked_state",
    "load_baseline",
    "load_model",
    "read_checkpoint",
    "save_baseline",
    "save_checkpoint",
    "training_envelope",
]

FORMAT = "roadbev-checkpoint/1"
# The image-view baselines (roadbev_core.models.gwcnet, .adabins): keys format, model_config
# (their configuration's dict), state_dict, meta (training command, data, budget) and envelope.
GWCNET_FORMAT = "roadbev-gwcnet-checkpoint/1"
ADABINS_FORMAT = "roadbev-adabins-checkpoint/1"


class CheckpointError(RoadbevError, ValueError):
    """A checkpoint that is missing, unreadable, or does not fit the requested model."""


@dataclass(frozen=True)
class TrainingEnvelope:
    """What a network was trained for, and how far a frame may stray from it.

    Attributes:
        grid: the training grid (window, resolution, ``base_height``).
        fx_px: the training rig's focal length range (pixels, at its image width ``width_px``).
        width_px: image width the focal lengths refer to (a resized image scales both).
        baseline_m: the training rig's stereo baseline range (m; (0, 0) for mono data).
        window_margin_m: how far the grid's window may reach beyond the training window.
        resolution_ratio: the grid's cell size may be at most this factor off the training one.
        base_height_margin_m: how far ``base_height`` may be off the training one.
        rig_ratio: how far (factor) the focal length in image widths and the baseline may be off.
    """

    grid: GridSpec
    fx_px: tuple[float, float]
    width_px: int
    baseline_m: tuple[float, float]
    window_margin_m: float = 0.3
    resolution_ratio: float = 1.5
    base_height_margin_m: float = 0.15
    rig_ratio: float = 1.3

    def grid_problems(self, grid: GridSpec) -> list[str]:
        """Why ``grid`` is outside the envelope (empty when inside)."""
        t, m = self.grid, self.window_margin_m
        problems = []
        if grid.x_min < t.x_min - m or grid.x_max > t.x_max + m:
            problems.append(f"x window {grid.x_min:.2f}..{grid.x_max:.2f} m is beyond the trained "
                            f"{t.x_min:.2f}..{t.x_max:.2f} m (+-{m} m)")
        if grid.y_min < t.y_min - m or grid.y_max > t.y_max + m:
            problems.append(f"y window {grid.y_min:.2f}..{grid.y_max:.2f} m is beyond the trained "
                            f"{t.y_min:.2f}..{t.y_max:.2f} m (+-{m} m)")
        ratio = grid.resolution / t.resolution
        if not 1.0 / self.resolution_ratio <= ratio <= self.resolution_ratio:
            problems.append(f"cells of {grid.resolution} m against the trained {t.resolution} m")
        if abs(grid.base_height - t.base_height) > self.base_height_margin_m:
            problems.append(f"base_height {grid.base_height} m against the trained {t.base_height} m "
                            f"(+-{self.base_height_margin_m} m)")
        return problems

    def rig_problems(self, camera: StereoCamera, stereo: bool) -> list[str]:
        """Why ``camera`` is outside the envelope (empty when inside)."""
        problems = []
        r = self.rig_ratio
        fx = camera.fx * self.width_px / camera.width  # at the training image width
        if not self.fx_px[0] / r <= fx <= self.fx_px[1] * r:
            problems.append(f"focal length {fx:.0f} px (at {self.width_px} px wide) against the trained "
                            f"{self.fx_px[0]:.0f}..{self.fx_px[1]:.0f} px (x/ {r})")
        if stereo and not self.baseline_m[0] / r <= camera.baseline <= self.baseline_m[1] * r:
            problems.append(f"baseline {camera.baseline:.3f} m against the trained "
                            f"{self.baseline_m[0]:.3f}..{self.baseline_m[1]:.3f} m (x/ {r})")
        return problems

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["grid"] = self.grid.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainingEnvelope:
        fields = dict(data)
        fields["grid"] = GridSpec.from_dict(fields["grid"])
        fields["fx_px"] = tuple(float(v) for v in fields["fx_px"])
        fields["baseline_m"] = tuple(float(v) for v in fields["baseline_m"])
        return cls(**fields)


def training_envelope(payload: dict[str, Any]) -> TrainingEnvelope:
    """The :class:`TrainingEnvelope` of a checkpoint dict.

    Checkpoints without an ``envelope`` entry were all trained on the synthetic RSRD
    half-resolution rig (``StereoCamera.rsrd_half``, ``roadbev_lab.synth``) on their own grid.
    """
    try:
        if "envelope" in payload:
            return TrainingEnvelope.from_dict(payload["envelope"])
        rig = StereoCamera.rsrd_half()
        return TrainingEnvelope(
            grid=GridSpec.from_dict(payload["grid"]), fx_px=(rig.fx, rig.fx), width_px=rig.width,
            baseline_m=(rig.baseline, rig.baseline),
        )
    except (ConfigError, KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"checkpoint has a bad training envelope: {exc}") from exc


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
    return _write(payload, path)


def _write(payload: dict[str, Any], path: Path) -> Path:
    """Save ``payload`` to ``path`` atomically (a partial file never has the final name)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def baseline_kind(path: str | Path) -> str | None:
    """The image-view baseline (:data:`BASELINES`) a checkpoint holds, None for anything else.

    Raises:
        CheckpointError: a missing or unreadable file.
    """
    payload = _load(Path(path))
    form = payload.get("format") if isinstance(payload, dict) else None
    return next((kind for kind, (f, _, _) in BASELINES.items() if f == form), None)


def _load(path: Path) -> Any:
    """A checkpoint file's content, loaded with ``weights_only=True``."""
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt files (pickle, zip, runtime)
        raise CheckpointError(f"checkpoint {path} is unreadable or corrupt: {exc.__class__.__name__}") from exc


def read_checkpoint(path: str | Path, *, expect: str = FORMAT) -> dict[str, Any]:
    """The checkpoint dict at ``path`` (loaded with ``weights_only=True``), of format ``expect``
    (:data:`FORMAT`, a RoadBEV network's, or a baseline's in :data:`BASELINES`).

    Raises:
        CheckpointError: missing file, unreadable or foreign content.
    """
    path = Path(path)
    payload = _load(path)
    if not isinstance(payload, dict) or payload.get("format") != expect:
        what = {FORMAT: "a RoadBEV", GWCNET_FORMAT: "a GwcNet-lite", ADABINS_FORMAT: "an AdaBins-lite"}[expect]
        raise CheckpointError(f"{path} is not {what} checkpoint (format {expect!r})")
    for key in ("model_config", "grid" if expect == FORMAT else "envelope", "state_dict"):
        if key not in payload:
            raise CheckpointError(f"checkpoint {path} lacks {key!r}")
    return payload


# Largest magnitude of any trained weight or batch-norm statistic a checkpoint may hold: trained
# RoadBEV models stay within a few thousand (running variances the largest); a file far beyond it
# would give an all-NaN or all-saturated output instead of an error.
MAX_WEIGHT = 1e6


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
    state = checked_state(payload["state_dict"], path)
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointError(
            f"checkpoint {path} does not fit a {config.kind} model on this grid: {str(exc).splitlines()[0]}"
        ) from exc
    return model.eval(), payload


def checked_state(state_dict: dict[str, torch.Tensor], path: str | Path) -> dict[str, torch.Tensor]:
    """A checkpoint's weights in fp32, refused (:class:`CheckpointError`) when one is not finite
    or beyond :data:`MAX_WEIGHT`."""
    state = {k: v.float() if v.is_floating_point() else v for k, v in state_dict.items()}
    broken = [k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if broken:
        more = f" and {len(broken) - 1} more" if len(broken) > 1 else ""
        raise CheckpointError(f"checkpoint {path} has non-finite weights (NaN or inf) in {broken[0]}{more}")
    largest = max(((float(v.abs().max()), k) for k, v in state.items() if v.is_floating_point() and v.numel()),
                  default=(0.0, ""))
    if largest[0] > MAX_WEIGHT:
        raise CheckpointError(f"checkpoint {path} has implausible weights: |{largest[1]}| up to {largest[0]:.3g} "
                              f"(a trained model stays far below {MAX_WEIGHT:g}); a damaged or tampered file?")
    return state


# An image-view baseline network of Table I.
BaselineNetwork = GwcNetLite | AdaBinsLite
# The image-view baselines: kind -> (checkpoint format, configuration, network).
BASELINES: dict[str, tuple[str, type[GwcNetConfig] | type[AdaBinsConfig], type[BaselineNetwork]]] = {
    "gwcnet": (GWCNET_FORMAT, GwcNetConfig, GwcNetLite),
    "adabins": (ADABINS_FORMAT, AdaBinsConfig, AdaBinsLite),
}


def save_baseline(path: str | Path, kind: str, model: BaselineNetwork, envelope: TrainingEnvelope, *,
                  meta: dict[str, Any] | None = None) -> Path:
    """Write an image-view baseline network (``kind`` in :data:`BASELINES`: weights, configuration,
    the grid and rig it was trained for, ``meta``) to ``path`` atomically."""
    path = Path(path)
    payload: dict[str, Any] = {
        "format": BASELINES[kind][0],
        "model_config": model.config.to_dict(),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "meta": dict(meta or {}),
        "envelope": envelope.to_dict(),
    }
    return _write(payload, path)


def load_baseline(path: str | Path, kind: str) -> tuple[BaselineNetwork, dict[str, Any]]:
    """The image-view baseline network ``kind`` of a checkpoint (eval mode, fp32) and the checkpoint dict.

    Raises:
        CheckpointError: missing, corrupt or foreign file, bad configuration, weights that do not fit.
    """
    form, config_type, network = BASELINES[kind]
    payload = read_checkpoint(path, expect=form)
    try:
        config = config_type.from_dict(payload["model_config"])
    except (ConfigError, TypeError) as exc:
        raise CheckpointError(f"checkpoint {path} has a bad configuration: {exc}") from exc
    model = network(config)  # type: ignore[arg-type]  # the format names the configuration's network
    try:
        model.load_state_dict(checked_state(payload["state_dict"], path))
    except RuntimeError as exc:
        raise CheckpointError(f"checkpoint {path} does not fit a {kind} network of {config}: "
                              f"{str(exc).splitlines()[0]}") from exc
    return model.eval(), payload
