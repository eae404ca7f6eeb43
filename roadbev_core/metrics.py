"""The paper's metrics, shared by ``roadbev eval``, the demo and the benchmarks.

Over labelled cells only: absolute error (cm), RMSE (cm), share of cells with error > 0.5 cm (%),
absolute error per distance band (15 bands along x, near to far), and the median and 95th
percentile of the absolute error (a mean can be carried by a few per cent of cells: the
percentiles say whether an estimator is broadly better or has a heavier tail). A labelled cell
without an estimate is *missing*: it lowers ``coverage_pct`` and never counts as zero error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from roadbev_core.config import GridSpec

__all__ = ["N_BANDS", "MetricAccumulator", "Metrics", "differences"]

N_BANDS = 15
# Error histogram for the percentiles: 0.001 cm bins up to 100 cm (larger errors share the top bin).
_HIST_STEP_CM = 0.001
_HIST_BINS = 100_000


@dataclass
class Metrics:
    """Aggregated metrics (JSON keys per the contract)."""

    frames: int
    cells: int
    abs_err_cm: float
    rmse_cm: float
    gt_0p5cm_pct: float
    band_abs_err_cm: list[float]
    coverage_pct: float
    labelled_cells: int
    median_abs_err_cm: float = math.nan
    p95_abs_err_cm: float = math.nan

    def to_dict(self) -> dict[str, object]:
        return {
            "frames": self.frames,
            "cells": self.cells,
            "labelled_cells": self.labelled_cells,
            "abs_err_cm": self.abs_err_cm,
            "rmse_cm": self.rmse_cm,
            "gt_0p5cm_pct": self.gt_0p5cm_pct,
            "band_abs_err_cm": self.band_abs_err_cm,
            "coverage_pct": self.coverage_pct,
            "median_abs_err_cm": self.median_abs_err_cm,
            "p95_abs_err_cm": self.p95_abs_err_cm,
        }


def differences(a: Metrics, b: Metrics) -> dict[str, float]:
    """|a - b| per metric, and the largest band difference (``band_abs_err_cm_max``): how far two
    evaluations of the same frames (online over DDS and offline, say) are apart. NaN where either
    is undefined."""
    out: dict[str, float] = {}
    for key in ("frames", "cells", "abs_err_cm", "rmse_cm", "gt_0p5cm_pct", "coverage_pct"):
        x, y = float(getattr(a, key)), float(getattr(b, key))
        out[key] = abs(x - y) if math.isfinite(x) and math.isfinite(y) else math.nan
    bands_a = np.asarray(a.band_abs_err_cm, np.float64)
    bands_b = np.asarray(b.band_abs_err_cm, np.float64)
    if bands_a.size and bands_a.shape == bands_b.shape:
        diff = np.abs(bands_a - bands_b)
        out["band_abs_err_cm_max"] = float(np.nanmax(diff)) if np.isfinite(diff).any() else math.nan
    return out


@dataclass
class MetricAccumulator:
    """Accumulates per-frame errors; frames may come one at a time (streaming evaluation)."""

    grid: GridSpec
    n_bands: int = N_BANDS
    _abs_sum: float = 0.0
    _sq_sum: float = 0.0
    _over: int = 0
    _cells: int = 0
    _labelled: int = 0
    _frames: int = 0
    _band_sum: np.ndarray = field(init=False)
    _band_cnt: np.ndarray = field(init=False)
    _band_of_row: np.ndarray = field(init=False)
    _hist: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self._hist = np.zeros(_HIST_BINS, dtype=np.int64)
        self._band_sum = np.zeros(self.n_bands)
        self._band_cnt = np.zeros(self.n_bands, dtype=np.int64)
        self._band_of_row = self.grid.band_of_rows(self.n_bands)

    def add(self, estimate: np.ndarray, truth: np.ndarray) -> None:
        """Add one frame.

        Args:
            estimate: [n_rows, n_cols] metres, NaN = no estimate.
            truth: [n_rows, n_cols] metres, NaN = no label.
        """
        if estimate.shape != truth.shape or truth.shape != self.grid.shape:
            raise ValueError(
                f"estimate {estimate.shape} and truth {truth.shape} must match grid {self.grid.shape}"
            )
        labelled = np.isfinite(truth)
        valid = labelled & np.isfinite(estimate)
        err = np.abs(estimate[valid].astype(np.float64) - truth[valid]) * 100.0  # cm
        self._frames += 1
        self._labelled += int(labelled.sum())
        self._cells += int(valid.sum())
        self._abs_sum += float(err.sum())
        self._sq_sum += float(np.square(err).sum())
        self._over += int((err > 0.5).sum())
        rows = np.nonzero(valid)[0]
        bands = self._band_of_row[rows]
        self._band_sum += np.bincount(bands, weights=err, minlength=self.n_bands)
        self._band_cnt += np.bincount(bands, minlength=self.n_bands)
        bins = np.minimum((err / _HIST_STEP_CM).astype(np.int64), _HIST_BINS - 1)
        self._hist += np.bincount(bins, minlength=_HIST_BINS)

    def _percentile(self, share: float) -> float:
        """The absolute error (cm) below which ``share`` of the compared cells lie (bin centre, +-5 um)."""
        if not self._cells:
            return math.nan
        rank = max(1, math.ceil(share * self._cells))
        index = int(np.searchsorted(np.cumsum(self._hist), rank))
        return (index + 0.5) * _HIST_STEP_CM

    def result(self) -> Metrics:
        n = max(self._cells, 1)
        nan = math.nan
        with np.errstate(invalid="ignore", divide="ignore"):
            bands = np.where(self._band_cnt > 0, self._band_sum / np.maximum(self._band_cnt, 1), nan)
        return Metrics(
            frames=self._frames,
            cells=self._cells,
            abs_err_cm=self._abs_sum / n if self._cells else nan,
            rmse_cm=math.sqrt(self._sq_sum / n) if self._cells else nan,
            gt_0p5cm_pct=100.0 * self._over / n if self._cells else nan,
            band_abs_err_cm=[float(b) for b in bands],
            coverage_pct=100.0 * self._cells / max(self._labelled, 1),
            labelled_cells=self._labelled,
            median_abs_err_cm=self._percentile(0.5),
            p95_abs_err_cm=self._percentile(0.95),
        )
