"""The preview a controller uses: wheel-track profiles read from the fused map.

As docs/concepts/preview.md ("`contact_plane`: the preview from the fused map") defines it: for each
wheel track of the front axle (and the rear axle with ``preview.rear_axle``), samples every
``preview.spacing_m`` from the tyre's contact point forward to the map's far edge, x ahead of
``base_link``'s origin along its heading, each the mean height over the tyre's footprint
(``tyre_width_m`` across, one spacing along; at least half of it known, else NaN), **relative to the
contact plane**: the least-squares plane through the four tyre contacts on the map at the stamp
(heights measured vertically), so body heave, pitch and roll never appear as road. The plane itself
travels with the profiles (:class:`roadbev_core.preview.ContactPlane`).

The plane is the plain least-squares plane through the four contacts (each counts the same, as
the interface defines it); their sigmas set its covariance only. When the map lacks one contact
(a kerb top above the grid's height range, a cell the backend declined), the fourth is stood in
from the body's attitude (the IMU's) through the other three, with a sigma of the suspension's
travel (3 cm). Until the map holds three of the contacts (the first metres of a drive: the rear
contacts lie ~4 m behind the grid's near edge) the plane is that of the road the map holds ahead
of the front wheels, features trimmed, carried back under the car (``source`` = ``"road"``), with
the body's own plane at static ride height as its prior (its attitude from the IMU, its height
from the map's datum; 3 cm and 1 degree), which alone decides where the map holds too little
(``source`` = ``"body"``). A profile sample's sigma combines the map cells' (their mean over the
footprint: neighbouring cells' errors are correlated) and the plane's.

Pure numpy; shapes in the comments.
"""

from __future__ import annotations

import math

import numpy as np

from roadbev_core.config import VehicleConfig
from roadbev_core.fusion import FramePlacement, FusedMap
from roadbev_core.preview import REFERENCE_CONTACT_PLANE, ContactPlane, PreviewProfiles, TrackProfile, bridge_gaps
from roadbev_core.vehicle import WHEEL_NAMES, contact_plane

__all__ = ["BODY_PLANE_SIGMA", "contact_plane_fit", "contact_plane_on_map", "footprint_heights", "map_preview"]

# 1-sigma of the body's plane at static ride height against the road's (suspension deflection
# over bumps and under braking: a few cm and about a degree).
BODY_PLANE_SIGMA = (0.03, math.radians(1.0))
# The road ahead (before the map holds the contacts): samples along the front tracks this far
# apart, at least this many, and those further than this from the plane are features, trimmed.
_ROAD_SAMPLE_M = 0.15
_ROAD_MIN_SAMPLES = 12
_ROAD_TRIM_M = 0.015
_ROAD_CORRELATION = 0.1  # as the map's alignment counts one frame's cells (map.align_correlation)


def footprint_heights(fused: FusedMap, x: np.ndarray, y: np.ndarray, heading: float, width: float,
                      length: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean fused height and sigma over tyre footprints centred at odom points (x, y) [N].

    The footprint (``width`` across, ``length`` along ``heading``) is sampled every half map
    cell (bilinear between cell centres: finer samples would add no information); at least half
    of the samples must be known, else NaN.
    """
    step = 0.5 * fused.settings.resolution
    n_w = max(2, int(math.ceil(width / step)))
    n_l = max(1, int(math.ceil(length / step)))
    across = (np.arange(n_w) + 0.5) / n_w * width - 0.5 * width  # [n_w]
    along = (np.arange(n_l) + 0.5) / n_l * length - 0.5 * length  # [n_l]
    a, b = np.repeat(along, n_w), np.tile(across, n_l)  # [S] every (along, across) pair, along-major
    c, s = math.cos(heading), math.sin(heading)
    px = np.asarray(x)[:, None] + c * a - s * b  # [N, S]
    py = np.asarray(y)[:, None] + s * a + c * b
    z, sz = fused.heights(px, py)
    known = np.isfinite(z) & np.isfinite(sz)
    count = known.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(known, z, 0.0).sum(axis=1) / count
        sigma = np.where(known, sz, 0.0).sum(axis=1) / count
    ok = count >= 0.5 * a.size
    return np.where(ok, mean, np.nan), np.where(ok, sigma, np.nan)


def contact_plane_fit(points: np.ndarray, sigmas: np.ndarray, prior: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The plane ``z = p0 + p1 x + p2 y`` through points [K, 3] (x, y relative to a nearby
    origin) with 1-sigma heights [K].

    Without a prior it is the interface's contact plane: the least-squares plane in which every
    point counts the same, its covariance propagated from the sigmas. Weighting the points by
    their sigmas would move the plane itself, not only its noise, whenever the contacts are not
    coplanar (one wheel on a bump or a kerb), so that it no longer estimates the plane a
    controller needs. With a Gaussian prior (coefficients [3], covariance [3, 3]), which decides
    what fewer than three points leave open, it is the weighted (Bayesian) fit.

    Returns:
        coefficients [3] and their covariance [3, 3].
    """
    A = np.stack([np.ones(points.shape[0]), points[:, 0], points[:, 1]], 1)  # [K, 3]
    if prior is None:
        gain = np.linalg.inv(A.T @ A) @ A.T  # [3, K]: the plane's coefficients are linear in z
        return contact_plane(points), (gain * np.square(sigmas)[None, :]) @ gain.T
    w = 1.0 / np.square(sigmas)
    prior_mean, prior_info = prior[0], np.linalg.inv(prior[1])
    cov = np.linalg.inv((A * w[:, None]).T @ A + prior_info)
    coeffs = cov @ ((A * w[:, None]).T @ points[:, 2] + prior_info @ prior_mean)
    return coeffs, cov


def _plane_from_body(placement: FramePlacement, base_z: float) -> tuple[np.ndarray, np.ndarray]:
    """The body's x-y plane through its origin (relative coordinates), with BODY_PLANE_SIGMA."""
    n = placement.R_odom_base[:, 2]  # base_link's z axis in odom
    coeffs = np.array([base_z, -n[0] / n[2], -n[1] / n[2]])
    h, ang = BODY_PLANE_SIGMA
    return coeffs, np.diag([h * h, ang * ang, ang * ang])


def _as_contact_plane(coeffs: np.ndarray, cov: np.ndarray, heading: float, base_z: float, source: str
                      ) -> ContactPlane:
    """A plane ``z = p0 + p1 dx + p2 dy`` (odom axes, relative to base_link's origin) in the
    heading frame of ``base_link`` (see :class:`ContactPlane`)."""
    c, s = math.cos(heading), math.sin(heading)
    T = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])  # (p0, p1, p2) -> (h, g_along, g_across)
    h, gx, gy = T @ coeffs
    C = T @ cov @ T.T
    pitch = -math.atan(gx)
    roll = math.atan(gy * math.cos(pitch))
    return ContactPlane(
        height_m=float(h - base_z), roll=roll, pitch=pitch,
        height_sigma_m=float(math.sqrt(C[0, 0])),
        pitch_sigma=float(math.sqrt(C[1, 1]) / (1.0 + gx * gx)),
        roll_sigma=float(math.sqrt(C[2, 2]) / (1.0 + gy * gy)),
        source=source,
    )


def contact_plane_on_map(fused: FusedMap, placement: FramePlacement, vehicle: VehicleConfig, *,
                         tyre_width_m: float, spacing_m: float) -> tuple[np.ndarray, np.ndarray, ContactPlane]:
    """The contact plane under the car at ``placement``: its coefficients ``z = p0 + p1 dx + p2
    dy`` (odom axes, relative to ``base_link``'s origin) [3], their covariance [3, 3], and the
    plane as a :class:`ContactPlane` (see the module docstring)."""
    base = placement.base
    c, s = math.cos(base.yaw), math.sin(base.yaw)
    wheels = vehicle.wheel_positions()  # [4, 2] base_link
    wx = base.x + c * wheels[:, 0] - s * wheels[:, 1]  # [4] odom
    wy = base.y + s * wheels[:, 0] + c * wheels[:, 1]
    wz, wsig = footprint_heights(fused, wx, wy, base.yaw, tyre_width_m, spacing_m)
    base_z = fused.base_z if fused.base_z is not None else 0.0
    known = np.isfinite(wz) & np.isfinite(wsig) & (wsig > 0)
    dx, dy = wx - base.x, wy - base.y
    if known.sum() == 3:
        # The interface's plane runs through four contacts; the map lacks one (a kerb top the
        # backend declined, a hole). Three points alone would give the plane through them, degrees
        # off whenever the fourth stands on a step. Stand the fourth in from the body's attitude
        # (the IMU's) through the three, with the suspension's travel as its sigma.
        attitude = _plane_from_body(placement, base_z)[0]
        offset = float(np.mean(wz[known] - attitude[1] * dx[known] - attitude[2] * dy[known]))
        missing = ~known
        wz, wsig = wz.copy(), wsig.copy()
        wz[missing] = offset + attitude[1] * dx[missing] + attitude[2] * dy[missing]
        wsig[missing] = BODY_PLANE_SIGMA[0]
        known = np.ones(4, bool)
    if known.sum() >= 3:
        coeffs, cov = contact_plane_fit(np.stack([dx, dy, wz], 1)[known], wsig[known])
        return coeffs, cov, _as_contact_plane(coeffs, cov, base.yaw, base_z, "map")
    body = _plane_from_body(placement, base_z)
    road = _road_ahead(fused, placement, vehicle, tyre_width_m, body)
    if road is not None:
        return road[0], road[1], _as_contact_plane(road[0], road[1], base.yaw, base_z, "road")
    rel = np.stack([dx, dy, wz], 1)[known]
    coeffs, cov = contact_plane_fit(rel, wsig[known], body)
    return coeffs, cov, _as_contact_plane(coeffs, cov, base.yaw, base_z, "body")


def _road_ahead(fused: FusedMap, placement: FramePlacement, vehicle: VehicleConfig, tyre_width_m: float,
                prior: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """The plane of the road the map holds ahead of the front wheels, carried back under the car:
    ``z = p0 + p1 dx + p2 dy`` (odom axes, relative to ``base_link``'s origin) [3] and its
    covariance [3, 3], fitted to footprints along both front tracks with features trimmed (a bump
    does not tilt it) and the body's plane as a prior; None when the map holds too little there.

    Before the map holds the tyre contacts this is the best guess of the plane they will form: a
    road's grade and cross slope change over tens of metres, while the body's own plane is off the
    road's by the suspension's deflection (centimetres and a degree over bumps)."""
    base = placement.base
    c, s = math.cos(base.yaw), math.sin(base.yaw)
    wheels = vehicle.wheel_positions()
    x = np.arange(wheels[0, 0], fused.settings.ahead_m, _ROAD_SAMPLE_M)  # [S] base_link x ahead of the front axle
    y = wheels[:2, 1]  # [2] the front tracks
    bx, by = np.meshgrid(x, y, indexing="ij")  # [S, 2]
    px, py = base.x + c * bx - s * by, base.y + s * bx + c * by
    z, sz = footprint_heights(fused, px.ravel(), py.ravel(), base.yaw, tyre_width_m, _ROAD_SAMPLE_M)
    known = np.isfinite(z) & np.isfinite(sz)
    if known.sum() < _ROAD_MIN_SAMPLES or np.ptp(bx.ravel()[known]) < 1.0:
        return None
    points = np.stack([(px.ravel() - base.x)[known], (py.ravel() - base.y)[known], z[known]], 1)  # [K, 3]
    keep = np.ones(points.shape[0], bool)
    for _ in range(3):  # trim what stands off the plane (bumps, potholes, kerbs)
        A = np.stack([np.ones(int(keep.sum())), points[keep, 0], points[keep, 1]], 1)
        coeffs = np.linalg.lstsq(A, points[keep, 2], rcond=None)[0]
        residual = points[:, 2] - (coeffs[0] + coeffs[1] * points[:, 0] + coeffs[2] * points[:, 1])
        keep = np.abs(residual) <= _ROAD_TRIM_M
        if keep.sum() < _ROAD_MIN_SAMPLES:
            return None
    n = int(keep.sum())
    rms = float(np.sqrt(np.mean(residual[keep] ** 2)))
    # the road between the samples and the tyres is unseen: its unevenness (the residual) adds to
    # every sample's sigma, and the samples' errors are correlated (one estimate, neighbouring
    # cells): n of them are worth n / (1 + (n - 1) rho) independent ones
    worth = n / (1.0 + (n - 1) * _ROAD_CORRELATION)
    sigmas = np.sqrt(sz[known][keep] ** 2 + rms**2) * math.sqrt(n / worth)
    return contact_plane_fit(points[keep], sigmas, prior)


def map_preview(
    fused: FusedMap,
    placement: FramePlacement,
    vehicle: VehicleConfig,
    *,
    tyre_width_m: float,
    spacing_m: float,
    rear_axle: bool = False,
    vehicle_speed: float | None = None,
    max_gap_m: float = 0.0,
) -> PreviewProfiles:
    """The contact-plane profiles of every wheel track at the pose of ``placement`` (inner gaps
    up to ``max_gap_m`` bridged, :func:`roadbev_core.preview.bridge_gaps`).

    Returns:
        Profiles named ``front_left``, ``front_right`` (then ``rear_left``, ``rear_right``), all
        sampled at ``x_i = start + i * spacing`` in ``base_link`` (start: the front axle, or the
        rear axle with ``rear_axle``; a front track is NaN behind its own contact), times of
        arrival relative to the front axle.
    """
    base = placement.base
    c, s = math.cos(base.yaw), math.sin(base.yaw)
    wheels = vehicle.wheel_positions()  # [4, 2] base_link
    coeffs, cov, plane = contact_plane_on_map(fused, placement, vehicle, tyre_width_m=tyre_width_m,
                                              spacing_m=spacing_m)

    start = 0.0 if rear_axle else vehicle.wheelbase_m
    far = fused.settings.ahead_m
    n = max(int(math.floor((far - start) / spacing_m + 1e-9)) + 1, 1)
    x = start + np.arange(n) * spacing_m  # [S] base_link x
    n_tracks = 4 if rear_axle else 2
    wheel_y = wheels[:n_tracks, 1][:, None]  # [T, 1]
    px = base.x + c * x[None, :] - s * wheel_y  # [T, S] odom
    py = base.y + s * x[None, :] + c * wheel_y
    z, sz = footprint_heights(fused, px.ravel(), py.ravel(), base.yaw, tyre_width_m, spacing_m)  # all tracks at once
    dx, dy = px - base.x, py - base.y  # [T, S]
    ref = coeffs[0] + coeffs[1] * dx + coeffs[2] * dy
    ref_var = (cov[0, 0] + 2.0 * cov[0, 1] * dx + 2.0 * cov[0, 2] * dy + cov[1, 1] * dx * dx
               + 2.0 * cov[1, 2] * dx * dy + cov[2, 2] * dy * dy)  # g^T cov g, g = (1, dx, dy)
    elevation = z.reshape(px.shape) - ref
    sigma = np.sqrt(sz.reshape(px.shape) ** 2 + ref_var)
    behind = x[None, :] < wheels[:n_tracks, 0][:, None] - 1e-9  # a front track starts at its own contact
    elevation[behind] = np.nan
    sigma[behind | ~np.isfinite(elevation)] = np.nan
    tracks = [TrackProfile(WHEEL_NAMES[index], float(wheels[index, 1]), float(tyre_width_m),
                           *bridge_gaps(elevation[index], sigma[index], spacing_m, max_gap_m))
              for index in range(n_tracks)]
    return PreviewProfiles(
        start_distance=float(start), spacing=float(spacing_m), tracks=tuple(tracks),
        vehicle_speed=None if vehicle_speed is None else float(vehicle_speed),
        reference_distance=float(vehicle.wheelbase_m), reference=REFERENCE_CONTACT_PLANE, contact_plane=plane,
    )
