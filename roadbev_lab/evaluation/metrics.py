"""The paper's metrics, shared by ``roadbev eval``, the demo and the benchmarks.

Over labelled cells only: absolute error (cm), RMSE (cm), share of cells with error > 0.5 cm (%),
absolute error per distance band (15 bands along x, near to far), and the median and 95th
percentile of the absolute error (a mean can be carried by a few per cent of cells: the
percentiles say whether an estimator is broadly better or has a heavier tail). A labelled cell
without an estimate is *missing*: it lowers ``coverage_pct`` and never counts as zero error.

The reported 1-sigma uncertainty is scored too (docs/interface/evaluation.md,
"Uncertainty keys"): the share of cells with the error inside 1, 2 and 3 sigma, the share that is *confidently
wrong* (error beyond both 3 sigma and 1 cm: a controller trusting sigma would act on them), the
mean sigma, and a reliability curve (the observed error quantile in bins of predicted sigma: an
honest sigma puts the 68.3 % quantile of the error on the diagonal).

The far-field grid is scored per distance band of whole metres (:class:`BandAccumulator`: error,
coverage and sigma honesty per band), since what the camera resolves falls with range.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from roadbev_core.config import GridSpec

__all__ = [
    "CONFIDENT_WRONG_CM",
    "N_BANDS",
    "RELIABILITY_EDGES_CM",
    "BandAccumulator",
    "MetricAccumulator",
    "Metrics",
    "SigmaAccumulator",
    "differences",
    "distance_bands",
    "reliability_curve",
    "reliability_histogram",
    "sigma_counts",
    "sigma_metrics",
]

N_BANDS = 15
# Error histogram for the percentiles: 0.001 cm bins up to 100 cm (larger errors share the top bin).
_HIST_STEP_CM = 0.001
_HIST_BINS = 100_000
# An error must exceed 3 sigma *and* this (cm) to count as confidently wrong (docs/interface/evaluation.md).
CONFIDENT_WRONG_CM = 1.0
# Predicted-sigma bins of the reliability curve (cm); the last bin is open.
RELIABILITY_EDGES_CM: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, math.inf)
# Error histogram inside each sigma bin: 0.01 cm steps up to 40 cm (larger errors share the top bin).
_REL_STEP_CM = 0.01
_REL_BINS = 4000


@dataclass
class Metrics:
    """Aggregated metrics (JSON keys per docs/interface/evaluation.md)."""

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

    def merge(self, other: MetricAccumulator) -> None:
        """Add another accumulator's frames to this one (the pooled metrics of several
        evaluations: sums and histograms add, so the result is that of all their frames at once).

        Raises:
            ValueError: ``other`` was made on another grid or band count (its bands mean other distances).
        """
        if other.grid != self.grid or other.n_bands != self.n_bands:
            raise ValueError(f"cannot pool metrics of grid {other.grid} ({other.n_bands} bands) into grid "
                             f"{self.grid} ({self.n_bands} bands)")
        self._frames += other._frames
        self._labelled += other._labelled
        self._cells += other._cells
        self._abs_sum += other._abs_sum
        self._sq_sum += other._sq_sum
        self._over += other._over
        self._band_sum += other._band_sum
        self._band_cnt += other._band_cnt
        self._hist += other._hist

    def state(self) -> dict[str, np.ndarray]:
        """The sums and histograms (arrays by name) that :meth:`from_state` rebuilds the
        accumulator from: what a result store keeps to pool an evaluation later."""
        return {
            "counts": np.array([self._frames, self._labelled, self._cells, self._over], np.int64),
            "sums": np.array([self._abs_sum, self._sq_sum], np.float64),
            "band_sum": self._band_sum.copy(),  # [n_bands] cm
            "band_cnt": self._band_cnt.copy(),  # [n_bands]
            "hist": self._hist.copy(),  # [_HIST_BINS]
        }

    @classmethod
    def from_state(cls, grid: GridSpec, state: Mapping[str, np.ndarray]) -> MetricAccumulator:
        """The accumulator of :meth:`state` on ``grid``.

        Raises:
            ValueError: arrays of the wrong shape.
        """
        band_sum = np.asarray(state["band_sum"], np.float64)
        out = cls(grid, n_bands=int(band_sum.size))
        counts, sums = np.asarray(state["counts"], np.int64), np.asarray(state["sums"], np.float64)
        hist = np.asarray(state["hist"], np.int64)
        if counts.shape != (4,) or sums.shape != (2,) or hist.shape != out._hist.shape:
            raise ValueError("not the state of a MetricAccumulator")
        out._frames, out._labelled, out._cells, out._over = (int(v) for v in counts)
        out._abs_sum, out._sq_sum = float(sums[0]), float(sums[1])
        out._band_sum = band_sum.copy()
        out._band_cnt = np.asarray(state["band_cnt"], np.int64).copy()
        out._hist = hist.copy()
        return out

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


# --- uncertainty ------------------------------------------------------------------------------
def sigma_counts(estimate: np.ndarray, sigma: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-frame counts for the uncertainty keys.

    Args:
        estimate: [R, C] metres, NaN = no estimate.
        sigma: [R, C] 1-sigma metres (NaN = none).
        truth: [R, C] metres, NaN = no label.

    Returns:
        [6] float64: labelled cells with an estimate and a finite sigma; of those, the error
        within 1, 2 and 3 sigma; confidently wrong (error > 3 sigma and > 1 cm); the sum of their
        sigma (cm).
    """
    return _counts(*_scored_cells(estimate, sigma, truth))


def _scored_cells(estimate: np.ndarray, sigma: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|estimate - truth| [N] and sigma [N] (m, float64) of the labelled cells with an estimate
    and a finite sigma."""
    usable = np.isfinite(truth) & np.isfinite(estimate) & np.isfinite(sigma)  # [R, C]
    error = np.abs(estimate[usable].astype(np.float64) - truth[usable])  # [N] m
    return error, sigma[usable].astype(np.float64)


def _counts(error: np.ndarray, s: np.ndarray) -> np.ndarray:
    """[6] :func:`sigma_counts` of errors [N] and their sigma [N] (m)."""
    wrong = (error > 3.0 * s) & (error > CONFIDENT_WRONG_CM / 100.0)
    return np.array(
        [error.size, (error <= s).sum(), (error <= 2.0 * s).sum(), (error <= 3.0 * s).sum(), wrong.sum(),
         100.0 * s.sum()],
        np.float64,
    )


def sigma_metrics(counts: np.ndarray) -> dict[str, float | int]:
    """The uncertainty keys (docs/interface/evaluation.md) from summed :func:`sigma_counts` (NaN without any sigma)."""
    n = int(counts[0])

    def pct(value: float) -> float:
        return 100.0 * value / n if n else math.nan

    return {
        "sigma_cells": n,
        "within_1sigma_pct": pct(counts[1]),
        "within_2sigma_pct": pct(counts[2]),
        "within_3sigma_pct": pct(counts[3]),
        "confident_wrong_pct": pct(counts[4]),
        "mean_sigma_cm": float(counts[5]) / n if n else math.nan,
    }


@dataclass
class SigmaAccumulator:
    """Sums the uncertainty scores over frames (streaming, like :class:`MetricAccumulator`):
    :func:`sigma_counts` and :func:`reliability_histogram`, so that ``roadbev eval``, the online
    evaluation over DDS and the demo's report score a sigma with one piece of code."""

    edges: tuple[float, ...] = RELIABILITY_EDGES_CM
    _counts: np.ndarray = field(init=False)  # [6] sigma_counts, summed
    _histogram: np.ndarray = field(init=False)  # [B, _REL_BINS] reliability_histogram counts, summed
    _sigma_sum: np.ndarray = field(init=False)  # [B] sigma (cm) per sigma bin, summed

    def __post_init__(self) -> None:
        self._counts = np.zeros(6, np.float64)
        self._histogram = np.zeros((len(self.edges) - 1, _REL_BINS), np.int64)
        self._sigma_sum = np.zeros(len(self.edges) - 1, np.float64)

    def add(self, estimate: np.ndarray, sigma: np.ndarray, truth: np.ndarray) -> None:
        """Add one frame.

        Args:
            estimate: [R, C] metres, NaN = no estimate.
            sigma: [R, C] the estimate's 1-sigma (m), NaN = none.
            truth: [R, C] metres, NaN = no label.
        """
        if not estimate.shape == sigma.shape == truth.shape:
            raise ValueError(f"estimate {estimate.shape}, sigma {sigma.shape} and truth {truth.shape} must match")
        error, s = _scored_cells(estimate, sigma, truth)  # [N] m each
        counts, sigma_sum = reliability_histogram(100.0 * error, 100.0 * s, self.edges)
        self._histogram += counts
        self._sigma_sum += sigma_sum
        self._counts += _counts(error, s)

    def merge(self, other: SigmaAccumulator) -> None:
        """Add another accumulator's frames to this one (pooled over several evaluations).

        Raises:
            ValueError: ``other`` bins sigma with other edges.
        """
        if tuple(other.edges) != tuple(self.edges):
            raise ValueError(f"cannot pool sigma scores binned at {other.edges} into {self.edges}")
        self._counts += other._counts
        self._histogram += other._histogram
        self._sigma_sum += other._sigma_sum

    def state(self) -> dict[str, np.ndarray]:
        """The sums (arrays by name) that :meth:`from_state` rebuilds the accumulator from."""
        return {"counts": self._counts.copy(), "histogram": self._histogram.copy(),
                "sigma_sum": self._sigma_sum.copy(), "edges": np.asarray(self.edges, np.float64)}

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray]) -> SigmaAccumulator:
        """The accumulator of :meth:`state`.

        Raises:
            ValueError: arrays of the wrong shape.
        """
        out = cls(edges=tuple(float(e) for e in np.asarray(state["edges"], np.float64)))
        counts = np.asarray(state["counts"], np.float64)
        histogram = np.asarray(state["histogram"], np.int64)
        sigma_sum = np.asarray(state["sigma_sum"], np.float64)
        if counts.shape != out._counts.shape or histogram.shape != out._histogram.shape or \
                sigma_sum.shape != out._sigma_sum.shape:
            raise ValueError("not the state of a SigmaAccumulator")
        out._counts, out._histogram, out._sigma_sum = counts.copy(), histogram.copy(), sigma_sum.copy()
        return out

    def result(self) -> dict[str, object]:
        """The uncertainty keys (:func:`sigma_metrics`) and ``reliability``
        (:func:`reliability_curve`, an empty list before any cell with a sigma)."""
        return {**sigma_metrics(self._counts), "reliability": reliability_curve(self._histogram, self._sigma_sum,
                                                                                 self.edges)}


def reliability_histogram(
    abs_err_cm: np.ndarray, sigma_cm: np.ndarray, edges: tuple[float, ...] = RELIABILITY_EDGES_CM
) -> tuple[np.ndarray, np.ndarray]:
    """Counts of the error per predicted-sigma bin (sums over frames add up).

    Args:
        abs_err_cm: [N] absolute errors (cm) of cells with a finite sigma.
        sigma_cm: [N] their 1-sigma (cm).
        edges: [B + 1] sigma bin edges (cm), increasing.

    Returns:
        counts [B, _REL_BINS] int64 (error in 0.01 cm steps, the top bin open) and the sigma sum
        per bin [B] float64 (cm).
    """
    n_bins = len(edges) - 1
    which = np.clip(np.searchsorted(np.asarray(edges), sigma_cm, side="right") - 1, 0, n_bins - 1)  # [N]
    err_bin = np.minimum((abs_err_cm / _REL_STEP_CM).astype(np.int64), _REL_BINS - 1)  # [N]
    counts = np.bincount(which * _REL_BINS + err_bin, minlength=n_bins * _REL_BINS).reshape(n_bins, _REL_BINS)
    sigma_sum = np.bincount(which, weights=sigma_cm, minlength=n_bins).astype(np.float64)
    return counts.astype(np.int64), sigma_sum


def reliability_curve(
    counts: np.ndarray,
    sigma_sum: np.ndarray,
    edges: tuple[float, ...] = RELIABILITY_EDGES_CM,
    quantiles: tuple[float, ...] = (0.683, 0.954),
) -> list[dict[str, float | int]]:
    """Observed error quantiles against predicted sigma, one entry per non-empty sigma bin.

    For an honest Gaussian sigma the 68.3 % quantile of the error equals the bin's mean sigma and
    the 95.4 % quantile twice it.

    Args:
        counts, sigma_sum: from :func:`reliability_histogram` (summed over frames).
        edges: the sigma bin edges (cm) they were made with.
        quantiles: error quantiles to report.

    Returns:
        dicts with ``sigma_lo_cm``, ``sigma_hi_cm``, ``cells``, ``mean_sigma_cm`` and
        ``q<percent>_abs_err_cm`` per quantile (e.g. ``q68_abs_err_cm``), bin-centre resolution.
    """
    out: list[dict[str, float | int]] = []
    for b in range(counts.shape[0]):
        cells = int(counts[b].sum())
        if cells == 0:
            continue
        cumulative = np.cumsum(counts[b])
        entry: dict[str, float | int] = {
            "sigma_lo_cm": float(edges[b]),
            "sigma_hi_cm": float(edges[b + 1]),
            "cells": cells,
            "mean_sigma_cm": float(sigma_sum[b]) / cells,
        }
        for q in quantiles:
            index = int(np.searchsorted(cumulative, max(1, math.ceil(q * cells))))
            entry[f"q{int(q * 100)}_abs_err_cm"] = (index + 0.5) * _REL_STEP_CM
        out.append(entry)
    return out


# --- per distance band ------------------------------------------------------------------------
def distance_bands(grid: GridSpec, band_m: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Bands of ``band_m`` metres of x (whole multiples: 7-8 m, 8-9 m...) over a grid.

    Returns:
        [n_rows] the band (0 = nearest) of each row, by its centre's x, and [B, 2] each band's
        x range (m), the nominal band cut to the grid's extent.
    """
    if not band_m > 0:
        raise ValueError(f"band width must be positive, got {band_m}")
    index = np.floor(grid.x_centres() / band_m + 1e-9).astype(np.int64)  # [n_rows]
    first = int(index.min())
    lower = (np.arange(first, int(index.max()) + 1) * band_m).astype(np.float64)  # [B]
    edges = np.stack([np.maximum(lower, grid.x_min), np.minimum(lower + band_m, grid.x_max)], axis=1)
    return index - first, np.round(edges, 9)


@dataclass
class BandAccumulator:
    """Error, coverage and sigma honesty per distance band (:func:`distance_bands`), summed over
    frames (streaming, like :class:`MetricAccumulator`)."""

    grid: GridSpec
    band_m: float = 1.0
    _band_of_row: np.ndarray = field(init=False)
    _edges: np.ndarray = field(init=False)
    _labelled: np.ndarray = field(init=False)  # [B] labelled cells
    _cells: np.ndarray = field(init=False)  # [B] labelled cells with an estimate
    _abs_sum: np.ndarray = field(init=False)  # [B] their absolute error (cm)
    _sigma: np.ndarray = field(init=False)  # [B, 6] sigma_counts

    def __post_init__(self) -> None:
        self._band_of_row, self._edges = distance_bands(self.grid, self.band_m)
        bands = self._edges.shape[0]
        self._labelled = np.zeros(bands, np.int64)
        self._cells = np.zeros(bands, np.int64)
        self._abs_sum = np.zeros(bands, np.float64)
        self._sigma = np.zeros((bands, 6), np.float64)

    def add(self, estimate: np.ndarray, sigma: np.ndarray, truth: np.ndarray) -> None:
        """Add one frame ([n_rows, n_cols] metres each; NaN = no estimate, sigma or label)."""
        if not estimate.shape == sigma.shape == truth.shape == self.grid.shape:
            raise ValueError(f"estimate {estimate.shape}, sigma {sigma.shape} and truth {truth.shape} must match "
                             f"grid {self.grid.shape}")
        for band in range(self._edges.shape[0]):
            rows = self._band_of_row == band
            e, s, t = estimate[rows], sigma[rows], truth[rows]
            labelled = np.isfinite(t)
            valid = labelled & np.isfinite(e)
            self._labelled[band] += int(labelled.sum())
            self._cells[band] += int(valid.sum())
            self._abs_sum[band] += 100.0 * float(np.abs(e[valid].astype(np.float64) - t[valid]).sum())
            self._sigma[band] += sigma_counts(e, s, t)

    def result(self) -> list[dict[str, float | int]]:
        """One dict per band, near to far: ``x_from_m``, ``x_to_m``, ``labelled_cells``, ``cells``,
        ``coverage_pct``, ``abs_err_cm`` and the uncertainty keys (:func:`sigma_metrics`); NaN
        where a band has nothing to score."""
        out: list[dict[str, float | int]] = []
        for band, (lo, hi) in enumerate(self._edges):
            cells, labelled = int(self._cells[band]), int(self._labelled[band])
            out.append({
                "x_from_m": float(lo),
                "x_to_m": float(hi),
                "labelled_cells": labelled,
                "cells": cells,
                "coverage_pct": 100.0 * cells / labelled if labelled else math.nan,
                "abs_err_cm": float(self._abs_sum[band]) / cells if cells else math.nan,
                **sigma_metrics(self._sigma[band]),
            })
        return out
