"""Road hazards tracked over the fused map as the car approaches them, a severity cost, and the
roughness along each wheel track (issue 22). ROS-free: ``roadbev_ros.hazard_monitor`` runs it on
``/roadbev/map``.

Each :meth:`HazardTracker.update` takes one published map window (:class:`roadbev_core.fusion.MapWindow`,
``odom``, grid_map order) and, when known, ``base_link``'s planar pose at its stamp:

1. **Detect.** :func:`roadbev_core.hazards.road_residual` (height above the road's own level) and
   :func:`roadbev_core.hazards.hazards_in_residual` on it, with the map's ``uncertainty`` layer
   without the datum's part (``MapWindow.local_uncertainty``) as sigma: bumps and potholes with
   centroid, extent, signed height, its 1-sigma and a confidence.
2. **Associate** (in ``odom``, where a road feature stands still): each detection goes to the
   nearest track of the same kind whose centroid lies within ``gate_m`` plus half of the larger
   extent on each axis (greedy, nearest first); an unmatched detection opens a tentative track.
3. **Keep.** A track takes its position, extent, height and sigma from its latest detection (the
   map already fuses every frame per cell, so averaging the detections again would count the same
   observations twice and shrink the sigma dishonestly), except a detection cut by the window's
   edge (only part of the feature in view) or of a feature the front axle has already reached
   (out of the camera's view: the map there changes only by re-alignment), which only keep the
   track alive; ``position_sigma_m`` is the spread (RMS
   distance) of its detections' centroids around their mean, at least half a cell. Its
   confidence is the latest detection's, times ``min(1, detections / confirm_hits)``.
4. **Report and forget.** A track is reported (``confirmed``) from its ``confirm_hits``-th
   detection on; the stamp and the distance from the front axle to its near edge at that moment
   are kept (``first_reported_*``: what a planner had as warning). A window that holds the
   track's cell but no matching detection is a miss: a tentative track is dropped at once, a
   confirmed one after more than ``max_misses`` in a row; a track whose position has left the
   window (it fell behind the map) is retired.

Per update also: the severity cost of the whole window (:func:`roadbev_core.hazards.severity_cost`:
|residual| / ``full_cost_height_m`` x 100, -1 unknown; ``nav_msgs/OccupancyGrid`` values) and,
with a pose, the roughness along each front wheel's track (the map's elevation along the line
``y = +-track_width / 2`` of ``base_link`` over the window, the reported hazards cut out,
:func:`roadbev_core.roughness.profile_roughness`), averaged over the last ``roughness_memory_m``
driven so the class does not flicker from one window to the next.

Pure numpy; shapes in the comments.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from roadbev_core.config import VehicleConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.errors import RoadbevError
from roadbev_core.fusion import MapWindow
from roadbev_core.hazards import Hazard, HazardSettings, hazards_in_residual, road_residual, severity_cost
from roadbev_core.roughness import Roughness, RoughnessSettings, iso8608_class, profile_roughness

__all__ = [
    "HazardReport",
    "HazardTracker",
    "TrackRoughness",
    "TrackedHazard",
    "TrackerError",
    "TrackerSettings",
    "distance_ahead",
]

FRONT_TRACKS = (("front_left", 1.0), ("front_right", -1.0))  # name, sign of the lateral offset
RETIRED_KEPT = 10_000


class TrackerError(RoadbevError, ValueError):
    """Tracker settings or a map window the tracker cannot use."""


@dataclass(frozen=True)
class TrackerSettings:
    """How hazards are tracked.

    Attributes:
        detector: the per-window detector's settings.
        gate_m: association distance beyond half the larger extent (m).
        confirm_hits: detections before a track is reported.
        max_misses: consecutive misses a reported track survives.
        full_cost_height_m: |residual| of cost 100.
        roughness: the roughness estimate's settings.
        roughness_memory_m: distance over which the roughness estimates are averaged (m).
        vehicle: wheelbase and track (the front axle and the wheel tracks).
    """

    detector: HazardSettings = field(default_factory=HazardSettings)
    gate_m: float = 0.5
    confirm_hits: int = 2
    max_misses: int = 2
    full_cost_height_m: float = 0.10
    roughness: RoughnessSettings = field(default_factory=RoughnessSettings)
    roughness_memory_m: float = 20.0
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)

    def __post_init__(self) -> None:
        if not (0.0 < self.gate_m <= 5.0 and 1 <= self.confirm_hits <= 20 and 0 <= self.max_misses <= 100
                and math.isfinite(self.full_cost_height_m) and self.full_cost_height_m > 0
                and math.isfinite(self.roughness_memory_m) and self.roughness_memory_m >= 0):
            raise TrackerError(f"bad tracker settings: gate {self.gate_m} m (0, 5], confirm_hits "
                               f"{self.confirm_hits} [1, 20], max_misses {self.max_misses} [0, 100], full cost "
                               f"{self.full_cost_height_m} m > 0, roughness memory {self.roughness_memory_m} m >= 0")


@dataclass
class TrackedHazard:
    """One hazard tracked in the map's frame.

    Attributes:
        id: stable while tracked (1, 2, ...).
        kind: ``bump`` or ``pothole``.
        x, y: centroid (m, map frame); ``level_z``: the road's level under it (m).
        position_sigma_m: spread of the detections' centroids (>= half a cell).
        length_m, width_m: extent along the map frame's x and y (m).
        height_m, height_sigma_m: signed height above the road's level (pothole < 0) and its 1-sigma.
        confidence: 0..1 (module docstring).
        detections, misses: windows it was detected in; consecutive misses now.
        first_seen_ns, last_seen_ns: stamps of the first and latest detection.
        first_reported_ns: stamp of the window that confirmed it (None while tentative).
        first_reported_distance_m: front axle to near edge then (m; NaN without a pose).
        first_reported_height_m: the height reported then (m).
        distance_ahead_m: front axle to near edge at the latest update (m; < 0: under or behind
            the front axle; NaN without a pose).
    """

    id: int
    kind: str
    x: float
    y: float
    level_z: float
    position_sigma_m: float
    length_m: float
    width_m: float
    height_m: float
    height_sigma_m: float
    confidence: float
    detections: int
    misses: int
    first_seen_ns: int
    last_seen_ns: int
    first_reported_ns: int | None = None
    first_reported_distance_m: float = math.nan
    first_reported_height_m: float = math.nan
    distance_ahead_m: float = math.nan
    _centroids: list[tuple[float, float]] = field(default_factory=list, repr=False)

    @property
    def confirmed(self) -> bool:
        return self.first_reported_ns is not None


class TrackRoughness(NamedTuple):
    """Roughness along one wheel track.

    Attributes:
        name: ``front_left`` / ``front_right``.
        lateral_offset_m: y of the track in ``base_link``.
        gd_n0: ISO 8608 Gd(n0) averaged over the memory (m^3; NaN: not estimated yet).
        iso_class: its class (``""`` when unknown).
        length_m: profile length of the latest window's estimate (m).
    """

    name: str
    lateral_offset_m: float
    gd_n0: float
    iso_class: str
    length_m: float


class HazardReport(NamedTuple):
    """What one map window gave.

    Attributes:
        stamp_ns: the window's stamp.
        hazards: the reported (confirmed) tracks as they are after this window (copies), nearest
            first when a pose is known.
        cost: [R, C] int8 severity 0..100, -1 unknown, grid_map order of the window.
        resolution, centre: the window's geometry (``centre`` in the map frame).
        roughness: per front wheel track (empty without a pose).
        speed_mps: the pose's speed (NaN without a pose).
    """

    stamp_ns: int
    hazards: list[TrackedHazard]
    cost: np.ndarray
    resolution: float
    centre: tuple[float, float]
    roughness: list[TrackRoughness]
    speed_mps: float


def distance_ahead(base: PlanarPose, x: float, y: float, length_m: float, width_m: float, front_x: float) -> float:
    """Along ``base``'s heading, from the axle at ``front_x`` in ``base_link`` to the near edge of
    an axis-aligned box (centre x, y; extent length x width in the map frame) (m)."""
    c, s = math.cos(base.yaw), math.sin(base.yaw)
    along = (x - base.x) * c + (y - base.y) * s
    half = 0.5 * (abs(c) * length_m + abs(s) * width_m)
    return along - half - front_x


def _cell(window: MapWindow, x: float, y: float) -> tuple[int, int] | None:
    """(row, col) of the window's cell holding (x, y), None outside."""
    n_rows, n_cols = window.elevation.shape
    r = window.resolution
    row = int(math.floor((window.centre[0] + 0.5 * n_rows * r - x) / r))
    col = int(math.floor((window.centre[1] + 0.5 * n_cols * r - y) / r))
    if 0 <= row < n_rows and 0 <= col < n_cols:
        return row, col
    return None


def _cut_by_edge(window: MapWindow, h: Hazard) -> bool:
    """Whether a detection's box reaches the window's edge or unknown cells around it (only part
    of the feature is in view)."""
    n_rows, n_cols = window.elevation.shape
    r = window.resolution
    x_hi, y_hi = window.centre[0] + 0.5 * n_rows * r, window.centre[1] + 0.5 * n_cols * r
    r0 = int(math.floor((x_hi - (h.x + 0.5 * h.length_m)) / r)) - 1
    r1 = int(math.floor((x_hi - (h.x - 0.5 * h.length_m)) / r)) + 1
    c0 = int(math.floor((y_hi - (h.y + 0.5 * h.width_m)) / r)) - 1
    c1 = int(math.floor((y_hi - (h.y - 0.5 * h.width_m)) / r)) + 1
    if r0 < 0 or r1 >= n_rows:
        return True
    ring = window.elevation[max(r0, 0): r1 + 1, max(c0, 0): min(c1, n_cols - 1) + 1]
    rows_known = np.isfinite(ring).any(axis=1)  # a row of the box outside the corridor: cut along x
    return bool(not rows_known.all())


class HazardTracker:
    """Hazards tracked over successive map windows (module docstring). Not thread-safe.

    Args:
        settings: tracker settings.
    """

    def __init__(self, settings: TrackerSettings | None = None) -> None:
        self.settings = settings or TrackerSettings()
        self.reset()

    def reset(self) -> None:
        """Forget every track and the roughness (a new drive, a map cleared)."""
        self.tracks: list[TrackedHazard] = []
        # reported tracks that left the map, newest last (for evaluation; bounded for a long drive)
        self.retired: deque[TrackedHazard] = deque(maxlen=RETIRED_KEPT)
        self._next_id = 1
        self._gd: dict[str, float] = {}
        self._last_pose: PlanarPose | None = None
        self._last_stamp: int | None = None

    def update(self, window: MapWindow, base: PlanarPose | None = None) -> HazardReport:
        """Track the hazards of one map window (``base``: ``base_link``'s pose at its stamp).

        Raises:
            TrackerError: a window whose layers do not match, or a stamp older than the last.
            HazardError: a window without any known cell.
        """
        s = self.settings
        e = np.asarray(window.elevation, np.float32)  # [R, C]
        # a hazard is a height against the road around it: the datum's part of the sigma cancels
        sig = np.asarray(window.local_uncertainty(), np.float32)
        if e.ndim != 2 or sig.shape != e.shape or not (math.isfinite(window.resolution) and window.resolution > 0):
            raise TrackerError(f"map window layers {e.shape} / {sig.shape} at resolution {window.resolution} "
                               "cannot be tracked")
        if self._last_stamp is not None and window.stamp_ns < self._last_stamp:
            raise TrackerError(f"map stamp {window.stamp_ns} is older than the last ({self._last_stamp}): reset first")
        self._last_stamp = int(window.stamp_ns)
        residual, noise = road_residual(e, window.resolution, s.detector)
        found = hazards_in_residual(residual, noise, sig, window.resolution, window.centre, s.detector)
        self._associate(window, found, e, residual)
        front_x = s.vehicle.wheelbase_m
        if base is not None:
            for t in self.tracks:
                t.distance_ahead_m = distance_ahead(base, t.x, t.y, t.length_m, t.width_m, front_x)
                if t.confirmed and t.first_reported_ns == window.stamp_ns:
                    t.first_reported_distance_m = t.distance_ahead_m
        reported = [replace(t, _centroids=list(t._centroids)) for t in self.tracks if t.confirmed]  # snapshots
        if base is not None:
            reported.sort(key=lambda t: t.distance_ahead_m)
        roughness = self._roughness(window, e, sig, base, reported) if base is not None else []
        cost = severity_cost(residual, s.full_cost_height_m)
        return HazardReport(int(window.stamp_ns), reported, cost, float(window.resolution),
                            (float(window.centre[0]), float(window.centre[1])), roughness,
                            float(base.speed) if base is not None else math.nan)

    # --- association ----------------------------------------------------------------------------
    def _associate(self, window: MapWindow, found: list[Hazard], e: np.ndarray, residual: np.ndarray) -> None:
        s = self.settings
        pairs = []
        for i, h in enumerate(found):
            for j, t in enumerate(self.tracks):
                if t.kind != h.kind:
                    continue
                gx = s.gate_m + 0.5 * max(h.length_m, t.length_m)
                gy = s.gate_m + 0.5 * max(h.width_m, t.width_m)
                dx, dy = abs(h.x - t.x) / gx, abs(h.y - t.y) / gy
                if dx <= 1.0 and dy <= 1.0:
                    pairs.append((math.hypot(dx, dy), i, j))
        used_h: set[int] = set()
        used_t: set[int] = set()
        for _, i, j in sorted(pairs):
            if i in used_h or j in used_t:
                continue
            used_h.add(i)
            used_t.add(j)
            self._hit(self.tracks[j], found[i], window, e)
        keep = []
        for j, t in enumerate(self.tracks):
            if j in used_t:
                keep.append(t)
                continue
            cell = _cell(window, t.x, t.y)
            if cell is None:  # it fell behind the map
                if t.confirmed:
                    self.retired.append(t)
                continue
            if not np.isfinite(residual[cell]):  # not covered by this window: no evidence either way
                keep.append(t)
                continue
            t.misses += 1
            if t.confirmed and t.misses <= s.max_misses:
                keep.append(t)
        for i, h in enumerate(found):
            if i not in used_h:
                t = TrackedHazard(self._next_id, h.kind, h.x, h.y, 0.0, 0.5 * window.resolution, h.length_m,
                                  h.width_m, h.height_m, h.height_sigma_m, 0.0, 0, 0, int(window.stamp_ns),
                                  int(window.stamp_ns))
                self._next_id += 1
                self._hit(t, h, window, e)
                keep.append(t)
        self.tracks = keep

    def _hit(self, t: TrackedHazard, h: Hazard, window: MapWindow, e: np.ndarray) -> None:
        s = self.settings
        t.detections += 1
        if t.detections > 1 and (_cut_by_edge(window, h) or t.distance_ahead_m < 0.0):
            # a feature leaving (or entering) the window shows only part of itself, and one the
            # front axle has reached is out of the camera's view (the map there changes only by
            # re-alignment): the track keeps what the last whole view ahead measured
            t.misses = 0
            t.last_seen_ns = int(window.stamp_ns)
            return
        t.x, t.y, t.length_m, t.width_m = h.x, h.y, h.length_m, h.width_m
        t.height_m, t.height_sigma_m = h.height_m, h.height_sigma_m
        t.misses = 0
        t.last_seen_ns = int(window.stamp_ns)
        t.confidence = h.confidence * min(1.0, t.detections / s.confirm_hits)
        t._centroids.append((h.x, h.y))
        c = np.array(t._centroids)
        spread = float(np.sqrt(np.mean(np.sum((c - c.mean(axis=0)) ** 2, axis=1))))
        t.position_sigma_m = max(spread, 0.5 * window.resolution)
        cell = _cell(window, h.x, h.y)
        z = float(e[cell]) if cell is not None else math.nan
        t.level_z = z - h.height_m if math.isfinite(z) else t.level_z
        if not t.confirmed and t.detections >= s.confirm_hits:
            t.first_reported_ns = int(window.stamp_ns)
            t.first_reported_height_m = t.height_m

    # --- roughness ------------------------------------------------------------------------------
    def _roughness(self, window: MapWindow, e: np.ndarray, sig: np.ndarray, base: PlanarPose,
                   hazards: list[TrackedHazard]) -> list[TrackRoughness]:
        s = self.settings
        r = window.resolution
        n_rows, n_cols = e.shape
        xs, ys = window.cell_centres()
        c, sn = math.cos(base.yaw), math.sin(base.yaw)
        # the window's extent along the heading from base_link (the axis-aligned box's corners)
        corners = np.array([[xs[0], ys[0]], [xs[0], ys[-1]], [xs[-1], ys[0]], [xs[-1], ys[-1]]])
        along = (corners[:, 0] - base.x) * c + (corners[:, 1] - base.y) * sn
        d = np.arange(float(along.min()), float(along.max()), r)  # [N] along the heading
        travelled = 0.0 if self._last_pose is None else math.hypot(base.x - self._last_pose.x,
                                                                    base.y - self._last_pose.y)
        self._last_pose = base
        alpha = 1.0 if s.roughness_memory_m <= 0 else min(1.0, travelled / s.roughness_memory_m)
        out = []
        for name, sign in FRONT_TRACKS:
            offset = sign * 0.5 * s.vehicle.track_width_m
            px = base.x + c * d - sn * offset  # [N]
            py = base.y + sn * d + c * offset
            rows = np.floor((window.centre[0] + 0.5 * n_rows * r - px) / r).astype(int)
            cols = np.floor((window.centre[1] + 0.5 * n_cols * r - py) / r).astype(int)
            inside = (rows >= 0) & (rows < n_rows) & (cols >= 0) & (cols < n_cols)
            z = np.full(d.size, np.nan)
            z_sig = np.full(d.size, np.nan)
            z[inside] = e[rows[inside], cols[inside]]
            z_sig[inside] = sig[rows[inside], cols[inside]]
            for h in hazards:  # discrete features are not roughness: cut out (bridged if short)
                box = (np.abs(px - h.x) <= 0.5 * h.length_m + r) & (np.abs(py - h.y) <= 0.5 * h.width_m + r)
                z[box] = np.nan
            est: Roughness = profile_roughness(z, r, z_sig, s.roughness)
            if math.isfinite(est.gd_n0):
                old = self._gd.get(name)
                self._gd[name] = est.gd_n0 if old is None else old + alpha * (est.gd_n0 - old)
            gd = self._gd.get(name, math.nan)
            out.append(TrackRoughness(name, offset, gd, iso8608_class(gd), est.length_m))
        return out
