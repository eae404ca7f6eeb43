"""Road height fields: ISO 8608 random roughness plus discrete features on a fine 2-D raster.

World frame of a synthetic road (``W``): x along the road (metres driven), y to the left, z up
along gravity. The surface is ``z = grade * x + cross_slope * y + d(x, y)`` where the
displacement ``d`` lives on a :class:`SurfaceCanvas` raster (1 cm cells by default) and is zero
outside it (the far field is the plain tilted plane).

Roughness (ISO 8608): the one-sided displacement PSD of a longitudinal profile is
``Gd(n) = Gd(n0) * (n / n0) ** -2`` with ``n0 = 0.1`` cycle/m. A 2-D isotropic field whose
two-sided spectrum is ``P(k) = C * (|k|^2 + kc^2) ** -1.5`` has exactly the 1-D profile PSD
``4 C / (n^2 + kc^2)``; with ``C = Gd(n0) n0^2 / 4`` that is ISO 8608 above the cut-off ``kc``
(wavelengths longer than about a wheelbase move the whole car and so do not show in the
camera-relative elevation, and are left out). Above ``ISO8608_N_MAX`` the spectrum steepens to
``n^-4``: the law describes unevenness, not the millimetre texture of the surface.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, cast

import cv2
import numpy as np

from roadbev_core.errors import RoadbevError
from roadbev_core.roughness import ISO8608_GD0, ISO8608_N0

__all__ = [
    "FEATURE_NAMES",
    "ISO8608_N_MAX",
    "Crack",
    "Feature",
    "Kerb",
    "Patch",
    "Pothole",
    "Rut",
    "SpeedBump",
    "Step",
    "SurfaceCanvas",
    "SynthError",
    "profile_psd",
    "roughness_field",
    "sample_feature",
]


class SynthError(RoadbevError, ValueError):
    """A synthetic-data configuration or request that cannot be honoured, with the reason."""

# Highest spatial frequency the class law is applied to (cycle/m): ISO 8608 classifies profiles
# up to about 3 cycle/m; shorter wavelengths fall off faster (see roughness_field).
ISO8608_N_MAX = 4.0

# Names accepted in RoadConfig.features (a "hump" covers speed humps and speed tables).
FEATURE_NAMES = ("pothole", "speed_bump", "hump", "rut", "crack", "step", "kerb", "patch")


def _spectral_noise(
    shape: tuple[int, int],
    spacing: float,
    rng: np.random.Generator,
    psd: Callable[[np.ndarray], np.ndarray],
    keep: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """Gaussian field with two-sided 2-D PSD ``psd(|k|)`` on a periodic grid.

    White noise of unit variance per cell has PSD ``spacing**2``; filtering with
    ``sqrt(P) / spacing`` gives the field PSD ``P``.
    """
    # FFT on a size with small prime factors (much faster), cropped back to the shape asked.
    fast = (cv2.getOptimalDFTSize(int(shape[0])), cv2.getOptimalDFTSize(int(shape[1])))
    kx = np.fft.fftfreq(fast[0], d=spacing)[:, None]  # cycles/m
    ky = np.fft.rfftfreq(fast[1], d=spacing)[None, :]
    k = np.sqrt(kx * kx + ky * ky)  # [n0, n1//2+1]
    white = rng.standard_normal(fast, dtype=np.float32)
    spectrum = np.fft.rfft2(white)
    gain = (np.sqrt(psd(k)) / spacing * keep(k)).astype(np.float32)
    gain[0, 0] = 0.0  # zero mean
    return np.fft.irfft2(spectrum * gain, s=fast)[: shape[0], : shape[1]]


def roughness_field(
    shape: tuple[int, int],
    resolution: float,
    road_class: str,
    rng: np.random.Generator,
    *,
    cutoff_wavelength: float = 10.0,
    scale: float = 1.0,
) -> np.ndarray:
    """ISO 8608 random roughness on a ``shape`` raster of ``resolution`` metres.

    Two bands so that long wavelengths need no fine FFT over a wide padded domain: wavelengths
    above 8 coarse cells on a coarse grid padded to twice the cut-off wavelength (cubic
    upsampling), the rest on the fine grid itself.

    Args:
        shape: ``(n_x, n_y)`` raster size (x along the road).
        resolution: cell size (m).
        road_class: ISO 8608 class "A".."E".
        rng: random source.
        cutoff_wavelength: longest wavelength kept (m), the high-pass corner ``kc = 1/it``.
            (The short-wavelength corner is ``ISO8608_N_MAX``.)
        scale: multiplies the amplitude (0 gives a smooth road).

    Returns:
        [n_x, n_y] float32 displacement (m), zero mean.
    """
    if road_class not in ISO8608_GD0:
        raise SynthError(f"unknown ISO 8608 road class {road_class!r}; choose from A, B, C, D, E")
    if resolution <= 0 or cutoff_wavelength <= 0:
        raise SynthError("roughness resolution and cut-off wavelength must be positive")
    n_x, n_y = int(shape[0]), int(shape[1])
    if n_x < 8 or n_y < 8:
        raise SynthError(f"roughness raster {shape} is too small (need at least 8 x 8)")
    c = ISO8608_GD0[road_class] * ISO8608_N0**2 / 4.0
    kc = 1.0 / cutoff_wavelength

    k_hi = ISO8608_N_MAX

    def psd(k: np.ndarray) -> np.ndarray:
        # ISO 8608 within its band; beyond n_max the spectrum steepens by n^-2 more (texture
        # below ~25 cm wavelength is the pavement's macrotexture, drawn by the albedo tiles).
        return cast("np.ndarray", c * (k * k + kc * kc) ** -1.5 / (1.0 + (k / k_hi) ** 2))

    factor = 8
    coarse = resolution * factor
    k_split = 1.0 / (8 * coarse)
    pad = int(math.ceil(2 * cutoff_wavelength / coarse))
    lo_shape = (n_x // factor + 2 + pad, max(n_y // factor + 2, pad))
    low = _spectral_noise(lo_shape, coarse, rng, psd, lambda k: (k < k_split).astype(np.float64))
    # Crop the padded coarse field and upsample it onto the fine grid.
    lo_crop = low[: n_x // factor + 2, : n_y // factor + 2].astype(np.float32)
    up = cv2.resize(lo_crop, (lo_crop.shape[1] * factor, lo_crop.shape[0] * factor), interpolation=cv2.INTER_CUBIC)[
        :n_x, :n_y
    ]
    high = _spectral_noise((n_x, n_y), resolution, rng, psd, lambda k: (k >= k_split).astype(np.float64))
    field = (up + high.astype(np.float32)) * np.float32(scale)
    return cast("np.ndarray", (field - field.mean()).astype(np.float32))


def profile_psd(profile: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD of profiles (periodogram, Hann window, averaged over the leading axes).

    Args:
        profile: [..., n] equally spaced samples along the last axis.
        spacing: sample spacing (m).

    Returns:
        n [m] spatial frequencies (cycle/m, zero excluded) and G(n) [m] (m^3).
    """
    p = np.asarray(profile, dtype=np.float64)
    n = p.shape[-1]
    window = np.hanning(n)
    p = (p - p.mean(axis=-1, keepdims=True)) * window
    spec = np.abs(np.fft.rfft(p, axis=-1)) ** 2
    g = 2.0 * spec * spacing / np.sum(window**2)
    g = g.reshape(-1, g.shape[-1]).mean(axis=0)
    freqs = np.fft.rfftfreq(n, d=spacing)
    return freqs[1:], g[1:]


@dataclass
class SurfaceCanvas:
    """Rasters of the road surface over a strip of the world frame.

    Cell ``[i, j]`` is centred at ``x = x0 + i * resolution``, ``y = y0 + j * resolution``.

    Attributes:
        heights: [n_x, n_y] float32 displacement above the tilted road plane (m).
        albedo: [n_x, n_y] float32 multiplicative albedo of features (stains, patches, cracks).
        light: [n_x, n_y] float32 share of direct sunlight reaching the surface (cast shadows).
        x0, y0: world coordinates of cell ``[0, 0]``.
        resolution: cell size (m).
    """

    heights: np.ndarray
    albedo: np.ndarray
    light: np.ndarray
    x0: float
    y0: float
    resolution: float

    @classmethod
    def empty(cls, x0: float, y0: float, n_x: int, n_y: int, resolution: float) -> SurfaceCanvas:
        return cls(
            heights=np.zeros((n_x, n_y), np.float32),
            albedo=np.ones((n_x, n_y), np.float32),
            light=np.ones((n_x, n_y), np.float32),
            x0=float(x0),
            y0=float(y0),
            resolution=float(resolution),
        )

    @property
    def x_end(self) -> float:
        return cast("float", self.x0 + (self.heights.shape[0] - 1) * self.resolution)

    @property
    def y_end(self) -> float:
        return cast("float", self.y0 + (self.heights.shape[1] - 1) * self.resolution)

    def window(
        self, x_lo: float, x_hi: float, y_lo: float, y_hi: float
    ) -> tuple[slice, slice, np.ndarray, np.ndarray] | None:
        """Index slices and world coordinates of the cells in a box (None if it misses).

        Returns:
            rows, cols slices and X [ni, 1], Y [1, nj] float64 coordinates of their centres.
        """
        r = self.resolution
        i0 = max(int(math.floor((x_lo - self.x0) / r)), 0)
        i1 = min(int(math.ceil((x_hi - self.x0) / r)) + 1, self.heights.shape[0])
        j0 = max(int(math.floor((y_lo - self.y0) / r)), 0)
        j1 = min(int(math.ceil((y_hi - self.y0) / r)) + 1, self.heights.shape[1])
        if i1 <= i0 or j1 <= j0:
            return None
        xs = (self.x0 + np.arange(i0, i1) * r)[:, None]
        ys = (self.y0 + np.arange(j0, j1) * r)[None, :]
        return slice(i0, i1), slice(j0, j1), xs, ys

    def displacement(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear displacement at world points (exact float64; zero outside the canvas)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        fi = (x - self.x0) / self.resolution
        fj = (y - self.y0) / self.resolution
        n_x, n_y = self.heights.shape
        inside = (fi >= 0) & (fi <= n_x - 1) & (fj >= 0) & (fj <= n_y - 1)
        i0 = np.clip(np.floor(fi), 0, n_x - 2).astype(np.int64)
        j0 = np.clip(np.floor(fj), 0, n_y - 2).astype(np.int64)
        ti = np.clip(fi - i0, 0.0, 1.0)
        tj = np.clip(fj - j0, 0.0, 1.0)
        h = self.heights
        top = h[i0, j0] * (1 - tj) + h[i0, j0 + 1] * tj
        bot = h[i0 + 1, j0] * (1 - tj) + h[i0 + 1, j0 + 1] * tj
        return np.where(inside, top * (1 - ti) + bot * ti, 0.0)


def _smoothstep(edge0: float | np.ndarray, edge1: float | np.ndarray, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / np.maximum(edge1 - edge0, 1e-9), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _local_noise(shape: tuple[int, int], cells: float, rng: np.random.Generator) -> np.ndarray:
    """Smooth zero-mean unit-ish noise with a correlation length of about ``cells`` cells."""
    small = (max(2, int(shape[0] / cells) + 2), max(2, int(shape[1] / cells) + 2))
    coarse = rng.standard_normal(small).astype(np.float32)
    return cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


class Feature(Protocol):
    """A discrete road feature drawn onto a :class:`SurfaceCanvas` (frozen dataclasses: read-only)."""

    @property
    def name(self) -> str: ...

    @property
    def x(self) -> float: ...

    @property
    def y(self) -> float: ...

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None: ...


@dataclass(frozen=True)
class Pothole:
    """A pothole: irregular elliptical outline, sloped walls, rough darker floor (negative)."""

    x: float
    y: float
    radius_x: float
    radius_y: float
    depth: float
    edge_width: float
    angle: float
    name: str = "pothole"

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
        reach = max(self.radius_x, self.radius_y) * 1.4 + self.edge_width
        win = canvas.window(self.x - reach, self.x + reach, self.y - reach, self.y + reach)
        if win is None:
            return
        rows, cols, xs, ys = win
        c, s = math.cos(self.angle), math.sin(self.angle)
        du, dv = xs - self.x, ys - self.y
        a = c * du + s * dv
        b = -s * du + c * dv
        theta = np.arctan2(b, a)
        wobble = np.ones_like(theta)
        for k in (2, 3, 5):  # irregular outline
            wobble = wobble + rng.uniform(-0.12, 0.12) * np.cos(k * theta + rng.uniform(0, 2 * math.pi))
        dist = np.hypot(a / self.radius_x, b / self.radius_y) / wobble  # 1 at the rim
        edge = self.edge_width / min(self.radius_x, self.radius_y)
        wall = 1.0 - _smoothstep(1.0 - edge, 1.0, dist)  # 1 on the floor, 0 outside
        floor = _local_noise(wall.shape, 3.0, rng) * 0.15 * self.depth
        canvas.heights[rows, cols] += (-self.depth * wall + floor * wall).astype(np.float32)
        canvas.albedo[rows, cols] *= (1.0 - 0.35 * wall - 0.15 * (wall > 0.02) * (wall < 0.98)).astype(np.float32)


@dataclass(frozen=True)
class SpeedBump:
    """A transverse bump or hump across the lane (positive).

    Profiles along x: ``parabolic``/``circular`` (short speed bumps), ``sinusoidal`` (Watts
    hump), ``flat_top`` (speed table: ramps and a plateau).
    """

    x: float
    y: float
    length: float
    height: float
    width: float
    profile: str
    ramp: float = 0.0
    painted: bool = False
    name: str = "speed_bump"

    def along(self, u: np.ndarray) -> np.ndarray:
        """Height profile at signed distance ``u`` from the centre line (m)."""
        half = self.length / 2
        t = np.clip(np.abs(u) / half, 0.0, 1.0)
        if self.profile == "parabolic":
            prof = 1.0 - t * t
        elif self.profile == "circular":
            # circular arc through the ends: chord `length`, sagitta `height`.
            radius = (half * half + self.height * self.height) / (2 * self.height)
            prof = (np.sqrt(np.maximum(radius**2 - (t * half) ** 2, 0.0)) - (radius - self.height)) / self.height
        elif self.profile == "sinusoidal":
            prof = 0.5 * (1.0 + np.cos(math.pi * t))
        elif self.profile == "flat_top":
            ramp = max(self.ramp, 1e-3) / half
            prof = np.clip((1.0 - t) / ramp, 0.0, 1.0)
        else:
            raise SynthError(f"unknown bump profile {self.profile!r}")
        return np.where(np.abs(u) < half, prof, 0.0) * self.height

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
        half_w = self.width / 2
        win = canvas.window(self.x - self.length, self.x + self.length, self.y - half_w - 0.3, self.y + half_w + 0.3)
        if win is None:
            return
        rows, cols, xs, ys = win
        taper = 1.0 - _smoothstep(half_w - 0.25, half_w, np.abs(ys - self.y))  # rounded ends
        bump = self.along(xs - self.x) * taper
        canvas.heights[rows, cols] += bump.astype(np.float32)
        on = (bump > 0.002).astype(np.float32)
        if self.painted:  # alternating light bands across the bump (painted or rubber units)
            bands = (np.floor((ys - self.y) / 0.5) % 2 == 0).astype(np.float32)
            canvas.albedo[rows, cols] *= 1.0 + 1.4 * on * bands
        else:
            canvas.albedo[rows, cols] *= 1.0 - 0.1 * on


@dataclass(frozen=True)
class Rut:
    """Wheel-track ruts: two longitudinal grooves ``track`` apart, tapered ends (negative)."""

    x: float
    y: float
    length: float
    depth: float
    width: float
    track: float = 1.6
    name: str = "rut"

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
        half_l = self.length / 2
        reach_y = self.track / 2 + 3 * self.width
        win = canvas.window(self.x - half_l, self.x + half_l, self.y - reach_y, self.y + reach_y)
        if win is None:
            return
        rows, cols, xs, ys = win
        along = _smoothstep(0.0, 1.5, half_l - np.abs(xs - self.x))  # fade in/out over 1.5 m
        vary = 1.0 + 0.3 * _local_noise((xs.shape[0], 1), 150.0, rng)  # depth varies along x
        sigma = self.width / 2.5
        groove = np.zeros((xs.shape[0], ys.shape[1]))
        for side in (-1.0, 1.0):
            centre = self.y + side * self.track / 2
            groove += np.exp(-0.5 * ((ys - centre) / sigma) ** 2)
        canvas.heights[rows, cols] -= (self.depth * along * vary * groove).astype(np.float32)
        canvas.albedo[rows, cols] *= (1.0 - 0.08 * along * groove).astype(np.float32)


@dataclass(frozen=True)
class Crack:
    """A crack: a wandering polyline with branches, V-shaped groove, dark (negative)."""

    x: float
    y: float
    length: float
    heading: float
    width: float
    depth: float
    name: str = "crack"

    def _polylines(self, rng: np.random.Generator) -> list[np.ndarray]:
        steps = max(int(self.length / 0.05), 2)
        head = self.heading + np.cumsum(rng.normal(0.0, 0.12, steps))
        pts = np.cumsum(np.stack([np.cos(head), np.sin(head)], axis=1) * 0.05, axis=0)
        pts = np.vstack([[0.0, 0.0], pts]) - pts[-1] / 2 + np.array([self.x, self.y])
        lines = [pts]
        for _ in range(int(rng.integers(0, 3))):  # branches
            start = pts[int(rng.integers(1, len(pts) - 1))]
            n = max(steps // 3, 2)
            bh = self.heading + rng.choice([-1.0, 1.0]) * rng.uniform(0.6, 1.3) + np.cumsum(rng.normal(0, 0.15, n))
            lines.append(start + np.vstack([[0.0, 0.0], np.cumsum(np.stack([np.cos(bh), np.sin(bh)], 1) * 0.05, 0)]))
        return lines

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
        lines = self._polylines(rng)
        allpts = np.vstack(lines)
        margin = 4 * self.width + 0.02
        win = canvas.window(
            allpts[:, 0].min() - margin,
            allpts[:, 0].max() + margin,
            allpts[:, 1].min() - margin,
            allpts[:, 1].max() + margin,
        )
        if win is None:
            return
        rows, cols, xs, ys = win
        dist = np.full((xs.shape[0], ys.shape[1]), np.inf)
        for line in lines:
            for p, q in itertools.pairwise(line):
                d = q - p
                t = np.clip(((xs - p[0]) * d[0] + (ys - p[1]) * d[1]) / max(float(d @ d), 1e-12), 0.0, 1.0)
                dist = np.minimum(dist, np.hypot(xs - p[0] - t * d[0], ys - p[1] - t * d[1]))
        half = self.width / 2
        groove = np.clip(1.0 - dist / half, 0.0, 1.0)  # V profile
        canvas.heights[rows, cols] -= (self.depth * groove).astype(np.float32)
        dark = np.exp(-0.5 * (dist / (half + 0.004)) ** 2)
        canvas.albedo[rows, cols] *= (1.0 - 0.6 * dark).astype(np.float32)


@dataclass(frozen=True)
class Step:
    """A step edge: a raised or sunk section (overlay/milled lane) with bevelled edges.

    ``orientation`` "transverse": the section spans x in [x, x + length] across the road;
    "longitudinal": the section lies to the right of y (y < self.y) over x in
    [x - length/2, x + length/2] (a milled lane next to an unmilled one).
    """

    x: float
    y: float
    height: float
    length: float
    bevel: float
    orientation: str
    name: str = "step"

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
        b = max(self.bevel, 1e-3)
        if self.orientation == "transverse":
            win = canvas.window(self.x - b, self.x + self.length + b, canvas.y0, canvas.y_end)
            if win is None:
                return
            rows, cols, xs, ys = win
            inside = _smoothstep(0.0, b, xs - self.x) * _smoothstep(0.0, b, self.x + self.length - xs)
            inside = np.broadcast_to(inside, (xs.shape[0], ys.shape[1]))
        elif self.orientation == "longitudinal":
            half = self.length / 2
            win = canvas.window(self.x - half - 1.0, self.x + half + 1.0, canvas.y0, self.y + b)
            if win is None:
                return
            rows, cols, xs, ys = win
            ends = _smoothstep(0.0, 1.0, half + 1.0 - np.abs(xs - self.x))  # ramped ends, 1 m
            inside = _smoothstep(0.0, b, self.y - ys) * ends
        else:
            raise SynthError(f"unknown step orientation {self.orientation!r}")
        canvas.heights[rows, cols] += (self.height * inside).astype(np.float32)
        tone = 0.85 if self.height < 0 else 0.75  # milled (lighter grooves) vs fresh overlay
        canvas.albedo[rows, cols] *= (1.0 - (1.0 - tone) * inside).astype(np.float32)


@dataclass(frozen=True)
class Kerb:
    """A kerb along the road at lateral position ``y``: the side beyond it is raised.

    ``side`` +1: the kerb bounds the road on the left (raised for y > self.y); -1: right.
    ``length`` (m): the kerb runs over x in [x - length/2, x + length/2], its raised side
    sloping down to the road over ``end_ramp`` beyond each end (a dropped kerb); ``inf`` (a
    single scene's kerb) runs along the whole canvas.
    """

    x: float
    y: float
    height: float
    side: int
    bevel: float = 0.03
    length: float = math.inf
    end_ramp: float = 0.5
    name: str = "kerb"

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
        if math.isfinite(self.length):
            half = self.length / 2 + self.end_ramp
            x_lo, x_hi = self.x - half, self.x + half
        else:
            x_lo, x_hi = canvas.x0, canvas.x_end
        if self.side > 0:
            win = canvas.window(x_lo, x_hi, self.y - self.bevel, canvas.y_end)
        else:
            win = canvas.window(x_lo, x_hi, canvas.y0, self.y + self.bevel)
        if win is None:
            return
        rows, cols, xs, ys = win
        beyond = _smoothstep(0.0, self.bevel, self.side * (ys - self.y))  # [1, W]
        if math.isfinite(self.length):  # [H, W]: the raised side tapers to the road at both ends
            beyond = beyond * _smoothstep(0.0, max(self.end_ramp, 1e-3), half - np.abs(xs - self.x))
        shape = (xs.shape[0], ys.shape[1])
        canvas.heights[rows, cols] += np.broadcast_to(self.height * beyond, shape).astype(np.float32)
        stone = (ys - self.y) * self.side < 0.15  # the kerb stones: lighter concrete
        gain = np.where(stone, 2.4, 1.7) * beyond + (1.0 - beyond)
        canvas.albedo[rows, cols] *= np.broadcast_to(gain, shape).astype(np.float32)


@dataclass(frozen=True)
class Patch:
    """A repair patch: a slightly rotated rectangle raised or sunk by millimetres to a
    centimetre or two, bevelled, with its own (darker or lighter) tone and sealed edges."""

    x: float
    y: float
    size_x: float
    size_y: float
    height: float
    angle: float
    tone: float
    name: str = "patch"

    def apply(self, canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
        reach = 0.75 * math.hypot(self.size_x, self.size_y) + 0.05
        win = canvas.window(self.x - reach, self.x + reach, self.y - reach, self.y + reach)
        if win is None:
            return
        rows, cols, xs, ys = win
        c, s = math.cos(self.angle), math.sin(self.angle)
        a = c * (xs - self.x) + s * (ys - self.y)
        b = -s * (xs - self.x) + c * (ys - self.y)
        margin = np.minimum(self.size_x / 2 - np.abs(a), self.size_y / 2 - np.abs(b))  # >0 inside
        inside = _smoothstep(0.0, 0.02, margin)
        canvas.heights[rows, cols] += (self.height * inside).astype(np.float32)
        seal = np.exp(-0.5 * (margin / 0.012) ** 2)  # dark sealant along the edges
        gain = (1.0 - inside + inside * self.tone) * (1.0 - 0.45 * seal)
        canvas.albedo[rows, cols] *= gain.astype(np.float32)


def sample_feature(name: str, rng: np.random.Generator, x: float, y: float) -> Feature:
    """A feature of kind ``name`` with random, realistic dimensions, centred near ``(x, y)``.

    Raises:
        SynthError: unknown feature name.
    """
    if name == "pothole":
        rx = rng.uniform(0.12, 0.45)
        return Pothole(
            x=x,
            y=y,
            radius_x=rx,
            radius_y=rx * rng.uniform(0.6, 1.4),
            depth=rng.uniform(0.03, 0.10),
            edge_width=rng.uniform(0.02, 0.08),
            angle=rng.uniform(0, math.pi),
        )
    if name == "speed_bump":
        profile = str(rng.choice(["parabolic", "circular", "flat_top"]))
        length = rng.uniform(0.3, 0.9)
        return SpeedBump(
            x=x,
            y=y,
            length=length,
            height=rng.uniform(0.04, 0.10),
            width=rng.uniform(3.0, 7.0),
            profile=profile,
            ramp=length * 0.3,
            painted=bool(rng.random() < 0.5),
        )
    if name == "hump":
        profile = str(rng.choice(["sinusoidal", "flat_top"]))
        length = rng.uniform(2.5, 4.5)
        return SpeedBump(
            x=x,
            y=y,
            length=length,
            height=rng.uniform(0.05, 0.10),
            width=rng.uniform(3.5, 7.0),
            profile=profile,
            ramp=rng.uniform(0.8, 1.2),
            painted=False,
            name="hump",
        )
    if name == "rut":
        return Rut(x=x, y=y, length=rng.uniform(6.0, 20.0), depth=rng.uniform(0.01, 0.03), width=rng.uniform(0.3, 0.5))
    if name == "crack":
        heading = rng.choice([0.0, math.pi / 2]) + rng.normal(0.0, 0.3)
        return Crack(
            x=x,
            y=y,
            length=rng.uniform(0.6, 3.0),
            heading=float(heading),
            width=rng.uniform(0.005, 0.015),
            depth=rng.uniform(0.004, 0.012),
        )
    if name == "step":
        orientation = str(rng.choice(["transverse", "longitudinal"]))
        height = rng.uniform(0.015, 0.045) * rng.choice([-1.0, 1.0])
        return Step(
            x=x,
            y=y,
            height=float(height),
            length=rng.uniform(2.0, 12.0),
            bevel=rng.uniform(0.005, 0.02),
            orientation=orientation,
        )
    if name == "kerb":
        side = int(rng.choice([-1, 1]))
        return Kerb(x=x, y=y, height=rng.uniform(0.08, 0.15), side=side)
    if name == "patch":
        return Patch(
            x=x,
            y=y,
            size_x=rng.uniform(0.5, 2.5),
            size_y=rng.uniform(0.4, 1.8),
            height=float(rng.uniform(0.003, 0.015) * rng.choice([-1.0, 1.0])),
            angle=rng.normal(0.0, 0.1),
            tone=float(rng.choice([rng.uniform(0.55, 0.8), rng.uniform(1.15, 1.4)])),
        )
    raise SynthError(f"unknown road feature {name!r}; choose from {', '.join(FEATURE_NAMES)}")
