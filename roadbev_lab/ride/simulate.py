"""Pure simulation: the preview controller riding over a drive's true road, fed by a preview source.

For each front wheel a quarter car (:class:`QuarterCar`) rides the true road under that wheel's
actual path (the tyre footprint's mean height, ``tyre_width_m`` x ``patch_length_m``, on the
true road map, every ``dt``), and :class:`PreviewLqr` computes its force from the true state and
the road velocity ahead, which comes from one of the sources:

* ``"passive"``: no actuator (u = 0);
* ``"none"``: the same controller without preview (the feedback part only);
* ``"true"``: the true road under the wheel over the whole horizon (the ceiling);
* a sequence of :class:`roadbev_lab.evaluation.arrival.TimedPreview` messages: at each step the controller
  holds every message received so far (``received_ns``, else stamp + ``latency_s``); for every point of the wheel's
  future path it uses the latest held message that has a value there, read exactly as the
  preview-at-arrival metric reads it (:func:`roadbev_core.preview.read_profile`, the true
  ego-motion from the message's stamp, ``REFERENCE_ROAD`` x ahead of the camera with the
  camera's yaw, ``REFERENCE_CONTACT_PLANE`` x in ``base_link``). The road velocity at a point is
  the slope of that one message's profile between consecutive steps, so each message's own
  reference offset drops out; where no held message has a value the road is taken flat
  (w' = 0). For contact-plane messages ``plane_slopes`` may give the plane's slopes (dz/dx,
  dz/dy in ``base_link``'s heading axes, heights vertical) so that the profile is put back on
  gravity; without it the plane's attitude reads as road. The controller applies its feedforward
  times the preview's gain measured on the road ridden so far
  (:mod:`roadbev_core.ride.preview_gain`, ``RideSettings.preview_gain``).

:func:`perfect_previews` makes the messages a perfect per-frame camera would send (the true road
cut to the grid's window at each frame's stamp): what the window alone allows; with
``visible_only`` the road the camera cannot see from where it is (:func:`hidden_from`: behind a
crest, a pothole's rim) is left out and bridged as the node's preview bridges gaps: what any
camera at that mount allows;
:func:`perfect_map_previews` those of a perfect fused map (contact-plane reference, from the
front tyre contact to the window's far edge), and :func:`true_plane_slopes` the attitude of
their plane, so that the cost of a contact-plane preview without its plane can be measured;
:func:`carried_plane_slopes` reads the plane a real message carries (the fused map's estimate).

Metrics per wheel over the scored span (:class:`RideMetrics`): ISO 2631-1 Wk-weighted RMS body
acceleration, peak suspension travel, RMS dynamic tyre load relative to the static load, RMS and
peak force. Pure numpy; shapes in the comments.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from roadbev_core.config import GridSpec, PreviewConfig
from roadbev_core.preview import PreviewProfiles, TrackProfile, bridge_gaps, read_profile
from roadbev_core.ride.preview_gain import DEFAULT_TIME_CONSTANT_S, preview_gains
from roadbev_core.ride.preview_lqr import PreviewLqr
from roadbev_core.ride.quarter_car import FRONT_WHEELS, RideError
from roadbev_core.vehicle import contact_plane, planar_yaw
from roadbev_lab.evaluation.arrival import (
    REFERENCE_CONTACT_PLANE,
    REFERENCE_ROAD,
    ArrivalSettings,
    RoadMap,
    TimedPreview,
    Trajectory,
    camera_in_odom,
)
from roadbev_lab.ride.iso2631 import weighted_rms

__all__ = [
    "PlaneSlopes",
    "RideMetrics",
    "RideSettings",
    "WheelRoad",
    "carried_plane_slopes",
    "gain_share",
    "hidden_from",
    "perfect_map_previews",
    "perfect_previews",
    "preview_feedforward",
    "ride",
    "ride_metrics",
    "simulate",
    "true_contact_planes",
    "true_plane_slopes",
    "wheel_road",
]

_WHEEL_INDEX = {"front_left": 0, "front_right": 1, "rear_left": 2, "rear_right": 3}
_TRACKS = {"front_left": ("front_left", "left"), "front_right": ("front_right", "right")}
# (dz/dx, dz/dy) of a contact-plane message's plane, or None when unknown
PlaneSlopes = Callable[[TimedPreview], "tuple[float, float] | None"]
Source = str | Sequence[TimedPreview]


@dataclass(frozen=True)
class RideSettings:
    """How the simulation runs and reads previews.

    Attributes:
        controller: the car and its preview LQR (step, horizon, weights).
        latency_s: a message is held from its stamp + this.
        tyre_width_m, patch_length_m: the tyre footprint averaged under the wheel (the drives'
            own tyre patch is 12 cm long).
        warmup_s: skipped at the start of the scored span (the first messages arrive, the filter settles).
        arrival: vehicle geometry, camera mounting and ``base_height`` (as the arrival metric).
        preview_gain: the controller scales its feedforward from messages by the preview's
            measured gain (:mod:`roadbev_core.ride.preview_gain`), as the reference controller does.
        gain_time_constant_s: the forgetting time constant of that gain.
    """

    controller: PreviewLqr = field(default_factory=PreviewLqr)
    latency_s: float = 0.1
    tyre_width_m: float = 0.20
    patch_length_m: float = 0.12
    warmup_s: float = 1.0
    arrival: ArrivalSettings = field(default_factory=ArrivalSettings)
    preview_gain: bool = True
    gain_time_constant_s: float = DEFAULT_TIME_CONSTANT_S

    def __post_init__(self) -> None:
        if not (math.isfinite(self.latency_s) and 0.0 <= self.latency_s <= 2.0):
            raise RideError(f"latency must be in [0, 2] s, got {self.latency_s}")
        if not (0.0 < self.tyre_width_m <= 1.0 and 0.0 < self.patch_length_m <= 0.5):
            raise RideError("tyre width must be in (0, 1] m and the patch length in (0, 0.5] m")
        if not (math.isfinite(self.warmup_s) and self.warmup_s >= 0.0):
            raise RideError(f"warm-up must be >= 0 s, got {self.warmup_s}")
        if not (math.isfinite(self.gain_time_constant_s) and self.gain_time_constant_s > 0.0):
            raise RideError(f"the preview gain's time constant must be > 0 s, got {self.gain_time_constant_s}")


class WheelRoad(NamedTuple):
    """One wheel's true path and road at the control steps.

    Attributes:
        name: the wheel (``front_left``, ...).
        stamp_ns: [J] int64, every ``dt``.
        xy: [J, 2] contact point in ``odom``.
        heading: [J] direction of travel (rad).
        height: [J] true road height under the tyre (footprint mean, m).
    """

    name: str
    stamp_ns: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    height: np.ndarray

    def road_velocity(self, dt: float) -> np.ndarray:
        """[J] w' held over each step (exact for a road linear between steps; 0 at the end)."""
        return np.append(np.diff(self.height) / dt, 0.0)


def wheel_road(truth: Trajectory, road_map: RoadMap, settings: RideSettings, wheel: str, start_ns: int,
               end_ns: int) -> WheelRoad:
    """The path and true road of ``wheel`` every ``dt`` from ``start_ns`` to ``end_ns``.

    Raises:
        RideError: an unknown wheel, a span outside the truth, or road unknown under the path.
    """
    if wheel not in _WHEEL_INDEX:
        raise RideError(f"unknown wheel {wheel!r} (one of {sorted(_WHEEL_INDEX)})")
    truth.check()
    if start_ns < truth.stamp_ns[0] or end_ns > truth.stamp_ns[-1] or end_ns <= start_ns:
        raise RideError("the ride span must lie inside the true poses")
    dt_ns = int(round(settings.controller.dt * 1e9))
    stamps = np.arange(int(start_ns), int(end_ns) + 1, dt_ns, dtype=np.int64)  # [J]
    planar = truth.planar(stamps)  # [J, 3]
    wx, wy = settings.arrival.vehicle.wheel_positions()[_WHEEL_INDEX[wheel]]
    c, s = np.cos(planar[:, 2]), np.sin(planar[:, 2])
    xy = np.stack([planar[:, 0] + c * wx - s * wy, planar[:, 1] + s * wx + c * wy], axis=1)
    heading = np.unwrap(np.arctan2(np.gradient(xy[:, 1]), np.gradient(xy[:, 0])))
    height = road_map.footprint(xy[:, 0], xy[:, 1], heading, settings.tyre_width_m, settings.patch_length_m)
    if not np.all(np.isfinite(height)):
        raise RideError(f"the true road map does not cover {wheel}'s path")
    return WheelRoad(wheel, stamps, xy, heading, height)


def _track_name(profiles: PreviewProfiles, wheel: str) -> str | None:
    names = {t.name for t in profiles.tracks}
    return next((n for n in _TRACKS.get(wheel, ()) if n in names), None)


def _camera_poses(truth: Trajectory, settings: ArrivalSettings, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera position [M, 3] in ``odom`` and the yaw [M] of its body at ``stamps`` (as the arrival metric)."""
    pos, R = truth.interpolate(stamps)
    return camera_in_odom(pos, R, settings)


def preview_feedforward(previews: Sequence[TimedPreview], road: WheelRoad, truth: Trajectory, settings: RideSettings,
                        plane_slopes: PlaneSlopes | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The preview term of the controller at every step of ``road`` fed by ``previews``.

    Returns:
        (feedforward [J] (N), covered [J] bool, true where a held message gave the road velocity
        at that step's own point when the wheel got there).
    """
    ctl = settings.controller
    dt = ctl.dt
    J = road.stamp_ns.size
    n = ctl.steps
    order = sorted(previews, key=lambda p: p.stamp_ns)
    lat_ns = int(round(settings.latency_s * 1e9))
    ff = np.zeros(J)
    known = np.full(J, np.nan)  # road velocity at each step from the latest held message that has one
    covered = np.zeros(J, bool)
    if not order:
        return ff, covered
    stamps = np.array([p.stamp_ns for p in order], np.int64)
    available = np.array([p.available_ns(lat_ns) for p in order], np.int64)
    receive = np.searchsorted(road.stamp_ns, available, side="left")  # [M] first step holding it
    cam_world, yaw_cam = _camera_poses(truth, settings.arrival, stamps)
    base_pos, base_R = truth.interpolate(stamps)
    x, y = road.xy[:, 0], road.xy[:, 1]
    gains = ctl.preview_gains
    for m, msg in enumerate(order):
        first = int(receive[m])
        if first >= J:
            break
        track = _track_name(msg.profiles, road.name)
        if track is not None:
            idx = np.arange(first, J)
            if msg.reference == REFERENCE_ROAD:
                dx, dy = x[idx] - cam_world[m, 0], y[idx] - cam_world[m, 1]
                local_x = np.cos(yaw_cam[m]) * dx + np.sin(yaw_cam[m]) * dy
                local_y = None
            else:
                rel = np.stack([x[idx] - base_pos[m, 0], y[idx] - base_pos[m, 1], road.height[idx] - base_pos[m, 2]], 1)
                local_x = rel @ base_R[m][:, 0]
                local_y = rel @ base_R[m][:, 1]
            lo = msg.profiles.start_distance - msg.profiles.spacing
            hi = msg.profiles.start_distance + msg.profiles.n_samples * msg.profiles.spacing
            inside = (local_x >= lo) & (local_x <= hi)
            if inside.any():
                sel = idx[inside]
                h = np.full(J, np.nan)
                h[sel] = read_profile(msg.profiles, track, local_x[inside])
                if msg.reference == REFERENCE_CONTACT_PLANE and plane_slopes is not None and local_y is not None:
                    slopes = plane_slopes(msg)
                    if slopes is not None:
                        h[sel] += slopes[0] * local_x[inside] + slopes[1] * local_y[inside]
                w = np.append(np.diff(h) / dt, np.nan)  # [J] NaN unless both ends known in this message
                ok = np.isfinite(w)
                known[ok] = w[ok]  # the latest message that has a value wins
        stop = int(receive[m + 1]) if m + 1 < len(order) else J
        stop = min(stop, J)
        if stop <= first:
            continue
        covered[first:stop] = np.isfinite(known[first:stop])
        seg = np.nan_to_num(known[first: min(stop + n, J)], nan=0.0)
        seg = np.concatenate([seg, np.zeros(stop - first + n - seg.size)])
        ff[first:stop] = np.correlate(seg, gains, mode="valid")[: stop - first]
    return ff, covered


def simulate(controller: PreviewLqr, road_velocity: np.ndarray, feedforward: np.ndarray | None,
             *, passive: bool = False) -> dict[str, np.ndarray]:
    """Run the quarter car over ``road_velocity`` [J] from static equilibrium.

    Args:
        feedforward: [J] the preview term (None: the controller without preview).
        passive: no actuator at all.

    Returns:
        ``state`` [J, 4], ``force`` [J] (N), ``acceleration`` [J] body (m/s^2).
    """
    Phi, Gu, Gw = controller.matrices
    w = np.asarray(road_velocity, np.float64)
    J = w.size
    K = np.zeros(4) if passive else controller.feedback
    ff = np.zeros(J) if (passive or feedforward is None) else np.asarray(feedforward, np.float64)
    if ff.shape != (J,):
        raise RideError(f"feedforward {ff.shape} does not match the road ({J},)")
    Ac = Phi - Gu @ K[None, :]
    gu, gw = Gu[:, 0], Gw[:, 0]
    drive = gw[None, :] * w[:, None] - gu[None, :] * ff[:, None]  # [J, 4]
    x = np.zeros(4)
    states = np.empty((J, 4))
    AcT = Ac.T
    for j in range(J):
        states[j] = x
        x = x @ AcT + drive[j]
    force = -(states @ K) - ff
    C, D = controller.car.body_acceleration()
    return {"state": states, "force": force, "acceleration": states @ C + D[0] * force}


class RideMetrics(NamedTuple):
    """What a passenger and the chassis feel over the scored span.

    Attributes:
        wk_rms_mps2: ISO 2631-1 Wk-weighted RMS body acceleration (m/s^2).
        peak_travel_m: largest |suspension deflection| from static (m).
        tyre_load_rms_ratio: RMS dynamic tyre load / static load.
        force_rms_n, force_peak_n: actuator force.
        preview_coverage_pct: share of steps where a held message covered the wheel's own point
            (NaN for sources without messages).
    """

    wk_rms_mps2: float
    peak_travel_m: float
    tyre_load_rms_ratio: float
    force_rms_n: float
    force_peak_n: float
    preview_coverage_pct: float

    def to_dict(self) -> dict[str, float]:
        return dict(self._asdict())


def ride_metrics(result: dict[str, np.ndarray], controller: PreviewLqr, start: int,
                 covered: np.ndarray | None = None) -> RideMetrics:
    """Metrics of one :func:`simulate` result over steps ``start:`` (the Wk filter runs from step 0)."""
    s = result["state"][start:]
    f = result["force"][start:]
    if s.shape[0] == 0:
        raise RideError("nothing to score after the warm-up")
    car = controller.car
    tyre = car.tyre_n_per_m * s[:, 2] / car.static_tyre_load_n
    return RideMetrics(
        wk_rms_mps2=weighted_rms(result["acceleration"], 1.0 / controller.dt, start),
        peak_travel_m=float(np.abs(s[:, 0]).max()),
        tyre_load_rms_ratio=float(np.sqrt(np.mean(tyre * tyre))),
        force_rms_n=float(np.sqrt(np.mean(f * f))),
        force_peak_n=float(np.abs(f).max()),
        preview_coverage_pct=math.nan if covered is None else 100.0 * float(covered[start:].mean()),
    )


def ride(truth: Trajectory, road_map: RoadMap, sources: Mapping[str, Source], settings: RideSettings, start_ns: int,
         end_ns: int, score_end_ns: int | None = None, plane_slopes: Mapping[str, PlaneSlopes] | None = None,
         wheels: Sequence[str] = FRONT_WHEELS) -> dict[str, dict[str, Any]]:
    """Ride every source over the drive's true road (both front wheels) and score it.

    Args:
        sources: name -> ``"passive"``, ``"none"``, ``"true"`` or a sequence of messages.
        start_ns, end_ns: the simulated span (inside the truth; ``end_ns`` should leave the
            ceiling a full horizon of true road beyond ``score_end_ns``).
        score_end_ns: the scored span ends here (default ``end_ns``); it starts ``warmup_s``
            after ``start_ns``.
        plane_slopes: source name -> the slopes of its contact-plane messages' planes
            (sources not named read contact-plane profiles without them).

    Returns:
        source -> {"mean": metrics averaged over the wheels, wheel: metrics}.
    """
    ctl = settings.controller
    out: dict[str, dict[str, Any]] = {name: {} for name in sources}
    for wheel in wheels:
        road = wheel_road(truth, road_map, settings, wheel, start_ns, end_ns)
        w = road.road_velocity(ctl.dt)
        first = int(np.searchsorted(road.stamp_ns, start_ns + int(round(settings.warmup_s * 1e9))))
        last = road.stamp_ns.size if score_end_ns is None else \
            int(np.searchsorted(road.stamp_ns, score_end_ns, "right"))
        for name, source in sources.items():
            covered = None
            if isinstance(source, str):
                if source not in ("passive", "none", "true"):
                    raise RideError(f"unknown preview source {source!r}")
                ff = ctl.feedforward(w) if source == "true" else None
                result = simulate(ctl, w, ff, passive=source == "passive")
            else:
                ff, covered = preview_feedforward(source, road, truth, settings, (plane_slopes or {}).get(name))
                if settings.preview_gain:  # the road ridden so far says how much of the preview to trust
                    ff = ff * preview_gains(ff, ctl.feedforward(w), ctl.steps, ctl.dt, settings.gain_time_constant_s)
                result = simulate(ctl, w, ff)
            cut = {k: v[:last] for k, v in result.items()}
            out[name][wheel] = ride_metrics(cut, ctl, first, None if covered is None else covered[:last]).to_dict()
    for name in sources:
        keys = out[name][wheels[0]].keys()
        out[name]["mean"] = {k: float(np.mean([out[name][wh][k] for wh in wheels])) for k in keys}
    return out


def gain_share(no_preview: float, ceiling: float, value: float) -> float:
    """The share of the ceiling's gain over the no-preview controller that ``value`` delivers
    ((no_preview - value) / (no_preview - ceiling); NaN when the ceiling gains nothing)."""
    gain = no_preview - ceiling
    if not (math.isfinite(gain) and gain > 1e-9 * max(abs(no_preview), 1e-12)):
        return math.nan
    return (no_preview - value) / gain


# Sight lines are tested against the road every RAY_STEP_M along the ground; a road point within
# TARGET_CLEARANCE_M of the target is the target's own surface, not an occluder.
RAY_STEP_M = 0.02
TARGET_CLEARANCE_M = 0.05
OCCLUSION_TOLERANCE_M = 0.002


def hidden_from(camera: np.ndarray, points: np.ndarray, road_map: RoadMap) -> np.ndarray:
    """[N] whether the road hides each point of ``points`` [N, 3] (odom) from ``camera`` [3]: the
    straight line between them passes below the true road (by more than
    :data:`OCCLUSION_TOLERANCE_M`) somewhere short of the point, tested every
    :data:`RAY_STEP_M` of ground; a point outside the map is not hidden by what lies outside."""
    c = np.asarray(camera, np.float64)
    p = np.asarray(points, np.float64)
    ground = np.hypot(p[:, 0] - c[0], p[:, 1] - c[1])  # [N]
    if ground.size == 0:
        return np.zeros(0, bool)
    steps = np.arange(1, int(math.ceil(float(ground.max()) / RAY_STEP_M)) + 1) * RAY_STEP_M  # [K]
    t = steps[None, :] / np.maximum(ground, 1e-9)[:, None]  # [N, K] fraction of the way to the point
    before = t < 1.0 - TARGET_CLEARANCE_M / np.maximum(ground, 1e-9)[:, None]
    x = c[0] + t * (p[:, 0:1] - c[0])  # [N, K]
    y = c[1] + t * (p[:, 1:2] - c[1])
    z = c[2] + t * (p[:, 2:3] - c[2])
    road = road_map.height(np.where(before, x, c[0]), np.where(before, y, c[1]))  # [N, K]
    with np.errstate(invalid="ignore"):
        below = before & (road > z + OCCLUSION_TOLERANCE_M)
    return np.asarray(below.any(axis=1))


def perfect_previews(truth: Trajectory, road_map: RoadMap, stamps_ns: Sequence[int], grid: GridSpec,
                     settings: RideSettings, track_offsets_m: Sequence[float] = (0.8, -0.8),
                     track_names: Sequence[str] = ("left", "right"), *, visible_only: bool = False,
                     max_gap_m: float = PreviewConfig().max_gap_m) -> list[TimedPreview]:
    """The per-frame messages (``REFERENCE_ROAD``) a perfect camera would send at ``stamps_ns``:
    the true road (footprint ``tyre_width_m`` x ``patch_length_m``) along each track, at the
    grid's sample positions (x from ``grid.x_min`` + half a cell to ``grid.x_max``, one cell
    apart, ahead of the camera with its yaw), relative to the plane ``base_height`` below the camera.

    With ``visible_only`` a sample whose track centre the road hides from the camera
    (:func:`hidden_from`) has no value, and gaps of at most ``max_gap_m`` are bridged as the
    node's preview bridges them (:func:`roadbev_core.preview.bridge_gaps`)."""
    stamps = np.asarray(list(stamps_ns), np.int64)
    cam_world, yaw = _camera_poses(truth, settings.arrival, stamps)
    spacing = grid.resolution
    start = grid.x_min + 0.5 * spacing
    xs = start + np.arange(int(math.floor((grid.x_max - grid.x_min) / spacing + 1e-9))) * spacing  # [S]
    out = []
    for m, stamp in enumerate(stamps.tolist()):
        c, s = math.cos(yaw[m]), math.sin(yaw[m])
        tracks = []
        for name, offset in zip(track_names, track_offsets_m, strict=True):
            px = cam_world[m, 0] + c * xs - s * offset
            py = cam_world[m, 1] + s * xs + c * offset
            h = road_map.footprint(px, py, np.full(xs.size, yaw[m]), settings.tyre_width_m, settings.patch_length_m)
            rel = (h - (cam_world[m, 2] - settings.arrival.base_height)).astype(np.float32)
            sigma = np.zeros_like(rel)
            if visible_only:
                centre = np.stack([px, py, road_map.height(px, py)], axis=1)  # [S, 3]
                rel[hidden_from(cam_world[m], centre, road_map)] = np.nan
                rel, sigma = bridge_gaps(rel, np.where(np.isfinite(rel), 0.0, np.nan), spacing, max_gap_m)
            tracks.append(TrackProfile(name, float(offset), settings.tyre_width_m, rel, sigma))
        profiles = PreviewProfiles(float(start), float(spacing), tuple(tracks))
        out.append(TimedPreview(int(stamp), REFERENCE_ROAD, profiles))
    return out


def true_contact_planes(truth: Trajectory, road_map: RoadMap, settings: RideSettings,
                        stamps_ns: np.ndarray) -> np.ndarray:
    """[M, 3] (a, b, c) of ``z = a + b x + c y`` in ``odom``: the least-squares plane through the four
    true tyre contacts (footprint means) at ``stamps_ns`` [M], as the preview-at-arrival metric defines it."""
    pos, R = truth.interpolate(np.asarray(stamps_ns, np.int64))
    yaw = planar_yaw(R)
    wheels = settings.arrival.vehicle.wheel_positions()  # [4, 2]
    cb, sb = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    wx = pos[:, 0:1] + cb * wheels[:, 0] - sb * wheels[:, 1]  # [M, 4]
    wy = pos[:, 1:2] + sb * wheels[:, 0] + cb * wheels[:, 1]
    wz = road_map.footprint(wx.ravel(), wy.ravel(), np.repeat(yaw, 4), settings.tyre_width_m,
                            settings.patch_length_m).reshape(wx.shape)
    if not np.all(np.isfinite(wz)):
        raise RideError("the true road map does not cover the tyre contacts")
    return contact_plane(np.stack([wx, wy, wz], axis=2))


def perfect_map_previews(truth: Trajectory, road_map: RoadMap, stamps_ns: Sequence[int], grid: GridSpec,
                         settings: RideSettings) -> list[TimedPreview]:
    """The messages a perfect fused map would send at ``stamps_ns`` (``REFERENCE_CONTACT_PLANE``):
    the true road along each front wheel's line ahead in ``base_link`` (x from the front tyre
    contact to the camera's x + ``grid.x_max``, one grid cell apart, tracks ``front_left`` /
    ``front_right``), heights relative to the true contact plane at the stamp."""
    stamps = np.asarray(list(stamps_ns), np.int64)
    vehicle = settings.arrival.vehicle
    pos, R = truth.interpolate(stamps)
    planes = true_contact_planes(truth, road_map, settings, stamps)
    cam_x = float(settings.arrival.camera_in_base[0][0]) if settings.arrival.camera_in_base is not None \
        else vehicle.camera_position_m[0]
    spacing = grid.resolution
    start = vehicle.wheelbase_m
    xs = start + np.arange(int(math.floor((cam_x + grid.x_max - start) / spacing + 1e-9)) + 1) * spacing  # [S]
    half = 0.5 * vehicle.track_width_m
    yaw = planar_yaw(R)
    out = []
    for m, stamp in enumerate(stamps.tolist()):
        tracks = []
        for name, offset in (("front_left", half), ("front_right", -half)):
            body = np.stack([xs, np.full(xs.size, offset), np.zeros(xs.size)], axis=1)  # [S, 3] on base_link's plane
            world = pos[m] + body @ R[m].T
            h = road_map.footprint(world[:, 0], world[:, 1], np.full(xs.size, yaw[m]), settings.tyre_width_m,
                                   settings.patch_length_m)
            ref = planes[m, 0] + planes[m, 1] * world[:, 0] + planes[m, 2] * world[:, 1]
            rel = (h - ref).astype(np.float32)
            tracks.append(TrackProfile(name, float(offset), settings.tyre_width_m, rel, np.zeros_like(rel)))
        profiles = PreviewProfiles(float(start), float(spacing), tuple(tracks), reference_distance=float(start))
        out.append(TimedPreview(int(stamp), REFERENCE_CONTACT_PLANE, profiles))
    return out


def true_plane_slopes(truth: Trajectory, road_map: RoadMap, settings: RideSettings,
                      stamps_ns: Sequence[int] = ()) -> PlaneSlopes:
    """The true contact plane's slopes (dz/dx, dz/dy along ``base_link``'s heading axes) at a
    message's stamp: what a message carrying its plane's attitude lets a controller undo
    (precomputed for ``stamps_ns``, computed on demand for other stamps)."""

    def compute(stamps: np.ndarray) -> np.ndarray:  # [M] -> [M, 2]
        _, R = truth.interpolate(stamps)
        planes = true_contact_planes(truth, road_map, settings, stamps)
        yaw = planar_yaw(R)
        c, s = np.cos(yaw), np.sin(yaw)
        return np.stack([planes[:, 1] * c + planes[:, 2] * s, -planes[:, 1] * s + planes[:, 2] * c], axis=1)

    known = np.asarray(list(stamps_ns), np.int64)
    table = {int(t): (float(v[0]), float(v[1])) for t, v in zip(known.tolist(), compute(known) if known.size else [],
                                                                 strict=True)}

    def slopes(msg: TimedPreview) -> tuple[float, float] | None:
        if msg.stamp_ns not in table:
            v = compute(np.array([msg.stamp_ns], np.int64))[0]
            table[msg.stamp_ns] = (float(v[0]), float(v[1]))
        return table[msg.stamp_ns]

    return slopes


def carried_plane_slopes(msg: TimedPreview) -> tuple[float, float] | None:
    """The slopes (dz/dx, dz/dy along ``base_link``'s heading axes) of the contact plane a
    message carries itself (:class:`roadbev_core.preview.ContactPlane`: ``z = height - x tan(pitch)
    + y tan(roll) / cos(pitch)``), as a controller reading ``RoadPreview``'s contact-plane fields
    would undo it; None for messages without one (per-frame previews) or with a non-finite or
    implausible (> ~27 deg) attitude."""
    plane = msg.profiles.contact_plane
    if msg.reference != REFERENCE_CONTACT_PLANE or plane is None:
        return None
    roll, pitch = float(plane.roll), float(plane.pitch)
    if not (math.isfinite(roll) and math.isfinite(pitch) and abs(roll) < 0.5 and abs(pitch) < 0.5):
        return None
    return -math.tan(pitch), math.tan(roll) / math.cos(pitch)
