"""Surface appearance: periodic albedo tiles (asphalt, concrete, verge), mip pyramids and lookups.

A tile is a periodic grey albedo raster (3 mm texels by default) made in the Fourier domain so
that it wraps seamlessly; scenes sample it under a random rotation and offset, so no two scenes
see the same texture layout. Asphalt has a dark binder with multi-scale mottling, a dense
aggregate of light and dark chips of 3-12 mm, sand grains and pores: the 1-pixel detail real
stereo matchers lock onto at 2-7 m on the RSRD rig (one pixel is 2-7 mm there).

Lookups go through :func:`sample_mip`: trilinear filtering over a mip pyramid, the level chosen
from each pixel's footprint, with ``cv2.remap`` doing the bilinear taps.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from typing import cast

import cv2
import numpy as np

from roadbev_lab.synth.heightfield import SynthError

__all__ = ["SURFACES", "AlbedoTile", "build_pyramid", "make_glint_tile", "make_tile", "remap_points", "sample_mip"]

SURFACES = ("asphalt", "concrete")


def build_pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """Mip pyramid by 2x2 box averaging (periodic images stay periodic); level 0 is ``image``.

    Odd sizes are handled by ``cv2.INTER_AREA``; each level has at least 2 cells per side.
    """
    pyr: list[np.ndarray] = [np.ascontiguousarray(image, dtype=np.float32)]
    for _ in range(levels - 1):
        prev = pyr[-1]
        h, w = prev.shape[:2]
        if h < 4 or w < 4:
            break
        pyr.append(cv2.resize(prev, ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA))
    return pyr


def _remap(image: np.ndarray, col: np.ndarray, row: np.ndarray, wrap: bool) -> np.ndarray:
    """Bilinear taps at float (col, row) of a [h, w] or [h, w, c] image; 1-D coordinate arrays."""
    h, w = image.shape[:2]
    if wrap:  # remap saturates coordinates to int16 internally: bring them into the tile
        col = np.mod(col, w)
        row = np.mod(row, h)
        border = cv2.BORDER_WRAP
    else:
        col = np.clip(col, -4.0, w + 3.0)
        row = np.clip(row, -4.0, h + 3.0)
        border = cv2.BORDER_REPLICATE
    return remap_points(image, col, row, border)


def remap_points(image: np.ndarray, col: np.ndarray, row: np.ndarray, border: int, value: float = 0.0) -> np.ndarray:
    """``cv2.remap`` bilinear taps at N scattered points (cv2 wants maps under 32767 a side).

    Args:
        image: [h, w] or [h, w, c] float32 source (each side < 32767).
        col, row: [N] float coordinates (cell centres at integers).
        border: cv2 border mode; value: the constant for ``cv2.BORDER_CONSTANT``.

    Returns:
        [N] or [N, c] float32.
    """
    n = col.shape[0]
    width = 1024
    rows = max(-(-n // width), 1)
    mx = np.zeros(rows * width, np.float32)
    my = np.zeros(rows * width, np.float32)
    mx[:n] = col
    my[:n] = row
    out = cv2.remap(
        image, mx.reshape(rows, width), my.reshape(rows, width), cv2.INTER_LINEAR, borderMode=border, borderValue=value
    )
    return cast("np.ndarray", out.reshape(rows * width, *image.shape[2:])[:n])


def sample_mip(
    pyramid: list[np.ndarray], col: np.ndarray, row: np.ndarray, lod: np.ndarray, *, wrap: bool
) -> np.ndarray:
    """Trilinear lookup of a mip pyramid at level-0 cell coordinates.

    Args:
        pyramid: levels from :func:`build_pyramid` ([h, w] or [h, w, c] each).
        col, row: [N] level-0 coordinates (cell centres at integers).
        lod: [N] level of detail, log2 of the footprint in level-0 cells (clipped to the pyramid).
        wrap: periodic tile (True) or clamp at the edges (False).

    Returns:
        [N] or [N, c] float32 samples.
    """
    n_levels = len(pyramid)
    lod = np.clip(np.nan_to_num(lod, nan=0.0), 0.0, n_levels - 1.0)
    base = np.minimum(np.floor(lod).astype(np.int64), n_levels - 1)
    frac = (lod - base).astype(np.float32)
    out = np.zeros((col.shape[0], *pyramid[0].shape[2:]), np.float32)
    for level, sel in _groups(base):
        vals = _level_taps(pyramid[level], col[sel], row[sel], level, level, wrap)
        if level + 1 < n_levels:
            f = frac[sel] if vals.ndim == 1 else frac[sel, None]
            vals = vals * (1 - f) + _level_taps(pyramid[level + 1], col[sel], row[sel], level + 1, level + 1, wrap) * f
        out[sel] = vals
    return out


def _groups(keys: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(key, indices) of each distinct integer key, by one sort (not a scan per key)."""
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    starts = np.flatnonzero(np.diff(sorted_keys)) + 1
    bounds = np.concatenate([[0], starts, [keys.shape[0]]])
    return [(int(sorted_keys[a]), order[a:b]) for a, b in itertools.pairwise(bounds) if b > a]


def _level_taps(
    image: np.ndarray, col: np.ndarray, row: np.ndarray, level_col: int, level_row: int, wrap: bool
) -> np.ndarray:
    """Bilinear taps of a level reduced 2^level_col times along columns, 2^level_row along rows,
    at level-0 coordinates (a level cell k covers level-0 cells [2^L k, 2^L (k+1)))."""
    c = (col + 0.5) * 0.5**level_col - 0.5
    r = (row + 0.5) * 0.5**level_row - 0.5
    return _remap(image, c, r, wrap)


def build_ripmap(image: np.ndarray, levels: int) -> dict[tuple[int, int], np.ndarray]:
    """Rip-map of a periodic [n, n] image (n a power of two): level (i, j) is the image averaged
    over 2^i rows and 2^j columns, so footprints stretched along one axis (the road seen at a
    grazing angle) are filtered along that axis only."""
    rip: dict[tuple[int, int], np.ndarray] = {(0, 0): np.ascontiguousarray(image, dtype=np.float32)}
    for i in range(levels):
        if i > 0:
            prev = rip[(i - 1, 0)]
            rip[(i, 0)] = np.ascontiguousarray(prev.reshape(prev.shape[0] // 2, 2, prev.shape[1]).mean(axis=1))
        for j in range(1, levels):
            prev = rip[(i, j - 1)]
            rip[(i, j)] = np.ascontiguousarray(prev.reshape(prev.shape[0], prev.shape[1] // 2, 2).mean(axis=2))
    return rip


def sample_ripmap(
    rip: dict[tuple[int, int], np.ndarray],
    col: np.ndarray,
    row: np.ndarray,
    lod_row: np.ndarray,
    lod_col: np.ndarray,
) -> np.ndarray:
    """Anisotropic lookup of a periodic rip-map at level-0 coordinates.

    Both levels are blended linearly (four bilinear taps per point), so the filter changes
    smoothly with the footprint: two cameras seeing a point from slightly different distances
    filter it alike (a rounded level would differ between them at level boundaries).

    Args:
        rip: from :func:`build_ripmap`.
        col, row: [N] level-0 texel coordinates.
        lod_row, lod_col: [N] log2 of the footprint (level-0 texels) along rows / columns.

    Returns:
        [N] float32.
    """
    top = max(i for i, _ in rip)
    lr = np.clip(np.nan_to_num(lod_row), 0.0, top)
    lc = np.clip(np.nan_to_num(lod_col), 0.0, top)
    li = np.minimum(np.floor(lr).astype(np.int64), top)
    lj = np.minimum(np.floor(lc).astype(np.int64), top)
    fr = (lr - li).astype(np.float32)
    fc = (lc - lj).astype(np.float32)
    out = np.zeros(col.shape[0], np.float32)
    for key, sel in _groups(li * (top + 1) + lj):
        i, j = divmod(key, top + 1)
        c, r = col[sel], row[sel]
        i1, j1 = min(i + 1, top), min(j + 1, top)
        lo = _level_taps(rip[(i, j)], c, r, j, i, True)
        lo_c = _level_taps(rip[(i, j1)], c, r, j1, i, True)
        hi = _level_taps(rip[(i1, j)], c, r, j, i1, True)
        hi_c = _level_taps(rip[(i1, j1)], c, r, j1, i1, True)
        a, b = fr[sel], fc[sel]
        out[sel] = (lo * (1 - b) + lo_c * b) * (1 - a) + (hi * (1 - b) + hi_c * b) * a
    return out


def _fourier_noise(size: int, rng: np.random.Generator, beta: float, k_lo: float, k_hi: float) -> np.ndarray:
    """Periodic [size, size] noise with amplitude spectrum ~ k^-beta for k in [k_lo, k_hi]
    (cycles per texel), unit standard deviation."""
    kx = np.fft.fftfreq(size)[:, None]
    ky = np.fft.rfftfreq(size)[None, :]
    k = np.sqrt(kx * kx + ky * ky)
    amp = np.where((k >= k_lo) & (k <= k_hi), np.maximum(k, 1e-9) ** -beta, 0.0)
    spec = np.fft.rfft2(rng.standard_normal((size, size))) * amp
    field = np.fft.irfft2(spec, s=(size, size))
    return cast("np.ndarray", (field / (field.std() + 1e-12)).astype(np.float32))


def _brush_noise(size: int, rng: np.random.Generator) -> np.ndarray:
    """Periodic stripes running along the tile's columns (transverse brushing of concrete)."""
    kx = np.fft.fftfreq(size)[:, None]
    ky = np.fft.rfftfreq(size)[None, :]
    amp = np.exp(-0.5 * (ky / 0.004) ** 2) * ((np.abs(kx) > 0.01) & (np.abs(kx) < 0.25))
    field = np.fft.irfft2(np.fft.rfft2(rng.standard_normal((size, size))) * amp, s=(size, size))
    return cast("np.ndarray", (field / (field.std() + 1e-12)).astype(np.float32))


def _periodic_blobs(
    size: int, rng: np.random.Generator, count: int, radius: float, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Periodic discs of ``radius`` texels at random positions: (value sum, coverage) rasters."""
    pos = rng.integers(0, size, (count, 2))
    impulses = np.zeros((2, size, size), np.float64)
    np.add.at(impulses[0], (pos[:, 0], pos[:, 1]), values)
    np.add.at(impulses[1], (pos[:, 0], pos[:, 1]), 1.0)
    d = np.minimum(np.arange(size), size - np.arange(size))  # periodic distance to 0
    r = np.hypot(d[:, None], d[None, :])
    kernel = np.clip(radius + 0.5 - r, 0.0, 1.0)  # anti-aliased disc
    kf = np.fft.rfft2(kernel)
    out = np.fft.irfft2(np.fft.rfft2(impulses) * kf, s=(size, size))
    return out[0].astype(np.float32), out[1].astype(np.float32)


def _composite_aggregate(
    base: np.ndarray, rng: np.random.Generator, specs: list[tuple[float, float, float, float]]
) -> np.ndarray:
    """Lay chips over ``base``: specs are (density per texel, radius texels, mean value, spread)."""
    size = base.shape[0]
    out = base.copy()
    for density, radius, mean, spread in specs:
        count = int(density * size * size)
        values = np.clip(rng.normal(mean, spread, count), 0.02, 0.95)
        vsum, cov = _periodic_blobs(size, rng, count, radius, values)
        colour = vsum / np.maximum(cov, 1e-6)
        alpha = np.clip(cov, 0.0, 1.0)
        out = out * (1.0 - alpha) + colour * alpha
    return cast("np.ndarray", out)


@dataclass(frozen=True)
class AlbedoTile:
    """A periodic albedo tile with its mip pyramid.

    Attributes:
        pyramid: levels of [size, size] float32 grey albedo (level 0 finest).
        texel: level-0 texel size (m).
    """

    pyramid: tuple[np.ndarray, ...]
    texel: float
    rip: dict[tuple[int, int], np.ndarray] | None = None

    @property
    def size(self) -> int:
        return int(self.pyramid[0].shape[0])

    @property
    def period(self) -> float:
        return self.size * self.texel


@functools.lru_cache(maxsize=6)
def make_tile(surface: str, variant: int, size: int = 1024, texel: float = 0.003) -> AlbedoTile:
    """The albedo tile of a surface kind (cached: a few variants serve all scenes).

    Args:
        surface: "asphalt", "concrete" or "verge" (gravel and grass beside the road).
        variant: which random instance (seeds the generator).
        size: texels per side (a power of two keeps the pyramid exact).
        texel: texel size (m).
    """
    if size < 64:
        raise SynthError(f"texture tile of {size} texels is too small")
    rng = np.random.default_rng([0x7E47, int(variant), int(size), len(surface)])
    mm = 0.001 / texel  # texels per millimetre
    if surface == "asphalt":
        mottle = _fourier_noise(size, rng, 1.0, 2.0 / size, 0.05)  # cm..m scale variation
        grain = _fourier_noise(size, rng, 0.0, 0.02, 0.5)  # texel-scale sand and binder
        base = 0.16 + 0.025 * mottle + 0.03 * grain
        albedo = _composite_aggregate(
            base,
            rng,
            [
                (0.0009 / mm**2, 5.0 * mm, 0.30, 0.08),  # coarse chips, 10 mm
                (0.004 / mm**2, 2.5 * mm, 0.34, 0.10),  # medium chips, 5 mm
                (0.012 / mm**2, 1.2 * mm, 0.28, 0.12),  # fine chips and sand, 2-3 mm
                (0.004 / mm**2, 1.0 * mm, 0.07, 0.02),  # pores and voids (dark)
            ],
        )
    elif surface == "concrete":
        mottle = _fourier_noise(size, rng, 1.2, 2.0 / size, 0.05)
        grain = _fourier_noise(size, rng, 0.0, 0.03, 0.5)
        # transverse brushing: fine stripes along y (tile rows run along x)
        brush = _brush_noise(size, rng)
        base = 0.50 + 0.035 * mottle + 0.06 * grain + 0.015 * brush
        albedo = _composite_aggregate(
            base,
            rng,
            [
                (0.003 / mm**2, 2.0 * mm, 0.62, 0.08),  # exposed sand/aggregate
                (0.003 / mm**2, 0.8 * mm, 0.30, 0.06),  # air voids
            ],
        )
    elif surface == "verge":
        mottle = _fourier_noise(size, rng, 1.0, 2.0 / size, 0.2)
        grain = _fourier_noise(size, rng, 0.0, 0.05, 0.5)
        albedo = 0.22 + 0.06 * mottle + 0.05 * grain
    else:
        raise SynthError(f"unknown surface {surface!r}; choose from asphalt, concrete")
    albedo = np.clip(albedo, 0.02, 0.95).astype(np.float32)
    levels = int(math.log2(size)) - 1
    rip = build_ripmap(albedo, min(levels, 8)) if size & (size - 1) == 0 else None
    return AlbedoTile(pyramid=tuple(build_pyramid(albedo, levels)), texel=float(texel), rip=rip)


@functools.lru_cache(maxsize=6)
def make_glint_tile(
    variant: int, layout: int, density: float, brightness: float, size: int = 1024, texel: float = 0.003
) -> AlbedoTile:
    """One layout of specular glints of the aggregate: an additive [size, size] tile.

    Sunlit chips with a facet turned between the sun and a camera flash far brighter than the
    diffuse binder. Two cameras see a facet's narrow specular lobe from directions a few degrees
    apart, so only some glints are in both images; the renderer blends a layout both cameras see
    (``layout`` 0) with one per camera (1 left, 2 right) by how far apart the cameras' rays to a
    point are (``RoadConfig.glint_lobe_deg``). Layouts are independent draws from ``variant``.
    To a stereo matcher a camera's own glints are texture that does not match: strong,
    surface-bound (averaged away with the footprint, unlike sensor noise) and different in the
    other image. This is a texture-space stand-in for a glinting BRDF, not one.

    Args:
        variant: which random instance (as :func:`make_tile`'s).
        layout: 0 (seen by both cameras), 1 (the left camera's own), 2 (the right camera's own).
        density: glints per square millimetre of pavement (> 0).
        brightness: a glint's added albedo (the binder's is about 0.16).
        size, texel: as :func:`make_tile`'s (a power of two: the tile is rip-mapped).
    """
    if layout not in (0, 1, 2):
        raise SynthError(f"glint layout must be 0 (shared), 1 (left) or 2 (right), got {layout}")
    if not (density > 0 and brightness > 0):
        raise SynthError(f"glints need density > 0 and brightness > 0; got {density}, {brightness}")
    if size < 64 or size & (size - 1):
        raise SynthError(f"glint tiles need a power-of-two size >= 64, got {size}")
    mm = 0.001 / texel  # texels per millimetre
    count = max(int(round(density / mm**2 * size * size)), 1)
    rng = np.random.default_rng([0x611A7, int(variant), int(size), int(layout)])
    _, cover = _periodic_blobs(size, rng, count, 0.7 * mm, np.ones(count))  # facets of ~1.4 mm
    cover = np.where(cover > 1e-6, np.clip(cover, 0.0, 1.0), 0.0)  # the FFT's round-off is not a glint
    tile = (brightness * cover).astype(np.float32)
    levels = int(math.log2(size)) - 1
    rip = build_ripmap(tile, min(levels, 8))
    return AlbedoTile(pyramid=tuple(build_pyramid(tile, levels)), texel=float(texel), rip=rip)
