"""The metrics of several evaluated bags pooled: computed from their sums, never from their means.

``roadbev eval`` over many bags reports each bag's metrics and the pooled ones: those of all the
bags' frames (and, on drive bags, all their wheel path points and map windows) at once, as if one
evaluation had seen them all. A mean of per-bag means would weigh a 10-frame bag like a 10,000-frame
one and cannot give a pooled median or 95th percentile at all; sums, counts and histograms add up.

:class:`BagSums` is what one bag's evaluation leaves for that
(:attr:`roadbev_lab.evaluation.offline.BagEvaluation.sums`):

* the frame metrics' sums and histograms (:class:`roadbev_lab.evaluation.frames.EvalSums`);
* the counts: frames lost in the bag, frames the map skipped;
* on a drive bag, each front wheel's path points (:class:`roadbev_lab.evaluation.arrival.WheelErrors`)
  and each map window's scores (:func:`roadbev_lab.evaluation.arrival.map_window_rows`).

:meth:`BagSums.merge` adds two; :meth:`BagSums.metrics` gives the keys of ``roadbev eval --json``
(docs/interface/evaluation.md) from them, so the metrics of one bag's sums are that bag's own.
:meth:`BagSums.to_arrays` and :meth:`BagSums.from_arrays` keep them in a ``.npz`` file (a result
store's entry) and read them back.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from roadbev_core.config import GridSpec
from roadbev_core.errors import RoadbevError
from roadbev_lab.evaluation.arrival import WheelErrors, map_summary, summarise_errors
from roadbev_lab.evaluation.frames import EvalSums, json_safe
from roadbev_lab.evaluation.metrics import MetricAccumulator, SigmaAccumulator

__all__ = ["BagSums", "PoolingError"]


class PoolingError(ValueError):
    """Sums that cannot be pooled (another backend, grid or lead time), or arrays that are not sums."""


@dataclass
class BagSums:
    """What the pooled metrics of bags are computed from (see the module docstring).

    Attributes:
        frames: the frame metrics' sums.
        lost_frames: frames lost to damage in the bags.
        map_enabled: whether the fused map ran.
        map_skipped: reason -> frames the map did not fuse.
        lead_time_s: the preview-at-arrival lead time (drive bags; None otherwise).
        wheels: front wheel -> its path points (drive bags with ground truth; None otherwise).
        map_rows: :data:`roadbev_lab.evaluation.arrival.MAP_KEYS` key -> its value per map window
            (None without windows).
        map_windows: map windows published.
    """

    frames: EvalSums
    lost_frames: int = 0
    map_enabled: bool = False
    map_skipped: dict[str, int] = field(default_factory=dict)
    lead_time_s: float | None = None
    wheels: dict[str, WheelErrors] | None = None
    map_rows: dict[str, list[float]] | None = None
    map_windows: int = 0

    @property
    def grid(self) -> GridSpec:
        """The grid the frame metrics were computed on (sums pool only on the same grid)."""
        return self.frames.accuracy.grid

    def merge(self, other: BagSums) -> BagSums:
        """These sums and ``other``'s added, as a new object.

        Raises:
            PoolingError: another backend, grid or lead time.
        """
        try:
            frames = self.frames.merge(other.frames)
        except ValueError as exc:
            raise PoolingError(str(exc)) from None
        if self.wheels is not None and other.wheels is not None and self.lead_time_s != other.lead_time_s:
            raise PoolingError(f"cannot pool previews at arrival with lead {other.lead_time_s} s into "
                               f"{self.lead_time_s} s")
        skipped = dict(self.map_skipped)
        for reason, n in other.map_skipped.items():
            skipped[reason] = skipped.get(reason, 0) + n
        return BagSums(frames, self.lost_frames + other.lost_frames, self.map_enabled or other.map_enabled, skipped,
                       self.lead_time_s if self.lead_time_s is not None else other.lead_time_s,
                       _concat_wheels(self.wheels, other.wheels), _concat_rows(self.map_rows, other.map_rows),
                       self.map_windows + other.map_windows)

    def metrics(self) -> dict[str, Any]:
        """The keys of ``roadbev eval --json`` (without ``losses``, ``bag``, ``grid``,
        ``backend_options`` and ``params_file``, which name one bag), JSON-safe."""
        out: dict[str, Any] = json_safe(self.frames.metrics())
        if self.map_enabled:
            out["map_enabled"] = True
            if self.map_skipped:
                out["map_skipped"] = dict(self.map_skipped)
        out["lost_frames"] = self.lost_frames
        if self.wheels and self.lead_time_s is not None:
            out["preview_at_arrival"] = json_safe(summarise_errors(self.wheels, self.lead_time_s))
        if self.map_rows is not None:
            out["map"] = json_safe(map_summary(self.map_rows, self.map_windows))
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Every sum as arrays by name (``np.savez`` keeps them; :meth:`from_arrays` reads them)."""
        arrays = {f"accuracy.{k}": v for k, v in self.frames.accuracy.state().items()}
        arrays.update({f"sigma.{k}": v for k, v in self.frames.sigma.state().items()})
        scalars = {"backend": self.frames.backend, "grid": self.frames.accuracy.grid.to_dict(),
                   "frames": self.frames.frames,
                   "timed_frames": self.frames.timed_frames, "decode_ms_sum": self.frames.decode_ms_sum,
                   "estimate_ms_sum": self.frames.estimate_ms_sum, "stage_ms_sum": self.frames.stage_ms_sum,
                   "lost_frames": self.lost_frames, "map_enabled": self.map_enabled,
                   "map_skipped": self.map_skipped, "lead_time_s": self.lead_time_s,
                   "wheels": None if self.wheels is None else list(self.wheels),
                   "map_rows": self.map_rows, "map_windows": self.map_windows}
        # floats as JSON text keep every bit (repr round-trips); the arrays keep theirs
        arrays["scalars"] = np.array(json.dumps(scalars))
        for name, wheel in (self.wheels or {}).items():
            arrays.update({f"wheel.{name}.{k}": np.asarray(v) for k, v in wheel._asdict().items()})
        return arrays

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> BagSums:
        """The sums of :meth:`to_arrays`.

        Raises:
            PoolingError: arrays that are not :meth:`to_arrays`'.
        """
        try:
            scalars = json.loads(str(arrays["scalars"]))
            grid = GridSpec.from_dict(scalars["grid"])
            accuracy = MetricAccumulator.from_state(grid, _prefixed(arrays, "accuracy."))
            sigma = SigmaAccumulator.from_state(_prefixed(arrays, "sigma."))
            frames = EvalSums(str(scalars["backend"]), accuracy, sigma, int(scalars["frames"]),
                              int(scalars["timed_frames"]), float(scalars["decode_ms_sum"]),
                              float(scalars["estimate_ms_sum"]),
                              {str(k): float(v) for k, v in scalars["stage_ms_sum"].items()})
            wheels = None if scalars["wheels"] is None else {
                name: _wheel_errors(_prefixed(arrays, f"wheel.{name}.")) for name in scalars["wheels"]}
            rows = scalars["map_rows"]
            return cls(frames, int(scalars["lost_frames"]), bool(scalars["map_enabled"]),
                       {str(k): int(v) for k, v in scalars["map_skipped"].items()},
                       None if scalars["lead_time_s"] is None else float(scalars["lead_time_s"]), wheels,
                       None if rows is None else {str(k): [float(v) for v in vs] for k, vs in rows.items()},
                       int(scalars["map_windows"]))
        except (KeyError, TypeError, ValueError, RoadbevError) as exc:
            raise PoolingError(f"not the sums of an evaluation: {type(exc).__name__}: {exc}") from None


def _wheel_errors(arrays: Mapping[str, np.ndarray]) -> WheelErrors:
    """One wheel's points as :meth:`BagSums.to_arrays` stored them (sums stored before the points
    carried the preview's sigma have none: NaN)."""
    fields = dict(arrays)
    fields.setdefault("sigma", np.full(np.shape(fields["error"]), np.nan))
    return WheelErrors(**fields)


def _concat_wheels(first: dict[str, WheelErrors] | None,
                   second: dict[str, WheelErrors] | None) -> dict[str, WheelErrors] | None:
    """Each wheel's points of ``first`` followed by those of ``second`` (None: no drive bag)."""
    if first is None or second is None:
        return second if first is None else first
    out = dict(first)
    for name, points in second.items():
        out[name] = out[name].concat(points) if name in out else points
    return out


def _concat_rows(first: dict[str, list[float]] | None,
                 second: dict[str, list[float]] | None) -> dict[str, list[float]] | None:
    """Each key's window scores of ``first`` followed by those of ``second`` (None: no map windows)."""
    if first is None or second is None:
        return second if first is None else first
    return {k: [*first.get(k, []), *second.get(k, [])] for k in {**first, **second}}


def _prefixed(arrays: Mapping[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    return {k[len(prefix):]: np.asarray(v) for k, v in arrays.items() if k.startswith(prefix)}
