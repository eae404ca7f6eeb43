"""Calibrated, sharp 1-sigma for every backend, and the visibility step behind it.

A backend's own spread (a softmax width, the scatter of a cell's points) says how well a height
was matched, not how wrong it can be: on the edges of a bump, behind a crest or across a pothole
rim the error is several times that spread. :func:`refine` turns a backend's raw estimate into
what a controller may trust:

1. cells the camera(s) cannot see (:func:`roadbev_core.visibility.hidden_cells`) become NaN;
2. sigma becomes a :class:`SigmaModel` of per-cell features of the estimate itself
   (:func:`sigma_features`): the backend's spread, a floor, the local slope, the local relief
   (the cell against its neighbourhood), the height above the fitted road plane and, where a
   crest in front would hide the road plane's level (the road may drop out of view behind it),
   the height above that level again (``shadow``), and the length of road one image row covers at
   the cell (``footprint``, :func:`roadbev_core.far_field.cell_row_length`: what one pixel of the
   matcher's window averages over, which grows with the square of the range)::

       sigma^2 = (raw * spread)^2 + floor^2 + (slope * |grad e| * 1 m)^2 + (relief * |e - mean|)^2
                 + (plane * |e - road|)^2 + (shadow * depth)^2 + (footprint * row length)^2

The coefficients are fitted per backend on tuning scenes and drives (:func:`fit_sigma_model`, Gaussian
likelihood), never on the test frames, by ``python -m benchmarks.calibrate_sigma``, which writes
``roadbev_core/data/sigma_calibration.json`` (with the command and the seeds);
:func:`calibration_for` reads it. The far-field grid has tables of its own
(``roadbev_core/data/far_sigma_calibration.json``, ``calibrate_sigma --far-field``, with the
``footprint`` term: what a matcher resolves falls with range): a grid that starts at or beyond the
near edge of the grid those were fitted on takes them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

from roadbev_core.config import GridSpec
from roadbev_core.far_field import cell_row_length
from roadbev_core.frame import Estimate, Frame
from roadbev_core.tables import json_table
from roadbev_core.visibility import Visibility, analyse

__all__ = [
    "CALIBRATION_FILE",
    "FAR_CALIBRATION_FILE",
    "SigmaFeatures",
    "SigmaModel",
    "calibration_for",
    "calibration_key",
    "camera_positions",
    "fit_sigma_model",
    "refine",
    "sigma_features",
    "visible_estimate",
    "with_footprint",
]

CALIBRATION_FILE = Path(__file__).resolve().parent / "data" / "sigma_calibration.json"
FAR_CALIBRATION_FILE = Path(__file__).resolve().parent / "data" / "far_sigma_calibration.json"
_RELIEF_CELLS = 7  # window (cells) of the neighbourhood mean for the relief feature
_SLOPE_REACH = 2  # cells each side of the central difference for the slope feature


class SigmaFeatures(NamedTuple):
    """Per-cell features of an estimate (all [R, C] float32, metres or unitless)."""

    spread: np.ndarray  # the backend's own 1-sigma (m)
    slope: np.ndarray  # |grad e| (unitless)
    relief: np.ndarray  # |e - window mean of e| (m)
    plane: np.ndarray  # |e - fitted road plane| (m)
    shadow: np.ndarray  # height above the road plane where the plane's level would be hidden (m, >= 0)
    # road length along x one image row covers at the cell (m; cell_row_length); None: not computed
    # (only a model with a footprint term needs it)
    footprint: np.ndarray | None = None


@dataclass(frozen=True)
class SigmaModel:
    """Coefficients of the calibrated sigma (module docstring); all >= 0."""

    raw: float = 1.0
    floor: float = 0.0
    slope: float = 0.0
    relief: float = 0.0
    plane: float = 0.0
    shadow: float = 0.0
    footprint: float = 0.0

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"SigmaModel.{name} must be a finite number >= 0, got {value!r}")

    def sigma(self, features: SigmaFeatures) -> np.ndarray:
        """[R, C] float32 calibrated 1-sigma (m); NaN where the spread is NaN.

        Raises:
            ValueError: a model with a footprint term and features without the footprint.
        """
        variance = (
            np.square(self.raw * features.spread.astype(np.float64))
            + self.floor**2
            + np.square(self.slope * features.slope)
            + np.square(self.relief * features.relief)
            + np.square(self.plane * features.plane)
            + np.square(self.shadow * features.shadow)
        )
        if self.footprint:
            if features.footprint is None:
                raise ValueError("this sigma model has a footprint term: the features need their footprint")
            variance = variance + np.square(self.footprint * features.footprint.astype(np.float64))
        return np.sqrt(variance).astype(np.float32)

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SigmaModel:
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown SigmaModel field(s): {', '.join(sorted(unknown))}")
        return cls(**{k: float(v) for k, v in data.items()})


def camera_positions(frame: Frame, stereo: bool) -> tuple[float, ...]:
    """Road-frame lateral positions (m) of the cameras a backend looks through: the left one at
    0, the right one ``baseline`` to its right."""
    if stereo and frame.camera.baseline > 0:
        return (0.0, -float(frame.camera.baseline))
    return (0.0,)


def sigma_features(spread: np.ndarray, grid: GridSpec, visibility: Visibility) -> SigmaFeatures:
    """The features of :class:`SigmaModel` for one estimate.

    Args:
        spread: [R, C] the backend's own 1-sigma (m); NaN or non-positive values count as 0.
        grid: the grid.
        visibility: :func:`roadbev_core.visibility.analyse` of the estimate.
    """
    surface, road = visibility.surface, visibility.road
    k = _SLOPE_REACH
    padded = np.pad(surface, k, mode="edge")
    d_row = (padded[2 * k :, k:-k] - padded[: -2 * k, k:-k]) / (2 * k * grid.resolution)
    d_col = (padded[k:-k, 2 * k :] - padded[k:-k, : -2 * k]) / (2 * k * grid.resolution)
    slope = np.hypot(d_row, d_col)
    mean = cv2.blur(surface, (_RELIEF_CELLS, _RELIEF_CELLS), borderType=cv2.BORDER_REPLICATE)
    # Where the road plane's own level would be hidden (a crest in front), the truth may lie
    # anywhere down to it: the estimate's height above the road is what it may be off by.
    shadow = np.where(visibility.sight.lowest_visible > road, np.clip(surface - road, 0.0, None), 0.0)
    own = np.where(np.isfinite(spread) & (spread > 0), spread, 0.0)
    return SigmaFeatures(
        own.astype(np.float32),
        slope.astype(np.float32),
        np.abs(surface - mean).astype(np.float32),
        np.abs(surface - road).astype(np.float32),
        shadow.astype(np.float32),
    )


def visible_estimate(estimate: Estimate, grid: GridSpec, camera_y: Sequence[float]) -> tuple[np.ndarray, SigmaFeatures]:
    """A raw estimate with its hidden cells NaN, and the sigma features of every cell.

    Args:
        estimate: a backend's raw answer on ``grid``.
        grid: the grid.
        camera_y: the cameras' lateral positions (:func:`camera_positions`).

    Returns:
        [R, C] float32 elevation (hidden cells NaN) and :class:`SigmaFeatures`.
    """
    visibility = analyse(estimate.elevation, grid, camera_y)
    elevation = np.where(visibility.hidden, np.nan, estimate.elevation).astype(np.float32)
    return elevation, sigma_features(estimate.uncertainty, grid, visibility)


def with_footprint(features: SigmaFeatures, frame: Frame, grid: GridSpec) -> SigmaFeatures:
    """``features`` with the footprint of ``frame``'s rig and attitude on ``grid``."""
    return features._replace(footprint=cell_row_length(frame.camera, frame.attitude, grid))


def refine(estimate: Estimate, frame: Frame, grid: GridSpec, *, stereo: bool,
           model: SigmaModel | None) -> Estimate:
    """The estimate a controller may trust: hidden cells NaN, sigma from ``model``.

    Args:
        estimate: a backend's raw answer on ``grid``.
        frame: the frame it answered (for the rig).
        grid: the grid.
        stereo: whether the backend needs both cameras to see a cell.
        model: the backend's calibration (None: keep its own sigma).

    Returns:
        A new :class:`Estimate` (same timings).
    """
    elevation, features = visible_estimate(estimate, grid, camera_positions(frame, stereo))
    if model is not None and model.footprint:
        features = with_footprint(features, frame, grid)
    sigma = estimate.uncertainty if model is None else model.sigma(features)
    sigma = np.where(np.isfinite(elevation), sigma, np.nan).astype(np.float32)
    return Estimate(elevation=elevation, uncertainty=sigma, timings_ms=dict(estimate.timings_ms))


def fit_sigma_model(features: Sequence[SigmaFeatures], errors: Sequence[np.ndarray], *,
                    fit: Sequence[str] = ("raw", "floor", "slope", "relief", "plane", "shadow"),
                    iterations: int = 400) -> SigmaModel:
    """Coefficients maximising the Gaussian likelihood of the observed errors.

    The loss per cell is 0.5 (log sigma^2 + err^2 / sigma^2), minimised by Adam over the
    log-coefficients (so they stay positive).

    Args:
        features: per frame, :func:`sigma_features`.
        errors: per frame, [R, C] estimate - truth (m), NaN where either is missing.
        fit: the coefficients to fit (the others stay 0, ``raw`` 1).
        iterations: Adam steps on the log-coefficients.

    Raises:
        ValueError: no cell with an error.
    """
    # lazy: torch loads only where a learned backend's uncertainty needs it (the classical backends run without it)
    import torch

    names = list(SigmaModel.__dataclass_fields__)
    columns, targets = [], []
    for feats, err in zip(features, errors, strict=True):
        usable = np.isfinite(err)
        if not usable.any():
            continue
        squared = {
            "raw": feats.spread[usable], "floor": np.ones(int(usable.sum()), np.float32),
            "slope": feats.slope[usable], "relief": feats.relief[usable], "plane": feats.plane[usable],
            "shadow": feats.shadow[usable],
            "footprint": (feats.footprint[usable] if feats.footprint is not None
                          else np.zeros(int(usable.sum()), np.float32)),
        }
        columns.append(np.stack([np.square(squared[n].astype(np.float64)) for n in names], axis=1))
        targets.append(np.square(err[usable].astype(np.float64)))
    if not columns:
        raise ValueError("no cell with both an estimate and a label to fit sigma on")
    basis = torch.from_numpy(np.concatenate(columns))  # [N, P] squared features
    err2 = torch.from_numpy(np.concatenate(targets))  # [N]
    active = torch.tensor([n in fit for n in names], dtype=torch.float64)
    first = {"raw": 0.0, "floor": math.log(0.002)}
    start = [first.get(n, math.log(0.05)) for n in names]
    log_coeff = torch.tensor(start, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([log_coeff], lr=0.05)
    fixed = torch.tensor([1.0 if n == "raw" else 0.0 for n in names], dtype=torch.float64)
    for _ in range(iterations):
        optimiser.zero_grad()
        coeff = torch.where(active > 0, log_coeff.exp(), fixed)
        variance = (basis * coeff.square()).sum(dim=1).clamp_min(1e-10)
        loss = 0.5 * (variance.log() + err2 / variance).mean()
        loss.backward()
        optimiser.step()
    fitted = torch.where(active > 0, log_coeff.exp(), fixed).detach().numpy()
    return SigmaModel(**{n: float(c) for n, c in zip(names, fitted, strict=True)})


def calibration_key(backend: str, options: Mapping[str, Any] | None = None) -> str:
    """The calibration tables' key of ``backend`` built with ``options``: its name, and with
    options ``NAME:OPTION=VALUE,...`` (sorted): ``bm:plane_parallax_px=16``."""
    if not options:
        return backend
    return f"{backend}:" + ",".join(f"{key}={options[key]}" for key in sorted(options))


def calibration_for(backend: str, path: Path = CALIBRATION_FILE, *, grid: GridSpec | None = None,
                    far_path: Path = FAR_CALIBRATION_FILE, options: Mapping[str, Any] | None = None
                    ) -> SigmaModel | None:
    """The fitted :class:`SigmaModel` of ``backend`` (None when the table has none).

    Args:
        grid: the grid it answers: one that starts at or beyond the near edge of the grid the far-field
            tables were fitted on (``far_path``'s ``grid``) takes ``backend``'s far-field table when
            there is one; every other grid (and None) the table at ``path``.
        options: the options it was built with: a table fitted with those options
            (:func:`calibration_key`) wins over the backend's own; where the table has none, the
            backend's own (an option that changes how the estimate errs, such as ``bm``'s
            ``plane_parallax_px``, has its own fit).
    """
    keys = [calibration_key(backend, options), backend] if options else [backend]

    def fitted(table: Mapping[str, Any]) -> Any:
        models = table.get("models", {})
        return next((models[key] for key in keys if key in models), None)

    far = json_table(far_path)
    fitted_on = far.get("grid", {}).get("x_min")
    if grid is not None and fitted_on is not None and grid.x_min >= float(fitted_on) - 1e-9:
        entry = fitted(far)
        if entry is not None:
            return SigmaModel.from_dict(entry)
    entry = fitted(json_table(path))
    return None if entry is None else SigmaModel.from_dict(entry)
