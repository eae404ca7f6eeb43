"""The demo's drive: the fused map, the previews at arrival, hazards and the ride, map on and off.

Besides its ROS 2 run on the evaluation drive, ``roadbev demo`` writes (or reuses from its cache)
a short drive where the car rides on its road (:class:`roadbev_lab.synth.RidingDrive`, as
``roadbev synth --drive``: :func:`drive_config`, seed :data:`DRIVE_SEED`, 10 m/s, camera at 10 Hz,
ISO 8608 class C with a speed bump and a pothole every ~5 m) and evaluates it twice, with the
fused map on and off, through :mod:`roadbev_lab.evaluation.offline` (what ``roadbev eval --map`` /
``--no-map`` run, so the numbers are theirs). From the two runs' outputs it derives:

* the preview at arrival of both front wheels, point by point
  (:func:`roadbev_lab.evaluation.arrival.arrival_points`, the points behind the ``preview_at_arrival`` keys);
* the fused map over the drive (:func:`mosaic`: every cell as the map last held it) with the car's
  path, and the hazards :func:`roadbev_core.hazards.detect_hazards` finds on it against the road's
  true features (:func:`match_hazards`);
* the ride of the quarter-car preview controller over the drive's true road
  (:func:`roadbev_core.ride.ride`): passive, the controller without preview, fed with the
  per-frame previews, with the fused map's previews (their contact plane's attitude undone, as the
  message carries it) and with the true road (the ceiling), and each preview's share of the
  ceiling's gain.

With ``roadbev demo --bag DRIVE`` on a drive bag the same runs on that bag; its true features are
then unknown and the hazards are compared with those the detector finds on the bag's true road map
over the same cells.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple, NoReturn

import numpy as np
from tqdm import tqdm

from roadbev_core.config import DEFAULT_BACKEND, RoadbevConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.fusion import MapWindow
from roadbev_core.hazards import Hazard, HazardError, detect_hazards
from roadbev_core.pipeline import check_config
from roadbev_core.ride import RideError
from roadbev_lab.evaluation.arrival import (
    ArrivalError,
    ArrivalPoints,
    RoadMap,
    TimedPreview,
    arrival_points,
    per_frame_previews,
)
from roadbev_lab.evaluation.drivebag import arrival_settings, read_drive_truth
from roadbev_lab.evaluation.frames import to_json
from roadbev_lab.evaluation.offline import BagEvaluation, OfflineEvalError, prepare_bag, run_prepared
from roadbev_lab.ride import RideSettings, gain_share, ride
from roadbev_lab.ride.simulate import Source
from roadbev_lab.synth import REAL_ROAD_MIDDLE, DriveConfig, RidingConfig, RoadConfig

__all__ = [
    "DEFAULT_DRIVE_FRAMES",
    "DRIVE_FEATURES",
    "DRIVE_SEED",
    "DriveSection",
    "FeatureMatch",
    "MapMosaic",
    "TrueFeature",
    "drive_config",
    "features_path",
    "match_hazards",
    "message_plane_slopes",
    "mosaic",
    "run_drive_section",
]

# The demo drive's own seed: disjoint from training (< 1e5), test (1e5+), tuning (2e5+), the map's
# tuning drive (300001), bench_arrival / bench_ride (310000+) and bench_map / bench_hazards (320000+).
DRIVE_SEED = 330_000
DEFAULT_DRIVE_FRAMES = 20
DRIVE_SPEED_MPS = 10.0
DRIVE_RATE_HZ = 10.0
DRIVE_FEATURES: tuple[str, ...] = ("speed_bump", "pothole")
DRIVE_FEATURE_SPACING_M = 5.0
_BUMPS = ("speed_bump", "hump")
MATCH_ALONG_M = 0.5  # a detection matches a feature this close along x (potholes also across y)
MIN_FEATURE_M = 0.03  # features scored: |height| >= 3 cm (the hazards issue's target)


class DriveDemoError(RoadbevError, RuntimeError):
    """The drive section cannot run (a bag that is not a drive, a drive too short to ride...)."""


def drive_config(frames: int = DEFAULT_DRIVE_FRAMES, seed: int = DRIVE_SEED, image_scale: float = 1.0
                 ) -> RidingConfig:
    """The demo's drive: ``frames`` camera frames at 10 Hz and 10 m/s over an ISO 8608 class C
    road with a speed bump and a pothole every ~5 m, the motion continuing 1.5 s after the last
    frame (the ride's ceiling needs the road ahead)."""
    road = REAL_ROAD_MIDDLE.apply(
        RoadConfig(road_class="C", features=DRIVE_FEATURES, feature_spacing_m=DRIVE_FEATURE_SPACING_M))
    drive = DriveConfig(frames=frames, speed_mps=DRIVE_SPEED_MPS, frame_rate_hz=DRIVE_RATE_HZ, seed=seed, road=road)
    if image_scale != 1.0:
        drive = replace(drive, camera=drive.camera.scaled(image_scale))
    return RidingConfig(drive=drive, tail_s=1.5)


def features_path(bag: Path) -> Path:
    """Where the cache keeps a synthetic drive's true features (next to its bag)."""
    return bag.with_name(bag.stem + ".features.json")


# --------------------------------------------------------------------------------------------
# the fused map over the drive
# --------------------------------------------------------------------------------------------
class MapMosaic(NamedTuple):
    """The fused map over a whole drive, grid_map order (row 0 at the largest x, column 0 at the
    largest y), in ``odom``: every cell as the last published window that held it had it.

    Attributes:
        elevation, uncertainty, observations: [R, C] float32 (NaN = never held).
        resolution: cell size (m).
        centre: (x, y) of the mosaic's centre.
        local_uncertainty: [R, C] float32, ``uncertainty`` without the datum's part
            (:meth:`roadbev_core.fusion.MapWindow.local_uncertainty`): what a cell's height is
            worth against the cells around it (hazards).
    """

    elevation: np.ndarray
    uncertainty: np.ndarray
    observations: np.ndarray
    resolution: float
    centre: tuple[float, float]
    local_uncertainty: np.ndarray

    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the mosaic's cells' outer edges."""
        n_rows, n_cols = self.elevation.shape
        r = self.resolution
        return (self.centre[0] - 0.5 * n_rows * r, self.centre[0] + 0.5 * n_rows * r,
                self.centre[1] - 0.5 * n_cols * r, self.centre[1] + 0.5 * n_cols * r)

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """[R] x and [C] y of the cell centres."""
        n_rows, n_cols = self.elevation.shape
        r = self.resolution
        return (self.centre[0] + 0.5 * n_rows * r - (np.arange(n_rows) + 0.5) * r,
                self.centre[1] + 0.5 * n_cols * r - (np.arange(n_cols) + 0.5) * r)


def mosaic(windows: Sequence[MapWindow]) -> MapMosaic:
    """Paste fused-map windows (in stamp order) into one
    map of the drive; a later window's known cell replaces an earlier one's.

    Raises:
        DriveDemoError: no windows, or windows of different resolutions or off one cell lattice.
    """
    if not windows:
        raise DriveDemoError("no fused-map windows to paste")
    res = float(windows[0].resolution)
    if any(abs(float(w.resolution) - res) > 1e-9 for w in windows):
        raise DriveDemoError("fused-map windows of different resolutions")
    tops = [w.centre[0] + 0.5 * w.elevation.shape[0] * res for w in windows]  # largest x edge
    lefts = [w.centre[1] + 0.5 * w.elevation.shape[1] * res for w in windows]  # largest y edge
    x_top, y_left = max(tops), max(lefts)
    x_bottom = min(w.centre[0] - 0.5 * w.elevation.shape[0] * res for w in windows)
    y_right = min(w.centre[1] - 0.5 * w.elevation.shape[1] * res for w in windows)
    n_rows, n_cols = int(round((x_top - x_bottom) / res)), int(round((y_left - y_right) / res))
    names = ("elevation", "uncertainty", "observations", "local_uncertainty")
    layers = {k: np.full((n_rows, n_cols), np.nan, np.float32) for k in names}
    for w, top, left in zip(windows, tops, lefts, strict=True):
        r0f, c0f = (x_top - top) / res, (y_left - left) / res
        r0, c0 = int(round(r0f)), int(round(c0f))
        if abs(r0f - r0) > 1e-3 or abs(c0f - c0) > 1e-3:
            raise DriveDemoError("fused-map windows off one cell lattice")
        rows, cols = w.elevation.shape
        known = np.isfinite(w.elevation)
        sources = {**w.layers(), "local_uncertainty": w.local_uncertainty()}
        for name in layers:
            dest = layers[name][r0: r0 + rows, c0: c0 + cols]
            dest[known] = np.asarray(sources[name], np.float32)[known]
    centre = (0.5 * (x_top + x_bottom), 0.5 * (y_left + y_right))
    return MapMosaic(layers["elevation"], layers["uncertainty"], layers["observations"], res, centre,
                     layers["local_uncertainty"])


# --------------------------------------------------------------------------------------------
# hazards against the true features
# --------------------------------------------------------------------------------------------
class TrueFeature(NamedTuple):
    """A road feature as the drive placed it (``features_in_odom``): kind, position in ``odom``,
    height (a pothole's depth negative)."""

    name: str
    x: float
    y: float
    height_m: float


class FeatureMatch(NamedTuple):
    """A true feature and the detection that found it (None: missed)."""

    feature: TrueFeature
    detection: Hazard | None


def _mapped(feature: TrueFeature, m: MapMosaic) -> bool:
    """Whether the fused map held the feature: a known cell within 0.2 m of a pothole's centre, or
    (a bump spans the lane) any known cell across the map at the bump's x."""
    xs, ys = m.cell_centres()
    row = int(np.argmin(np.abs(xs - feature.x)))
    if abs(xs[row] - feature.x) > m.resolution:
        return False
    if feature.name in _BUMPS:
        return bool(np.isfinite(m.elevation[row]).any())
    near_r = np.abs(xs - feature.x) <= 0.2
    near_c = np.abs(ys - feature.y) <= 0.2
    return bool(np.isfinite(m.elevation[np.ix_(near_r, near_c)]).any())


def match_hazards(hazards: Sequence[Hazard], features: Sequence[TrueFeature],
                  m: MapMosaic) -> tuple[list[FeatureMatch], list[Hazard]]:
    """The true features of >= 3 cm that the map held, each with the nearest detection of its kind
    within 0.5 m along x (potholes also across y), and the detections that match no feature.

    Returns:
        (matches in x order, false alarms: detections within the map's x range matching none).
    """
    kind_of = {name: "bump" for name in _BUMPS} | {"pothole": "pothole"}
    scored = sorted((f for f in features if f.name in kind_of and abs(f.height_m) >= MIN_FEATURE_M and _mapped(f, m)),
                    key=lambda f: f.x)
    used: set[int] = set()
    matches = []
    for f in scored:
        hits = [i for i, h in enumerate(hazards) if h.kind == kind_of[f.name] and abs(h.x - f.x) < MATCH_ALONG_M
                and (f.name in _BUMPS or abs(h.y - f.y) < MATCH_ALONG_M)]
        best = min(hits, key=lambda i: abs(hazards[i].x - f.x), default=None)
        if best is not None:
            used.add(best)
        matches.append(FeatureMatch(f, None if best is None else hazards[best]))
    # a detection next to any placed feature (also one under 3 cm or of another kind) is no false alarm
    false = [h for i, h in enumerate(hazards) if i not in used
             and not any(abs(h.x - f.x) < MATCH_ALONG_M for f in features)]
    return matches, false


# --------------------------------------------------------------------------------------------
# the ride
# --------------------------------------------------------------------------------------------
def message_plane_slopes(msg: TimedPreview) -> tuple[float, float] | None:
    """(dz/dx, dz/dy) of a contact-plane message's own plane (``RoadPreview``'s contact plane:
    ``z = height - x tan(pitch) + y tan(roll) / cos(pitch)``), what a controller undoes; None for
    messages without one."""
    plane = getattr(msg.profiles, "contact_plane", None)
    if plane is None:
        return None
    return -math.tan(plane.pitch), math.tan(plane.roll) / math.cos(plane.pitch)


RIDE_ROWS: tuple[tuple[str, str], ...] = (
    ("passive", "passive (no actuator)"),
    ("no_preview", "controller without preview"),
    ("per_frame", "per-frame preview (map off)"),
    ("fused", "fused-map preview (map on)"),
    ("true_road", "true road (the ceiling)"),
)


# --------------------------------------------------------------------------------------------
# the section
# --------------------------------------------------------------------------------------------
@dataclass
class DriveSection:
    """What the report shows of the drive.

    Attributes:
        bag: the drive bag.
        reused: whether it came from the cache.
        seed: the synthetic drive's seed (None for ``--bag``).
        map_on, map_off: the ``roadbev eval --map`` / ``--no-map`` JSON keys.
        points_on, points_off: the previews at arrival per front wheel.
        fused: the fused map over the drive.
        truth: the true road.
        path_xy: [K, 2] the true path of ``base_link`` in ``odom``.
        hazards: detections on the fused map; reference: the features compared with (true,
            or detected on the true road map: ``reference_kind``).
        matches, false_alarms: see :func:`match_hazards`.
        ride: source -> ``ride()`` rows (``mean`` and per wheel), ``share`` per preview row.
        ride_span_s: (warm-up, scored seconds).
        notes: how it was made.
        seconds: wall time per stage.
        online: ``preview_at_arrival`` and ``map`` of the ROS 2 node's recorded outputs when the
            demo's ROS 2 stage ran on this same bag (``roadbev demo --bag DRIVE``), else None.
    """

    bag: Path
    reused: bool
    seed: int | None
    map_on: dict[str, Any]
    map_off: dict[str, Any]
    points_on: list[ArrivalPoints]
    points_off: list[ArrivalPoints]
    fused: MapMosaic
    truth: RoadMap
    path_xy: np.ndarray
    hazards: list[Hazard]
    reference: list[TrueFeature]
    reference_kind: str
    matches: list[FeatureMatch]
    false_alarms: list[Hazard]
    ride: dict[str, Any]
    ride_span_s: tuple[float, float]
    notes: list[str] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    online: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The numbers of the section (report.json)."""
        def hazard(h: Hazard | None) -> dict[str, Any] | None:
            return None if h is None else dict(h._asdict())

        return {
            "bag": str(self.bag),
            "seed": self.seed,
            "map_on": self.map_on,
            "map_off": self.map_off,
            "online": self.online,
            "hazards": {
                "detected": [hazard(h) for h in self.hazards],
                "reference": self.reference_kind,
                "features": [{**f._asdict(), "detection": hazard(d)} for f, d in self.matches],
                "false_alarms": [hazard(h) for h in self.false_alarms],
            },
            "ride": self.ride,
            "ride_warmup_s": self.ride_span_s[0],
            "ride_scored_s": self.ride_span_s[1],
            "notes": self.notes,
        }


def _read_features(bag: Path) -> list[TrueFeature] | None:
    path = features_path(bag)
    if not path.is_file():
        return None
    return [TrueFeature(str(f[0]), float(f[1]), float(f[2]), float(f[3])) for f in json.loads(path.read_text())]


def _truth_hazards(truth: RoadMap, m: MapMosaic) -> list[TrueFeature]:
    """Hazards of the true road map over the cells the fused map held: the reference when the
    bag's true features are unknown."""
    xs, ys = m.cell_centres()
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    z = truth.height(gx, gy).astype(np.float32)
    z[~np.isfinite(m.elevation)] = np.nan
    kind = {"bump": "speed_bump", "pothole": "pothole"}
    return [TrueFeature(kind[h.kind], h.x, h.y, h.height_m) for h in detect_hazards(z, None, m.resolution, m.centre)]


def run_drive_section(
    bag_path: Path,
    *,
    backend: str = DEFAULT_BACKEND,
    reused: bool = False,
    seed: int | None = None,
    lead_time_s: float = 0.1,
    bar: Callable[[int, str], tqdm[NoReturn]] | None = None,
) -> DriveSection:
    """Evaluate a drive bag with the map on and off and derive everything the report shows.

    Args:
        bag_path: a drive bag (with odometry, ``/ground_truth/odom`` and the road map).
        backend: the pipeline's backend.
        reused, seed: what the report says about the bag.
        lead_time_s: the preview-at-arrival lead time and the controller's latency.
        bar: ``(total, label)`` -> a progress bar (context manager with ``update``), or None.

    Raises:
        DriveDemoError: the bag is not a drive bag with odometry, or a stage fails.
    """
    seconds: dict[str, float] = {}
    runs: dict[bool, BagEvaluation] = {}
    settings = check_config(RoadbevConfig.from_params({"backend": backend}))
    for enabled in (True, False):
        t0 = time.monotonic()
        label = "map on" if enabled else "map off"
        try:
            prepared = prepare_bag(bag_path, settings, map_enabled=enabled)
            if not prepared.drive:
                raise DriveDemoError(f"{bag_path} is not a drive bag (no /ground_truth/odom and road map)")
            if bar is None:
                runs[enabled] = run_prepared(prepared, lead_time_s=lead_time_s)
            else:
                with bar(len(prepared.bag), label) as b:
                    runs[enabled] = run_prepared(prepared, lead_time_s=lead_time_s, progress=b.update)
        except OfflineEvalError as exc:
            raise DriveDemoError(f"drive, {label}: {exc}") from exc
        if "preview_at_arrival" not in runs[enabled].metrics:
            raise DriveDemoError(f"drive, {label}: {bag_path} has no ground truth to score")
        seconds[f"drive eval, {label}"] = time.monotonic() - t0
    t0 = time.monotonic()
    on, off = runs[True], runs[False]
    config = on.pipeline.config
    truth = read_drive_truth(bag_path, base_frame=config.topics.base_frame, odom_topic=config.topics.odom)
    arrival = arrival_settings(config, lead_time_s=lead_time_s, camera_in_base=truth.camera_in_base)
    stamps = [int(r["stamp_ns"]) for r in on.result.per_frame]
    previews_on = per_frame_previews(on.result.outputs or [])
    previews_off = per_frame_previews(off.result.outputs or [])
    try:
        points_on = arrival_points(previews_on, truth.trajectory, truth.road_map, arrival, frame_stamps_ns=stamps)
        points_off = arrival_points(previews_off, truth.trajectory, truth.road_map, arrival, frame_stamps_ns=stamps)
    except ArrivalError as exc:
        raise DriveDemoError(f"drive: preview at arrival: {exc}") from exc
    windows = [o.map for o in on.result.outputs or [] if o.map is not None]
    fused = mosaic(windows)
    notes = list(truth.notes)
    # hazards on the fused map against the true features (or the detector on the true road)
    try:
        hazards = detect_hazards(fused.elevation, fused.local_uncertainty, fused.resolution, fused.centre)
        known = _read_features(bag_path)
        if known is None:
            reference, reference_kind = _truth_hazards(truth.road_map, fused), "detected on the true road map"
        else:
            reference, reference_kind = known, "placed by the synthesiser"
    except HazardError as exc:
        raise DriveDemoError(f"drive: hazards: {exc}") from exc
    matches, false_alarms = match_hazards(hazards, reference, fused)
    seconds["drive map and hazards"] = time.monotonic() - t0
    # the ride
    t0 = time.monotonic()
    lead_ns = int(round(lead_time_s * 1e9))
    start, end = stamps[0], int(truth.trajectory.stamp_ns[-1])
    score_end = min(stamps[-1] + lead_ns, end)
    span = (score_end - start) * 1e-9
    warmup = min(1.0, 0.4 * span)
    ride_settings = RideSettings(latency_s=lead_time_s, warmup_s=warmup, arrival=arrival)
    sources: dict[str, Source] = {"passive": "passive", "no_preview": "none", "per_frame": previews_off,
                               "fused": previews_on, "true_road": "true"}
    try:
        rows = ride(truth.trajectory, truth.road_map, sources, ride_settings, start, end, score_end,
                    {"fused": message_plane_slopes})
    except RideError as exc:
        raise DriveDemoError(f"drive: ride: {exc}") from exc
    none, ceiling = rows["no_preview"]["mean"]["wk_rms_mps2"], rows["true_road"]["mean"]["wk_rms_mps2"]
    share = {k: gain_share(none, ceiling, rows[k]["mean"]["wk_rms_mps2"]) for k in ("per_frame", "fused", "true_road")}
    seconds["drive ride"] = time.monotonic() - t0
    gt = truth.trajectory
    inside = (gt.stamp_ns >= start) & (gt.stamp_ns <= score_end + 10 * lead_ns)
    return DriveSection(
        bag=bag_path, reused=reused, seed=seed, map_on=_json(on.metrics), map_off=_json(off.metrics),
        points_on=points_on, points_off=points_off, fused=fused, truth=truth.road_map,
        path_xy=np.asarray(gt.position[inside, :2]), hazards=list(hazards), reference=reference,
        reference_kind=reference_kind, matches=matches, false_alarms=false_alarms,
        ride={"rows": rows, "share": share}, ride_span_s=(warmup, span - warmup), notes=notes, seconds=seconds,
    )


def _json(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """The metrics as ``roadbev eval --json`` writes them (NaN as null)."""
    return dict(json.loads(to_json(dict(metrics))))
