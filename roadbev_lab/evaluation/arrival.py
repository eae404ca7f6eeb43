"""Preview at arrival: a road preview judged when the wheel gets there.

docs/interface/evaluation.md, "Preview at arrival". For every 3 cm of each front wheel's
actual path (arrivals from the first camera frame + ``lead_time_s`` to the last camera frame +
``lead_time_s``), the latest preview message stamped at least ``lead_time_s`` before the wheel
reaches that point *that has a value there* (an earlier message still counts when a later one
does not reach so far: a controller holds what it was told) is read at that point with the true
ego-motion from its stamp to the arrival, and compared with the true road height there (the mean
over the tyre footprint, ``tyre_width_m`` x 3 cm) relative to the true counterpart of the
message's reference:

* ``REFERENCE_ROAD`` (today's per-frame previews, ``roadbev_road``): x ahead of the camera in
  the gravity-aligned frame ``base_height`` below the true camera with the camera's yaw;
  heights relative to that frame's plane;
* ``REFERENCE_CONTACT_PLANE`` (previews of the fused map, ``base_link``): x in ``base_link`` at
  the stamp; heights relative to the least-squares plane through the four true tyre contacts at
  the stamp (heights measured vertically).

Every preview is also scored against the true contact plane at its stamp
(``contact_plane_abs_err_cm``: what a controller would still have to correct). A point no
message covers is missing (it lowers ``coverage_pct``, never counts as zero error). Feature
points: where the true profile leaves its 2 m running median by more than 1.5 cm, dilated by
0.3 m; the rest is smooth road.

How a profile is read at x: linear interpolation between the two neighbouring samples when both
have a value, else the nearer sample when it has one and lies within half a spacing. Profiles
are 1-D along their track: a wheel that has moved sideways since the stamp reads the track as it
was sent (a controller has nothing else).

Wheel contact points are where ``base_link``'s planar pose (position and yaw) puts the tyre
centres (``vehicle.wheelbase_m``, ``vehicle.track_width_m``). Pure numpy; shapes in comments.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np

from roadbev_core.attitude import slerp
from roadbev_core.config import VehicleConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.fusion import MapWindow
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, quaternion_to_rotation
from roadbev_core.preview import (
    REFERENCE_CONTACT_PLANE,
    REFERENCE_ROAD,
    PreviewProfiles,
    read_profile_with_sigma,
)
from roadbev_core.vehicle import contact_plane, planar_yaw
from roadbev_lab.evaluation.metrics import sigma_counts, sigma_metrics

if TYPE_CHECKING:  # the pipeline imports nothing from here; typing only
    from roadbev_core.pipeline import PipelineOutput

__all__ = [
    "ARRIVAL_KEYS",
    "MAP_BAND_KEYS",
    "MAP_BAND_M",
    "MAP_KEYS",
    "REFERENCE_CONTACT_PLANE",
    "REFERENCE_ROAD",
    "ArrivalError",
    "ArrivalPoints",
    "ArrivalSettings",
    "RoadMap",
    "TimedPreview",
    "Trajectory",
    "WheelErrors",
    "WheelPath",
    "arrival_points",
    "camera_in_odom",
    "carried_through_car",
    "feature_mask",
    "map_accuracy",
    "map_summary",
    "map_window_rows",
    "per_frame_previews",
    "preview_at_arrival",
    "summarise_errors",
    "summarise_points",
    "wheel_errors",
    "wheel_paths",
]

ARRIVAL_KEYS: tuple[str, ...] = (
    "lead_time_s",
    "points",
    "abs_err_cm",
    "rmse_cm",
    "p95_abs_err_cm",
    "coverage_pct",
    "features_abs_err_cm",
    "smooth_abs_err_cm",
    "contact_plane_abs_err_cm",
    "sigma_points",
    "within_1sigma_pct",
    "within_2sigma_pct",
    "within_3sigma_pct",
    "confident_wrong_pct",
    "mean_sigma_cm",
)
# The fused map's keys (docs/interface/evaluation.md, "map"), each a mean over the published windows.
MAP_KEYS: tuple[str, ...] = ("abs_err_cm", "coverage_pct", "within_1sigma_pct", "within_2sigma_pct",
                             "within_3sigma_pct", "confident_wrong_pct", "mean_sigma_cm", "datum_offset_cm")
# The fused map's distance bands (docs/interface/evaluation.md, "map" "bands"): metres ahead of base_link.
MAP_BAND_M = 1.0
# The keys of each band, each a mean over the windows that hold cells in it.
MAP_BAND_KEYS: tuple[str, ...] = ("abs_err_cm", "within_1sigma_pct", "within_2sigma_pct", "confident_wrong_pct",
                                  "mean_sigma_cm", "cells")
_BAND_ROW = "band:"  # map_window_rows' key of a band's value: band:<index>:<key>, index = floor(ahead / MAP_BAND_M)
# Which preview track a front wheel reads, by the track's name.
_TRACK_OF_WHEEL = {"front_left": ("front_left", "left"), "front_right": ("front_right", "right")}


class ArrivalError(RoadbevError, ValueError):
    """Inputs the metric cannot score (no previews, truth that does not cover the drive...)."""


class Trajectory(NamedTuple):
    """The true pose of ``base_link`` in ``odom`` over time.

    Attributes:
        stamp_ns: [K] int64, strictly increasing.
        position: [K, 3] (m).
        orientation_xyzw: [K, 4] unit quaternions.
    """

    stamp_ns: np.ndarray
    position: np.ndarray
    orientation_xyzw: np.ndarray

    def check(self) -> None:
        """Raises ArrivalError unless the arrays agree and the stamps increase."""
        k = self.stamp_ns.shape[0]
        if k < 2 or self.position.shape != (k, 3) or self.orientation_xyzw.shape != (k, 4):
            raise ArrivalError(f"a trajectory needs >= 2 poses with [K, 3] positions and [K, 4] quaternions, got "
                               f"{self.stamp_ns.shape}, {self.position.shape}, {self.orientation_xyzw.shape}")
        if np.any(np.diff(self.stamp_ns) <= 0):
            raise ArrivalError("trajectory stamps must increase strictly")
        if not (np.all(np.isfinite(self.position)) and np.all(np.isfinite(self.orientation_xyzw))):
            raise ArrivalError("trajectory poses must be finite")

    def interpolate(self, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Poses at ``stamps_ns`` [N] (clamped to the span): positions [N, 3] (linear) and
        rotations [N, 3, 3] (slerp)."""
        stamps = np.asarray(stamps_ns, np.int64)
        t = (stamps - self.stamp_ns[0]).astype(np.float64)
        ts = (self.stamp_ns - self.stamp_ns[0]).astype(np.float64)
        k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
        frac = np.clip((t - ts[k]) / (ts[k + 1] - ts[k]), 0.0, 1.0)
        pos = self.position[k] * (1 - frac[:, None]) + self.position[k + 1] * frac[:, None]
        R = np.empty((stamps.size, 3, 3))
        for i in range(stamps.size):
            q = slerp(self.orientation_xyzw[k[i]], self.orientation_xyzw[k[i] + 1], float(frac[i]))
            R[i] = quaternion_to_rotation(*q)
        return pos, R

    def planar(self, stamps_ns: np.ndarray) -> np.ndarray:
        """[N, 3] (x, y, yaw) at ``stamps_ns`` (yaw linearly interpolated, unwrapped)."""
        stamps = np.asarray(stamps_ns, np.int64)
        t = (stamps - self.stamp_ns[0]).astype(np.float64)
        ts = (self.stamp_ns - self.stamp_ns[0]).astype(np.float64)
        R = np.array([quaternion_to_rotation(*q) for q in self.orientation_xyzw])
        yaw = np.unwrap(planar_yaw(R))
        return np.stack([np.interp(t, ts, self.position[:, 0]), np.interp(t, ts, self.position[:, 1]),
                         np.interp(t, ts, yaw)], axis=1)


class RoadMap(NamedTuple):
    """A road height map in grid_map order (row 0 at the largest x, column 0 at the largest y).

    Attributes:
        elevation: [n_rows, n_cols] float32 z (m), NaN = unknown.
        resolution: cell size (m).
        centre: (x, y) of the map's centre (m).
    """

    elevation: np.ndarray
    resolution: float
    centre: tuple[float, float]

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear height between cell centres at points [...] (NaN outside or next to NaN)."""
        n_rows, n_cols = self.elevation.shape
        r = self.resolution
        fr = (self.centre[0] + 0.5 * n_rows * r - np.asarray(x, np.float64)) / r - 0.5  # [...] row
        fc = (self.centre[1] + 0.5 * n_cols * r - np.asarray(y, np.float64)) / r - 0.5
        inside = (fr >= 0) & (fr <= n_rows - 1) & (fc >= 0) & (fc <= n_cols - 1)
        r0 = np.clip(np.floor(fr), 0, n_rows - 2).astype(np.int64)
        c0 = np.clip(np.floor(fc), 0, n_cols - 2).astype(np.int64)
        tr, tc = np.clip(fr - r0, 0, 1), np.clip(fc - c0, 0, 1)
        e = self.elevation  # indexed before converting: the map can hold millions of cells
        top = e[r0, c0].astype(np.float64) * (1 - tc) + e[r0, c0 + 1].astype(np.float64) * tc
        bot = e[r0 + 1, c0].astype(np.float64) * (1 - tc) + e[r0 + 1, c0 + 1].astype(np.float64) * tc
        return np.where(inside, top * (1 - tr) + bot * tr, np.nan)

    def footprint(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray, width: float,
                  length: float) -> np.ndarray:
        """[N] mean height over tyre footprints (``width`` across, ``length`` along ``heading``)
        centred at (x, y) [N], from samples every ~1 cm (NaN where any sample is unknown)."""
        n_w = max(2, int(math.ceil(width / 0.01)))
        n_l = max(2, int(math.ceil(length / 0.01)))
        across = (np.arange(n_w) + 0.5) / n_w * width - 0.5 * width
        along = (np.arange(n_l) + 0.5) / n_l * length - 0.5 * length
        grid_a, grid_b = np.meshgrid(along, across, indexing="ij")
        a, b = grid_a.ravel(), grid_b.ravel()  # [S] offsets along and across
        c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
        px = np.asarray(x)[:, None] + c * a - s * b  # [N, S]
        py = np.asarray(y)[:, None] + s * a + c * b
        return cast("np.ndarray", self.height(px, py).mean(axis=1))


@dataclass(frozen=True)
class TimedPreview:
    """One preview message as the metric needs it.

    Attributes:
        stamp_ns: the message's stamp (the image it was made from).
        reference: ``REFERENCE_ROAD`` or ``REFERENCE_CONTACT_PLANE``.
        profiles: the profiles (x of the samples in the reference's frame; tracks named
            ``left``/``right`` or ``front_left``/``front_right``).
        received_ns: when a consumer has it (None: ``stamp_ns`` + the reader's lead time or
            latency); a node that processes frames slower than the camera delivers some later.
    """

    stamp_ns: int
    reference: str
    profiles: PreviewProfiles
    received_ns: int | None = None

    def __post_init__(self) -> None:
        if self.reference not in (REFERENCE_ROAD, REFERENCE_CONTACT_PLANE):
            raise ArrivalError(f"unknown preview reference {self.reference!r}")
        if self.received_ns is not None and self.received_ns < self.stamp_ns:
            raise ArrivalError("a preview cannot be received before its stamp")

    def available_ns(self, delay_ns: int) -> int:
        """When it can be used: ``received_ns``, else ``stamp_ns + delay_ns``."""
        return self.stamp_ns + delay_ns if self.received_ns is None else self.received_ns


@dataclass(frozen=True)
class ArrivalSettings:
    """How the metric reads previews and the truth.

    Attributes:
        lead_time_s: a message counts for an arrival at least this much later than its stamp.
        spacing_m: path points every this far along each wheel's path.
        tyre_width_m: footprint width (``preview.tyre_width_m``).
        base_height: the per-frame road frame lies this far below the camera.
        vehicle: wheelbase, track and (without a TF) the camera's position on ``base_link``.
        camera_in_base: (position [3], R [3, 3] optical -> base_link) from ``/tf_static``;
            None: ``vehicle.camera_position_m`` and a camera without yaw on the body.
        feature_threshold_m, feature_window_m, feature_dilation_m: feature points.
    """

    lead_time_s: float = 0.1
    spacing_m: float = 0.03
    tyre_width_m: float = 0.20
    base_height: float = 1.10
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    camera_in_base: tuple[np.ndarray, np.ndarray] | None = None
    feature_threshold_m: float = 0.015
    feature_window_m: float = 2.0
    feature_dilation_m: float = 0.3

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lead_time_s) and 0.0 <= self.lead_time_s <= 10.0):
            raise ArrivalError(f"lead time must be in [0, 10] s, got {self.lead_time_s}")
        if not (0.001 <= self.spacing_m <= 1.0 and 0.0 < self.tyre_width_m <= 2.0):
            raise ArrivalError("spacing must be in [0.001, 1] m and the tyre width in (0, 2] m")


class WheelPath(NamedTuple):
    """Points every ``spacing_m`` along one wheel's true path.

    Attributes:
        name: the wheel (``front_left``, ``front_right``).
        xy: [P, 2] contact points in ``odom``.
        heading: [P] direction of travel (rad).
        arrival_ns: [P] int64 when the tyre centre passes.
        height: [P] true road height there (footprint mean, m; NaN off the map).
        feature: [P] bool feature points.
    """

    name: str
    xy: np.ndarray
    heading: np.ndarray
    arrival_ns: np.ndarray
    height: np.ndarray
    feature: np.ndarray


def feature_mask(heights: np.ndarray, spacing: float, threshold: float = 0.015, window: float = 2.0,
                 dilation: float = 0.3) -> np.ndarray:
    """[P] bool: points whose height leaves its ``window`` running median by > ``threshold``,
    dilated by ``dilation`` (m) each way. Unknown heights are never features."""
    h = np.asarray(heights, np.float64)
    n = h.size
    half = max(1, int(round(0.5 * window / spacing)))
    padded = np.pad(h, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)  # [P, W]
    with warnings.catch_warnings():  # a window without any known height has no median (NaN)
        warnings.simplefilter("ignore", RuntimeWarning)
        median = np.nanmedian(windows, axis=1) if n else np.zeros(0)
    with np.errstate(invalid="ignore"):
        raw = np.abs(h - median) > threshold
    d = int(round(dilation / spacing))
    out = raw.copy()
    for shift in range(1, d + 1):
        out[shift:] |= raw[:-shift]
        out[:-shift] |= raw[shift:]
    return cast("np.ndarray", out)


def wheel_paths(truth: Trajectory, road_map: RoadMap, settings: ArrivalSettings, start_ns: int,
                end_ns: int) -> list[WheelPath]:
    """The front wheels' paths with arrivals in [start_ns, end_ns] (clamped to the truth's span).

    The profile for the feature test runs ``feature_window_m / 2 + feature_dilation_m`` beyond
    both ends where the truth reaches, so points at the ends are judged like the rest.
    """
    truth.check()
    start_ns, end_ns = max(int(start_ns), int(truth.stamp_ns[0])), min(int(end_ns), int(truth.stamp_ns[-1]))
    if end_ns <= start_ns:
        raise ArrivalError("the true poses do not cover the arrivals (first frame + lead .. last frame + lead)")
    # dense planar poses over the whole truth (2 ms), then arc length per wheel
    step = 2_000_000
    stamps = np.arange(int(truth.stamp_ns[0]), int(truth.stamp_ns[-1]) + 1, step, dtype=np.int64)
    planar = truth.planar(stamps)  # [T, 3]
    c, s = np.cos(planar[:, 2]), np.sin(planar[:, 2])
    out = []
    extra = 0.5 * settings.feature_window_m + settings.feature_dilation_m
    for index, name in ((0, "front_left"), (1, "front_right")):
        wx, wy = settings.vehicle.wheel_positions()[index]
        px = planar[:, 0] + c * wx - s * wy
        py = planar[:, 1] + s * wx + c * wy
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(px), np.diff(py)))])  # [T] non-decreasing
        t_rel = (stamps - stamps[0]).astype(np.float64)
        a0 = float(np.interp(float(start_ns - stamps[0]), t_rel, arc))
        a1 = float(np.interp(float(end_ns - stamps[0]), t_rel, arc))
        lo, hi = max(a0 - extra, 0.0), min(a1 + extra, float(arc[-1]))
        first = int(math.ceil((lo - a0) / settings.spacing_m - 1e-9))
        count = int(math.floor((hi - a0) / settings.spacing_m + 1e-9)) - first + 1
        along = a0 + (first + np.arange(max(count, 0))) * settings.spacing_m  # [P'] on the grid from a0
        # arc -> time (arc may stand still when the car stops: take the first time it is reached)
        moving = np.concatenate([[True], np.diff(arc) > 1e-9])
        t_at = np.interp(along, arc[moving], t_rel[moving])
        x_at = np.interp(along, arc[moving], px[moving])
        y_at = np.interp(along, arc[moving], py[moving])
        heading = np.interp(along, arc[moving], np.unwrap(np.arctan2(np.gradient(py), np.gradient(px)))[moving])
        height = road_map.footprint(x_at, y_at, heading, settings.tyre_width_m, settings.spacing_m)
        feature = feature_mask(height, settings.spacing_m, settings.feature_threshold_m,
                               settings.feature_window_m, settings.feature_dilation_m)
        arrival = stamps[0] + np.rint(t_at).astype(np.int64)
        keep = (along >= a0 - 1e-9) & (along <= a1 + 1e-9)
        out.append(WheelPath(name, np.stack([x_at, y_at], 1)[keep], heading[keep], arrival[keep], height[keep],
                             feature[keep]))
    return out


def _track_name(profiles: PreviewProfiles, wheel: str) -> str | None:
    names = {t.name for t in profiles.tracks}
    for candidate in _TRACK_OF_WHEEL[wheel]:
        if candidate in names:
            return candidate
    return None


def _stats(err: np.ndarray) -> tuple[float, float, float]:
    if err.size == 0:
        return math.nan, math.nan, math.nan
    a = np.abs(err) * 100.0
    return float(a.mean()), float(np.sqrt(np.mean(a * a))), float(np.percentile(a, 95))


class ArrivalPoints(NamedTuple):
    """One front wheel's path points as the metric scored them (what a plot of the preview at
    arrival draws).

    Attributes:
        path: the wheel's path points (arrival, true height, feature points).
        along_m: [P] distance along the wheel's path from its first scored point (m).
        preview_z: [P] the road height in ``odom`` the preview promised there (the profile's
            value plus the true height of the reference it declares; NaN = missing).
        error: [P] ``preview_z`` - the true height (m; NaN where missing or the truth is unknown).
        error_contact_plane: [P] the same profile value against the true contact plane at the
            message's stamp.
        known: [P] bool the true height is known.
        covered: [P] bool known and a message covered the point.
        preview_sigma: [P] the 1-sigma the same message gave there (m; NaN = missing).
    """

    path: WheelPath
    along_m: np.ndarray
    preview_z: np.ndarray
    error: np.ndarray
    error_contact_plane: np.ndarray
    known: np.ndarray
    covered: np.ndarray
    preview_sigma: np.ndarray


def arrival_points(
    previews: Sequence[TimedPreview],
    truth: Trajectory,
    road_map: RoadMap,
    settings: ArrivalSettings | None = None,
    *,
    frame_stamps_ns: Sequence[int] | None = None,
) -> list[ArrivalPoints]:
    """Read the preview messages at every front-wheel path point (see the module docstring);
    :func:`preview_at_arrival` is the summary of these points.

    Args: as :func:`preview_at_arrival`.

    Returns:
        One :class:`ArrivalPoints` per front wheel (``front_left``, ``front_right``).

    Raises:
        ArrivalError: no previews or frames, or truth that does not cover the arrivals.
    """
    settings = settings or ArrivalSettings()
    if not previews:
        raise ArrivalError("no preview messages to score")
    order = sorted(previews, key=lambda p: p.stamp_ns)
    stamps = sorted(int(s) for s in (frame_stamps_ns if frame_stamps_ns is not None else
                                     [p.stamp_ns for p in order]))
    if not stamps:
        raise ArrivalError("no camera frames")
    lead_ns = int(round(settings.lead_time_s * 1e9))
    paths = wheel_paths(truth, road_map, settings, stamps[0] + lead_ns, stamps[-1] + lead_ns)

    msg_stamps = np.array([p.stamp_ns for p in order], np.int64)
    pos, R = truth.interpolate(msg_stamps)  # [M, 3], [M, 3, 3] base_link at each stamp
    yaw_base = planar_yaw(R)
    cam_world, yaw_cam = camera_in_odom(pos, R, settings)  # [M, 3], [M]: for the per-frame road frame
    road_origin_z = cam_world[:, 2] - settings.base_height
    # the true contact plane at each stamp
    wheels = settings.vehicle.wheel_positions()  # [4, 2]
    cb, sb = np.cos(yaw_base)[:, None], np.sin(yaw_base)[:, None]
    wx = pos[:, 0:1] + cb * wheels[:, 0] - sb * wheels[:, 1]  # [M, 4]
    wy = pos[:, 1:2] + sb * wheels[:, 0] + cb * wheels[:, 1]
    wz = road_map.footprint(wx.ravel(), wy.ravel(), np.repeat(yaw_base, 4), settings.tyre_width_m,
                            settings.spacing_m).reshape(wx.shape)
    planes = np.full((len(order), 3), np.nan)
    for m in range(len(order)):
        if np.all(np.isfinite(wz[m])):
            planes[m] = contact_plane(np.stack([wx[m], wy[m], wz[m]], axis=1))

    out: list[ArrivalPoints] = []
    for path in paths:
        P = path.arrival_ns.size
        value = np.full(P, np.nan)
        err = np.full(P, np.nan)
        err_cp = np.full(P, np.nan)
        sigma = np.full(P, np.nan)
        for m, msg in enumerate(order):
            track = _track_name(msg.profiles, path.name)
            if track is None:
                continue
            first = int(np.searchsorted(path.arrival_ns, msg.available_ns(lead_ns), side="left"))
            if first >= P:
                continue
            idx = np.arange(first, P)
            x, y = path.xy[idx, 0], path.xy[idx, 1]
            if msg.reference == REFERENCE_ROAD:
                dx, dy = x - cam_world[m, 0], y - cam_world[m, 1]
                local_x = np.cos(yaw_cam[m]) * dx + np.sin(yaw_cam[m]) * dy
                ref = np.full(idx.size, road_origin_z[m])
            else:
                z = np.where(np.isfinite(path.height[idx]), path.height[idx], pos[m, 2])
                rel = np.stack([x - pos[m, 0], y - pos[m, 1], z - pos[m, 2]], axis=1)
                local_x = rel @ R[m][:, 0]  # x in base_link at the stamp
                ref = planes[m, 0] + planes[m, 1] * x + planes[m, 2] * y
            read, read_sigma = read_profile_with_sigma(msg.profiles, track, local_x)
            hit = np.isfinite(read)
            if not hit.any():
                continue
            sel = idx[hit]
            value[sel] = read[hit] + ref[hit]  # later messages overwrite earlier ones: the latest one wins
            err[sel] = read[hit] - (path.height[sel] - ref[hit])
            cp = planes[m, 0] + planes[m, 1] * x[hit] + planes[m, 2] * y[hit]
            err_cp[sel] = read[hit] - (path.height[sel] - cp)
            sigma[sel] = read_sigma[hit]
        known = np.isfinite(path.height)
        covered = known & np.isfinite(err)
        along = np.arange(P) * settings.spacing_m
        out.append(ArrivalPoints(path, along, value, err, err_cp, known, covered, sigma))
    return out


def preview_at_arrival(
    previews: Sequence[TimedPreview],
    truth: Trajectory,
    road_map: RoadMap,
    settings: ArrivalSettings | None = None,
    *,
    frame_stamps_ns: Sequence[int] | None = None,
) -> dict[str, Any]:
    """Score preview messages at the moment each front wheel arrives (docs/interface/evaluation.md).

    Args:
        previews: the messages, any order.
        truth: the true ``base_link`` poses in ``odom`` (covering the arrivals).
        road_map: the true road in ``odom``.
        settings: lead time, footprint, vehicle, camera mounting.
        frame_stamps_ns: the camera frames' stamps (default: the previews' stamps); arrivals
            run from the first + lead to the last + lead.

    Returns:
        The ``preview_at_arrival`` keys of docs/interface/evaluation.md (:data:`ARRIVAL_KEYS`; errors in cm, NaN
        without a covered point) plus ``covered_points``, ``features_points``,
        ``smooth_points``, ``features_coverage_pct`` and ``per_wheel`` (the same per front wheel).

    Raises:
        ArrivalError: no previews or frames, or truth that does not cover the arrivals.
    """
    settings = settings or ArrivalSettings()
    points = arrival_points(previews, truth, road_map, settings, frame_stamps_ns=frame_stamps_ns)
    return summarise_points(points, settings.lead_time_s)


class WheelErrors(NamedTuple):
    """What the ``preview_at_arrival`` keys of one front wheel are computed from: its path
    points' errors and masks (:class:`ArrivalPoints` without the path). Points of several drives
    concatenate, so the keys over many drives are those of all their points at once.

    Attributes:
        error: [P] preview - true height (m; NaN where missing or the truth is unknown).
        error_contact_plane: [P] the same against the true contact plane.
        feature: [P] bool a feature point.
        known: [P] bool the true height is known.
        covered: [P] bool known and a message covered the point.
        sigma: [P] the 1-sigma the message gave there (m; NaN = none).
    """

    error: np.ndarray
    error_contact_plane: np.ndarray
    feature: np.ndarray
    known: np.ndarray
    covered: np.ndarray
    sigma: np.ndarray

    def concat(self, other: WheelErrors) -> WheelErrors:
        """These points followed by ``other``'s."""
        return WheelErrors(*(np.concatenate([a, b]) for a, b in zip(self, other, strict=True)))


def wheel_errors(points: Sequence[ArrivalPoints]) -> dict[str, WheelErrors]:
    """Front wheel name -> its :class:`WheelErrors` of :func:`arrival_points`."""
    return {p.path.name: WheelErrors(p.error, p.error_contact_plane, p.path.feature, p.known, p.covered,
                                     p.preview_sigma) for p in points}


def summarise_points(points: Sequence[ArrivalPoints], lead_time_s: float) -> dict[str, Any]:
    """The ``preview_at_arrival`` keys over :func:`arrival_points` (pooled over the wheels, and ``per_wheel``)."""
    return summarise_errors(wheel_errors(points), lead_time_s)


def summarise_errors(wheels: Mapping[str, WheelErrors], lead_time_s: float) -> dict[str, Any]:
    """The ``preview_at_arrival`` keys over each front wheel's points (pooled over the wheels,
    in their order, and ``per_wheel``)."""
    per_wheel = {name: _summary(*w, lead_time_s) for name, w in wheels.items()}
    pooled = WheelErrors(*(np.concatenate(parts) for parts in zip(*wheels.values(), strict=True)))
    out = _summary(*pooled, lead_time_s)
    out["per_wheel"] = per_wheel
    return out


def _summary(err: np.ndarray, err_cp: np.ndarray, feature: np.ndarray, known: np.ndarray, covered: np.ndarray,
             sigma: np.ndarray, lead: float) -> dict[str, Any]:
    points = int(known.sum())
    # the sigma the preview gave at each covered point, scored as a map cell's is (one definition)
    honesty = sigma_metrics(sigma_counts(np.where(covered, err, np.nan), sigma, np.zeros(err.shape)))
    abs_err, rmse, p95 = _stats(err[covered])
    feat, smooth = covered & feature, covered & ~feature
    cp = err_cp[covered & np.isfinite(err_cp)]
    n_feat = int((known & feature).sum())
    return {
        "lead_time_s": float(lead),
        "points": points,
        "abs_err_cm": abs_err,
        "rmse_cm": rmse,
        "p95_abs_err_cm": p95,
        "coverage_pct": 100.0 * int(covered.sum()) / points if points else math.nan,
        "features_abs_err_cm": _stats(err[feat])[0],
        "smooth_abs_err_cm": _stats(err[smooth])[0],
        "contact_plane_abs_err_cm": _stats(cp)[0],
        "covered_points": int(covered.sum()),
        "features_points": n_feat,
        "smooth_points": points - n_feat,
        "features_coverage_pct": 100.0 * int(feat.sum()) / n_feat if n_feat else math.nan,
        "sigma_points": int(honesty.pop("sigma_cells")),
        **honesty,
    }


def map_accuracy(windows: Sequence[MapWindow], road_map: RoadMap, truth: Trajectory | None = None,
                 vehicle: VehicleConfig | None = None, odometry: Trajectory | None = None) -> dict[str, Any]:
    """The fused map against the true road, time-averaged over frames (the ``"map"`` keys of
    docs/interface/evaluation.md).

    Per published window: ``abs_err_cm`` over the cells it holds (where the truth is known),
    ``coverage_pct`` the share of the window's cells (with truth) it holds; plus the sigma
    honesty of those cells (``within_1/2/3sigma_pct``, ``confident_wrong_pct``: error > 3 sigma
    and > 1 cm, ``mean_sigma_cm``). Each key is the mean over the windows (NaN without any).

    With ``truth`` (the true poses of ``base_link``) the map is scored as it is published, against
    the road under the car: each window's heights are compared after removing the median error of
    the cells under the car at its stamp (the rectangle between the four tyre contacts of
    ``vehicle``), which ``odom`` z's drift makes unknowable; ``datum_offset_cm`` is the mean
    absolute of those medians (how far the map's datum has drifted from the truth's). Without it
    the heights are compared in ``odom`` z as they are.

    The map is kept in the frame of the vehicle's own ``odometry`` ([K] poses of ``base_link``),
    which drifts from the truth's ``odom`` as the car drives (a wheel-speed scale error alone
    puts a feature decimetres away after a minute). With ``truth`` and ``odometry`` each window's
    cells are carried into the truth's frame through the car at the window's stamp (the
    odometry's planar pose of ``base_link`` to the true one), so the map is scored as the car
    uses it, around itself; without ``odometry`` the map is taken to be in the truth's frame.

    With ``truth`` the keys are also given per :data:`MAP_BAND_M` of distance ahead of the true
    ``base_link`` at each window's stamp (``bands``, near to far: :data:`MAP_BAND_KEYS`, each the
    mean over the windows holding cells in the band, and ``windows``); without it ``bands`` is empty.

    Raises:
        ArrivalError: no windows.
    """
    if not windows:
        raise ArrivalError("no map windows to score")
    return map_summary(map_window_rows(windows, road_map, truth, vehicle, odometry), len(windows))


def map_summary(rows: Mapping[str, Sequence[float]], windows: int) -> dict[str, Any]:
    """The ``"map"`` keys from :func:`map_window_rows` (each the mean over the windows that have
    it; NaN without any) and the number of windows published. Rows of several drives
    concatenate: the keys over many drives are the means over all their windows."""
    out: dict[str, Any] = {k: float(np.mean(rows.get(k, ()))) if len(rows.get(k, ())) else math.nan
                           for k in MAP_KEYS}
    out["windows"] = int(windows)
    bands: dict[int, dict[str, Any]] = {}
    for key, values in rows.items():
        if key.startswith(_BAND_ROW) and len(values):
            index, _, name = key[len(_BAND_ROW):].partition(":")
            band = bands.setdefault(int(index), {"x_from_m": int(index) * MAP_BAND_M,
                                                 "x_to_m": (int(index) + 1) * MAP_BAND_M})
            band[name] = float(np.mean(values))
            if name == "cells":
                band["windows"] = len(values)
    out["bands"] = [bands[i] for i in sorted(bands)]
    return out


def map_window_rows(windows: Sequence[MapWindow], road_map: RoadMap, truth: Trajectory | None = None,
                    vehicle: VehicleConfig | None = None, odometry: Trajectory | None = None
                    ) -> dict[str, list[float]]:
    """Per :data:`MAP_KEYS` key, its value on each window that has one (see :func:`map_accuracy`);
    with ``truth``, per distance band of :data:`MAP_BAND_M` ahead of the true ``base_link`` that a
    window holds cells in, each of :data:`MAP_BAND_KEYS` under ``band:<index>:<key>``
    (:func:`map_summary` gathers them)."""
    rows: dict[str, list[float]] = {k: [] for k in MAP_KEYS}
    vehicle = vehicle or VehicleConfig()
    # [W, 3] (x, y, yaw) of base_link at each window's stamp, in the truth's frame and in the map's
    stamps = np.array([int(w.stamp_ns) for w in windows], np.int64)
    true_poses = truth.planar(stamps) if truth is not None and windows else None
    held_poses = odometry.planar(stamps) if true_poses is not None and odometry is not None else None
    for index, window in enumerate(windows):
        x, y = window.cell_centres()
        gx, gy = np.meshgrid(x, y, indexing="ij")
        if true_poses is not None and held_poses is not None:
            gx, gy = carried_through_car(gx, gy, held_poses[index], true_poses[index])
        true_z = road_map.height(gx, gy)  # [n_rows, n_cols]
        known = np.isfinite(true_z)
        held = known & np.isfinite(window.elevation) & np.isfinite(window.uncertainty)
        if not known.any():
            continue
        rows["coverage_pct"].append(100.0 * held.sum() / known.sum())
        if not held.any():
            continue
        error = window.elevation.astype(np.float64) - true_z
        if truth is not None:
            offset = _offset_under_the_car(error, held, gx, gy, truth, int(window.stamp_ns), vehicle)
            if not math.isfinite(offset):
                continue  # the map holds nothing under the car yet: no anchor to score against
            rows["datum_offset_cm"].append(100.0 * abs(offset))
            error = error - offset
        err = np.abs(error[held])
        sigma = window.uncertainty[held].astype(np.float64)
        scores = _scores(err, sigma)
        for name in MAP_KEYS:
            if name in scores:  # the coverage and the datum's offset are the window's, above
                rows[name].append(scores[name])
        if true_poses is not None:
            car = true_poses[index]
            ahead = math.cos(float(car[2])) * (gx[held] - car[0]) + math.sin(float(car[2])) * (gy[held] - car[1])
            _append_bands(rows, np.floor(ahead / MAP_BAND_M).astype(np.int64), err, sigma)
    return rows


def _scores(err: np.ndarray, sigma: np.ndarray) -> dict[str, float]:
    """The map's scores of cells with absolute errors ``err`` [N] and sigma [N] (m): the mean error
    and the cell count, and the sigma keys by the evaluation's one rule
    (:func:`roadbev_lab.evaluation.metrics.sigma_counts`)."""
    return {**{k: float(v) for k, v in sigma_metrics(sigma_counts(err, sigma, np.zeros_like(err))).items()},
            "abs_err_cm": 100.0 * float(err.mean()), "cells": float(err.size)}


def _append_bands(rows: dict[str, list[float]], band: np.ndarray, err: np.ndarray, sigma: np.ndarray) -> None:
    """One window's :data:`MAP_BAND_KEYS` per band it holds cells in: ``band`` [N] each held
    cell's band index, ``err`` / ``sigma`` [N] its absolute error and sigma (m) (:func:`_scores`)."""
    for index in np.unique(band):
        inside = band == index
        values = _scores(err[inside], sigma[inside])
        for name in MAP_BAND_KEYS:
            rows.setdefault(f"{_BAND_ROW}{int(index)}:{name}", []).append(values[name])


def carried_through_car(x: np.ndarray, y: np.ndarray, held: np.ndarray, true: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Points (x, y) [...] of a frame in which ``base_link`` is at ``held`` ((x, y, yaw) [3]),
    carried rigidly to the frame in which it is at ``true`` [3]: the same places relative to the car."""
    dx, dy = x - held[0], y - held[1]
    c, s = math.cos(float(held[2])), math.sin(float(held[2]))
    along, across = c * dx + s * dy, -s * dx + c * dy  # in base_link
    c, s = math.cos(float(true[2])), math.sin(float(true[2]))
    return true[0] + c * along - s * across, true[1] + s * along + c * across


def _offset_under_the_car(error: np.ndarray, held: np.ndarray, gx: np.ndarray, gy: np.ndarray, truth: Trajectory,
                          stamp_ns: int, vehicle: VehicleConfig) -> float:
    """The median map error [n_rows, n_cols] over the held cells between the tyre contacts at
    ``stamp_ns`` (NaN when the map holds none there)."""
    pos, R = truth.interpolate(np.array([stamp_ns], np.int64))
    yaw = float(planar_yaw(R)[0])
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = gx - pos[0, 0], gy - pos[0, 1]
    along, across = c * dx + s * dy, -s * dx + c * dy
    half = 0.5 * vehicle.track_width_m
    under = held & (along >= 0.0) & (along <= vehicle.wheelbase_m) & (np.abs(across) <= half)
    return float(np.median(error[under])) if under.any() else math.nan


def camera_in_odom(pos: np.ndarray, R: np.ndarray, settings: ArrivalSettings) -> tuple[np.ndarray, np.ndarray]:
    """The camera's position [M, 3] in ``odom`` and the yaw [M] of its body, from ``base_link``'s
    poses (``pos`` [M, 3], ``R`` [M, 3, 3]) and the camera's mounting in ``settings``
    (``camera_in_base`` when known, else ``vehicle.camera_position_m`` with the body level)."""
    if settings.camera_in_base is not None:
        cam_pos = np.asarray(settings.camera_in_base[0], np.float64)
        R_base_cambody = np.asarray(settings.camera_in_base[1], np.float64) @ R_BODY_FROM_OPTICAL.T
    else:
        cam_pos = np.asarray(settings.vehicle.camera_position_m, np.float64)
        R_base_cambody = np.eye(3)
    return pos + np.einsum("mij,j->mi", R, cam_pos), planar_yaw(np.einsum("mij,jk->mik", R, R_base_cambody))


def per_frame_previews(outputs: Sequence[PipelineOutput]) -> list[TimedPreview]:
    """The pipeline's previews, stamped like their image, with the reference each declares
    (``roadbev_road`` per frame; ``contact_plane`` from the fused map)."""
    return [TimedPreview(o.stamp_ns, o.preview.reference, o.preview) for o in outputs if o.preview is not None]
