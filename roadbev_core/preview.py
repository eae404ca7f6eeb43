"""Wheel-track elevation profiles from a BEV elevation map, for a suspension controller.

A controller with road preview wants the road height under each wheel ahead, not the whole map:
for each track (a lateral offset in the road frame) the elevation averaged over the tyre's width
and over one sample spacing along x, nearest sample first, with its 1-sigma uncertainty.

Averaging is area-weighted: a sample's footprint is the rectangle
``[x - spacing/2, x + spacing/2] x [offset - width/2, offset + width/2]`` and each grid cell
counts with the area it shares with that rectangle, over the cells that have an estimate. A
sample whose footprint is less than ``min_coverage`` covered by estimated cells is NaN (no
guessing across holes). The uncertainty of a sample is the weighted mean of the cells' sigmas
(errors of neighbouring cells of one estimate are strongly correlated, so averaging does not
shrink them).

**Gaps.** A camera never sees some of the road a wheel will ride: the far side of a speed bump,
the near wall and part of the bottom of a pothole, cells a backend declined. A controller reads
the road *velocity* (the slope of a profile), so a hole it must take as flat turns a bump into a
step that never comes down. :func:`bridge_gaps` fills a gap of at most ``max_gap_m`` between
two known samples with the conditional mean of the road given its ends: the straight line (the
mean of a Brownian bridge, the ISO 8608 road's height being an integrated white noise), with a
sigma that says how little is known inside: the bridge's own spread for a road of roughness
:data:`BRIDGE_ROUGHNESS_M2_PER_M` plus a share of the step between the ends (a drop can lie
anywhere in the gap). Gaps before the first and after the last known sample stay NaN.

Pure numpy; shapes in the comments.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from roadbev_core.config import GridSpec
from roadbev_core.errors import RoadbevError

__all__ = [
    "BRIDGE_ROUGHNESS_M2_PER_M",
    "DEFAULT_TRACK_NAMES",
    "DEFAULT_TRACK_OFFSETS_M",
    "REFERENCE_CONTACT_PLANE",
    "REFERENCE_ROAD",
    "ContactPlane",
    "PreviewError",
    "PreviewProfiles",
    "TrackProfile",
    "bridge_gaps",
    "check_tracks",
    "read_profile",
    "read_profile_with_sigma",
    "wheel_track_profiles",
]

# Left and right wheel tracks of a car with a 1.6 m track width centred under the left camera.
DEFAULT_TRACK_OFFSETS_M: tuple[float, ...] = (0.8, -0.8)
DEFAULT_TRACK_NAMES: tuple[str, ...] = ("left", "right")
# What a preview's elevations are relative to (RoadPreview.reference).
REFERENCE_ROAD = "road"  # per frame: roadbev_road, the gravity-aligned plane base_height below the camera
REFERENCE_CONTACT_PLANE = "contact_plane"  # fused map: base_link, the plane through the four tyre contacts
# E[(h(x + d) - h(x))^2] = q d of an ISO 8608 class C road (Gd(n0) = 256e-6 m^3 at n0 = 0.1 cycles/m,
# PSD Gd(n0) (n / n0)^-2, so q = 2 pi^2 Gd(n0) n0^2): the spread of the road inside a bridged gap.
BRIDGE_ROUGHNESS_M2_PER_M = 2.0 * math.pi**2 * 256e-6 * 0.1**2


class PreviewError(RoadbevError, ValueError):
    """Preview settings or inputs that cannot give a profile (track off the grid, bad spacing)."""


@dataclass(frozen=True, eq=False)
class TrackProfile:
    """The road under one wheel track.

    Attributes:
        name: "left", "right", ...
        lateral_offset: y of the track centre in the road frame (left positive) [m].
        width: tyre width averaged over [m].
        elevation: [n] float32 road height per sample, nearest first [m]; NaN = no estimate.
        uncertainty: [n] float32 1-sigma [m]; NaN where elevation is NaN or unknown.
    """

    name: str
    lateral_offset: float
    width: float
    elevation: np.ndarray
    uncertainty: np.ndarray

    def __post_init__(self) -> None:
        if self.elevation.ndim != 1 or self.elevation.shape != self.uncertainty.shape:
            raise PreviewError(
                f"track {self.name!r}: elevation {self.elevation.shape} and uncertainty "
                f"{self.uncertainty.shape} must be equal 1-D arrays"
            )


@dataclass(frozen=True)
class ContactPlane:
    """The plane through the four tyre contacts, as a controller needs it to move a profile into
    its own reference.

    In the gravity-aligned frame at ``base_link``'s origin with ``base_link``'s heading (x
    forward, y left, z up), the plane is the one of a frame with ``roll`` and ``pitch``
    (REP-103, yaw 0) through ``(0, 0, height_m)``: a point (x, y) of it lies at
    ``z = height_m - x tan(pitch) + y tan(roll) / cos(pitch)`` (pitch > 0: the road falls ahead).

    Attributes:
        height_m: the plane's height at ``base_link``'s origin, relative to that origin (0 at
            static ride height on a flat road; > 0: the body sits lower than static).
        roll, pitch: the plane's attitude relative to gravity (rad).
        height_sigma_m, roll_sigma, pitch_sigma: their 1-sigma.
        source: ``"map"`` (fitted to the fused map at the four contacts), ``"road"`` (the map
            does not hold three contacts yet: the plane of the road it holds ahead of the front
            wheels, carried back under the car) or ``"body"`` (nor enough of the road ahead: the
            body's own plane at static ride height).
    """

    height_m: float
    roll: float
    pitch: float
    height_sigma_m: float
    roll_sigma: float
    pitch_sigma: float
    source: str = "map"

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """[...] the plane's z at (x, y) [...] of the gravity-aligned frame described above."""
        return self.height_m - np.asarray(x) * math.tan(self.pitch) + np.asarray(y) * (
            math.tan(self.roll) / math.cos(self.pitch))


@dataclass(frozen=True, eq=False)
class PreviewProfiles:
    """Profiles along every wheel track, sampled at ``start_distance + i * spacing``.

    Attributes:
        start_distance: x of the nearest sample in the road frame [m].
        spacing: distance between samples along x [m] (> 0).
        tracks: one :class:`TrackProfile` per track, all of the same length.
        vehicle_speed: speed along x [m/s], or None when unknown.
        reference_distance: x of the point the times of arrival refer to (e.g. the front axle).
        reference: what x and the elevations refer to: :data:`REFERENCE_ROAD` (x ahead of the
            camera in ``roadbev_road``, heights above its plane) or
            :data:`REFERENCE_CONTACT_PLANE` (x ahead of ``base_link``'s origin along its
            heading, heights above the contact plane, measured vertically).
        contact_plane: the contact plane (``REFERENCE_CONTACT_PLANE`` only).
    """

    start_distance: float
    spacing: float
    tracks: tuple[TrackProfile, ...]
    vehicle_speed: float | None = None
    reference_distance: float = 0.0
    reference: str = REFERENCE_ROAD
    contact_plane: ContactPlane | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.spacing) and self.spacing > 0):
            raise PreviewError(f"spacing must be positive, got {self.spacing}")
        if not math.isfinite(self.start_distance) or not math.isfinite(self.reference_distance):
            raise PreviewError("start_distance and reference_distance must be finite")
        if self.vehicle_speed is not None and not math.isfinite(self.vehicle_speed):
            raise PreviewError(f"vehicle_speed must be finite or None, got {self.vehicle_speed}")
        if self.reference not in (REFERENCE_ROAD, REFERENCE_CONTACT_PLANE):
            raise PreviewError(f"unknown preview reference {self.reference!r}")
        if (self.reference == REFERENCE_CONTACT_PLANE) != (self.contact_plane is not None):
            raise PreviewError("a contact-plane preview carries its contact plane, and only it does")
        lengths = {len(t.elevation) for t in self.tracks}
        if len(lengths) > 1:
            raise PreviewError(f"tracks have different lengths {sorted(lengths)}")

    @property
    def n_samples(self) -> int:
        return len(self.tracks[0].elevation) if self.tracks else 0

    def distances(self) -> np.ndarray:
        """[n] x of each sample, nearest first."""
        return self.start_distance + np.arange(self.n_samples) * self.spacing

    def time_of_arrival(self) -> np.ndarray | None:
        """[n] seconds until the reference point reaches each sample, None without a speed."""
        if self.vehicle_speed is None or self.vehicle_speed <= 0:
            return None
        return ((self.distances() - self.reference_distance) / self.vehicle_speed).astype(np.float32)

    def track(self, name: str) -> TrackProfile:
        for t in self.tracks:
            if t.name == name:
                return t
        raise KeyError(f"no track named {name!r} (have {[t.name for t in self.tracks]})")


def bridge_gaps(elevation: np.ndarray, uncertainty: np.ndarray, spacing: float, max_gap_m: float,
                roughness: float = BRIDGE_ROUGHNESS_M2_PER_M) -> tuple[np.ndarray, np.ndarray]:
    """A profile with its inner gaps of at most ``max_gap_m`` bridged (see the module docstring).

    Args:
        elevation, uncertainty: [S] the profile and its 1-sigma (NaN = no value).
        spacing: distance between samples (m).
        max_gap_m: the longest stretch of missing samples bridged (m, from the last known sample
            before it to the first after it); 0 = none.
        roughness: q of the road's height increments, E[(h(x + d) - h(x))^2] = q d (m^2 / m).

    Returns:
        [S] elevation and [S] 1-sigma (float32): inside a bridged gap at fraction t between the
        known ends a, b (distances d_a, d_b from them), the line between them, with
        ``sigma^2 = ((1 - t) s_a + t s_b)^2 + q d_a d_b / (d_a + d_b) + t (1 - t) (h_b - h_a)^2``
        (NaN when an end's sigma is unknown).
    """
    e = np.asarray(elevation, np.float64).copy()  # [S]
    s = np.asarray(uncertainty, np.float64).copy()  # [S]
    known = np.flatnonzero(np.isfinite(e))
    if max_gap_m > 0 and known.size >= 2:
        a, b = known[:-1], known[1:]  # [G] each known sample and the next one
        inner = (b - a > 1) & ((b - a) * spacing <= max_gap_m + 1e-9)
        for i, j in zip(a[inner].tolist(), b[inner].tolist(), strict=True):
            idx = np.arange(i + 1, j)
            t = (idx - i) / (j - i)
            d_a, d_b = (idx - i) * spacing, (j - idx) * spacing
            e[idx] = (1.0 - t) * e[i] + t * e[j]
            s[idx] = np.sqrt(((1.0 - t) * s[i] + t * s[j]) ** 2 + roughness * d_a * d_b / (d_a + d_b)
                             + t * (1.0 - t) * (e[j] - e[i]) ** 2)
    return e.astype(np.float32), s.astype(np.float32)


def _overlap(centres: np.ndarray, half_cell: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[len(lo), len(centres)] length shared by cells [c - h, c + h] and windows [lo, hi]."""
    left = np.maximum(centres[None, :] - half_cell, lo[:, None])
    right = np.minimum(centres[None, :] + half_cell, hi[:, None])
    return cast("np.ndarray", np.clip(right - left, 0.0, None))


def check_tracks(grid: GridSpec, track_offsets_m: Sequence[float], tyre_width_m: float, spacing_m: float) -> None:
    """Refuse wheel tracks that cannot be sampled on ``grid`` (before any frame arrives).

    Raises:
        PreviewError: as :func:`wheel_track_profiles` would for these settings.
    """
    if len(track_offsets_m) != 2:
        raise PreviewError(f"need the left and the right track offset, got {len(track_offsets_m)} values")
    wheel_track_profiles(
        np.full(grid.shape, np.nan, np.float32), None, grid,
        track_offsets_m=track_offsets_m, tyre_width_m=tyre_width_m, spacing_m=spacing_m,
    )


def wheel_track_profiles(
    elevation: np.ndarray,
    uncertainty: np.ndarray | None,
    grid: GridSpec,
    *,
    track_offsets_m: Sequence[float] = DEFAULT_TRACK_OFFSETS_M,
    track_names: Sequence[str] | None = None,
    tyre_width_m: float = 0.20,
    spacing_m: float | None = None,
    max_distance_m: float | None = None,
    min_coverage: float = 0.5,
    vehicle_speed: float | None = None,
    reference_distance: float = 0.0,
    max_gap_m: float = 0.0,
) -> PreviewProfiles:
    """Elevation profiles along wheel tracks, nearest first.

    Args:
        elevation: [n_rows, n_cols] metres (row 0 farthest, col 0 leftmost), NaN = none.
        uncertainty: [n_rows, n_cols] 1-sigma metres, or None (profiles' sigma is then NaN).
        grid: the grid the maps are on.
        track_offsets_m: y of each track centre (left positive).
        track_names: a name per track; default "left"/"right" for two tracks, else "track<i>".
        tyre_width_m: lateral width averaged over.
        spacing_m: distance between samples (default: the grid resolution).
        max_distance_m: the farthest x sampled (default: the grid's far edge).
        min_coverage: share (0..1] of a sample's footprint that must have estimates.
        vehicle_speed, reference_distance: passed on to :class:`PreviewProfiles`.
        max_gap_m: inner gaps up to this long are bridged (:func:`bridge_gaps`; 0 = none).

    Raises:
        PreviewError: maps not on ``grid``, a track whose tyre footprint leaves the grid, or
            non-positive spacing / width / coverage.
    """
    elevation = np.asarray(elevation, dtype=np.float64)
    if elevation.shape != grid.shape:
        raise PreviewError(f"elevation is {elevation.shape}, the grid is {grid.shape}")
    if uncertainty is None:
        sigma = np.full(grid.shape, np.nan)
    else:
        sigma = np.asarray(uncertainty, dtype=np.float64)
        if sigma.shape != grid.shape:
            raise PreviewError(f"uncertainty is {sigma.shape}, the grid is {grid.shape}")
    spacing = float(grid.resolution if spacing_m is None else spacing_m)
    if not (math.isfinite(spacing) and spacing > 0):
        raise PreviewError(f"spacing must be positive, got {spacing}")
    if not (math.isfinite(tyre_width_m) and tyre_width_m > 0):
        raise PreviewError(f"tyre width must be positive, got {tyre_width_m}")
    if not 0 < min_coverage <= 1:
        raise PreviewError(f"min_coverage must be in (0, 1], got {min_coverage}")
    far = grid.x_max if max_distance_m is None else min(float(max_distance_m), grid.x_max)
    n_samples = int(math.floor((far - grid.x_min) / spacing + 1e-9))
    if n_samples < 1:
        raise PreviewError(f"no sample of {spacing} m fits between {grid.x_min} and {far} m")
    names = list(track_names) if track_names is not None else (
        list(DEFAULT_TRACK_NAMES) if len(track_offsets_m) == 2 else
        [f"track{i}" for i in range(len(track_offsets_m))]
    )
    if len(names) != len(track_offsets_m):
        raise PreviewError(f"{len(names)} track names for {len(track_offsets_m)} tracks")

    start = grid.x_min + 0.5 * spacing
    x = start + np.arange(n_samples) * spacing  # [S] nearest first
    half = 0.5 * grid.resolution
    # [S, R] longitudinal overlap of each sample window with each row
    w_rows = _overlap(grid.x_centres(), half, x - 0.5 * spacing, x + 0.5 * spacing)
    known = np.isfinite(elevation)  # [R, C]
    e0 = np.where(known, elevation, 0.0)
    s_known = known & np.isfinite(sigma)
    s0 = np.where(s_known, sigma, 0.0)

    tracks = []
    for name, offset in zip(names, track_offsets_m, strict=True):
        lo, hi = offset - 0.5 * tyre_width_m, offset + 0.5 * tyre_width_m
        if lo < grid.y_min - 1e-9 or hi > grid.y_max + 1e-9:
            raise PreviewError(
                f"track {name!r} at y={offset} m with a {tyre_width_m} m tyre leaves the grid's "
                f"lateral range [{grid.y_min}, {grid.y_max}] m"
            )
        w_cols = _overlap(grid.y_centres(), half, np.array([lo]), np.array([hi]))[0]  # [C]
        area = w_rows.sum(axis=1) * w_cols.sum()  # [S] footprint area inside the grid
        covered = w_rows @ (known @ w_cols)  # [S] area with estimates
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = (w_rows @ (e0 @ w_cols)) / covered
            sigma_mean = (w_rows @ (s0 @ w_cols)) / (w_rows @ (s_known @ w_cols))
        ok = covered >= min_coverage * area - 1e-12
        ok &= covered > 0
        profile, profile_sigma = bridge_gaps(np.where(ok, mean, np.nan), np.where(ok, sigma_mean, np.nan), spacing,
                                             max_gap_m)
        tracks.append(TrackProfile(name, float(offset), float(tyre_width_m), profile, profile_sigma))
    return PreviewProfiles(
        start_distance=float(start),
        spacing=spacing,
        tracks=tuple(tracks),
        vehicle_speed=None if vehicle_speed is None else float(vehicle_speed),
        reference_distance=float(reference_distance),
    )


def read_profile(profiles: PreviewProfiles, track: str, x: np.ndarray) -> np.ndarray:
    """[N] the profile of ``track`` read at x [N] (see the module docstring; NaN = no value)."""
    return read_profile_with_sigma(profiles, track, x)[0]


def read_profile_with_sigma(profiles: PreviewProfiles, track: str, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[N] the profile of ``track`` read at x [N] and [N] its 1-sigma, read with the same weights
    (the elevation's known samples decide them; NaN = no value)."""
    profile = profiles.track(track)
    elev = np.asarray(profile.elevation, np.float64)  # [S]
    sig = np.asarray(profile.uncertainty, np.float64)  # [S]
    n = elev.size
    f = (np.asarray(x, np.float64) - profiles.start_distance) / profiles.spacing  # [N] fractional index
    out, out_sigma = np.full(f.shape, np.nan), np.full(f.shape, np.nan)
    if n == 0:
        return out, out_sigma
    i0 = np.floor(f).astype(np.int64)
    ok = (i0 >= 0) & (i0 < n - 1)
    a = np.where(ok, i0, 0)
    both = ok & np.isfinite(elev[a]) & np.isfinite(elev[np.minimum(a + 1, n - 1)])
    t = f - i0
    out[both] = elev[a[both]] * (1 - t[both]) + elev[a[both] + 1] * t[both]
    out_sigma[both] = sig[a[both]] * (1 - t[both]) + sig[a[both] + 1] * t[both]
    near = np.rint(f).astype(np.int64)
    fill = ~both & (near >= 0) & (near < n) & (np.abs(f - near) <= 0.5)
    near_ok = np.where(fill, near, 0)
    fill &= np.isfinite(elev[near_ok])
    out[fill] = elev[near_ok[fill]]
    out_sigma[fill] = sig[near_ok[fill]]
    return out, out_sigma
