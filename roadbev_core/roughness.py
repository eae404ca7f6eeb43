"""Road roughness along a profile: an ISO 8608 class estimate (issue 22).

ISO 8608 describes a road profile by its one-sided displacement PSD ``Gd(n) = Gd(n0) (n /
n0)^-2`` (``n0`` = 0.1 cycle/m) and names classes by ``Gd(n0)``: A below 32e-6 m^3, B below
128e-6, and so on, each class four times the one before (the geometric means are
:data:`ISO8608_GD0`). A map holds only metres of road ahead, so
:func:`profile_roughness` fits the law over the spatial frequencies such a profile resolves
(``band_cycles_per_m``, default 0.3-2 cycle/m: wavelengths 0.5-3.3 m):

1. the longest run of known samples (short gaps, e.g. where a hazard was cut out, are bridged
   by linear interpolation) of at least ``min_length_m``;
2. Welch's PSD: Hann-windowed, linearly detrended segments of ``segment_m`` (or the whole run
   when shorter), half overlapping, one-sided ``G(n) = 2 dx |X(n)|^2 / sum(w^2)``;
3. the measurement noise floor ``2 sigma^2 dx`` (white noise of the map's median 1-sigma along
   the profile) subtracted, and ``Gd(n0)`` = the mean of ``G(n) (n / n0)^2`` over the band (an
   unbiased estimate of ``Gd(n0)`` when the profile follows the law).

Pure numpy; shapes in the comments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, cast

import numpy as np

from roadbev_core.errors import RoadbevError

__all__ = ["ISO8608_CLASSES", "ISO8608_GD0", "ISO8608_N0", "Roughness", "RoughnessError", "RoughnessSettings",
           "iso8608_class", "profile_roughness"]

# ISO 8608 geometric-mean displacement PSD at n0 = 0.1 cycle/m, m^3 (classes A..E).
ISO8608_GD0: dict[str, float] = {"A": 16e-6, "B": 64e-6, "C": 256e-6, "D": 1024e-6, "E": 4096e-6}
ISO8608_N0 = 0.1
# Class -> upper bound of Gd(n0) (m^3): twice the class's geometric mean (the classes are a factor 4 apart);
# beyond E the standard goes on (F, G, H) with the same factor.
ISO8608_CLASSES: tuple[tuple[str, float], ...] = tuple(
    (c, 2.0 * g) for c, g in sorted(ISO8608_GD0.items())) + tuple(
    (c, 2.0 * ISO8608_GD0["E"] * 4.0 ** (k + 1)) for k, c in enumerate("FGH"))


class RoughnessError(RoadbevError, ValueError):
    """Settings or a profile the estimate cannot use."""


@dataclass(frozen=True)
class RoughnessSettings:
    """How a profile's roughness is estimated.

    Attributes:
        band_cycles_per_m: (low, high) spatial frequencies fitted (cycle/m).
        segment_m: Welch segment length (m).
        min_length_m: shortest run of known samples used (m).
        max_gap_m: longest gap bridged by interpolation (m).
    """

    band_cycles_per_m: tuple[float, float] = (0.3, 2.0)
    segment_m: float = 4.0
    min_length_m: float = 3.0
    max_gap_m: float = 0.6

    def __post_init__(self) -> None:
        lo, hi = self.band_cycles_per_m
        if not (0.0 < lo < hi and math.isfinite(hi) and 0.5 <= self.min_length_m <= self.segment_m
                and 0.0 <= self.max_gap_m < self.min_length_m and 1.0 / self.segment_m <= lo):
            raise RoughnessError(f"bad roughness settings {self} (the band must start at or above 1 / segment_m)")


class Roughness(NamedTuple):
    """A profile's roughness.

    Attributes:
        gd_n0: the displacement PSD at n0 = 0.1 cycle/m (m^3); NaN when the profile is too short.
        iso_class: ``"A"`` .. ``"H"`` (``""`` when unknown).
        length_m: the run of profile the estimate used (m).
    """

    gd_n0: float
    iso_class: str
    length_m: float


def iso8608_class(gd_n0: float) -> str:
    """The ISO 8608 class of a ``Gd(n0)`` (m^3): ``"A"`` .. ``"H"``, ``""`` for NaN."""
    if not math.isfinite(gd_n0):
        return ""
    for name, upper in ISO8608_CLASSES:
        if gd_n0 < upper:
            return name
    return ISO8608_CLASSES[-1][0]


def _longest_run(z: np.ndarray, max_gap: int) -> np.ndarray:
    """The longest stretch of ``z`` [N] whose gaps are at most ``max_gap`` samples, gaps filled linearly."""
    known = np.isfinite(z)
    idx = np.flatnonzero(known)
    if idx.size < 2:
        return z[idx]
    breaks = np.flatnonzero(np.diff(idx) > max_gap + 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [idx.size - 1]])
    k = int(np.argmax(idx[ends] - idx[starts]))
    lo, hi = int(idx[starts[k]]), int(idx[ends[k]])
    seg = z[lo: hi + 1]
    ok = np.isfinite(seg)
    positions = np.arange(seg.size)
    return cast("np.ndarray", np.interp(positions, positions[ok], seg[ok]))


def profile_roughness(profile: np.ndarray, spacing_m: float, sigma_m: np.ndarray | float | None = None,
                      settings: RoughnessSettings | None = None) -> Roughness:
    """The ISO 8608 roughness of a height profile (see the module docstring).

    Args:
        profile: [N] heights (m) every ``spacing_m`` along the track, NaN = unknown (or cut out).
        spacing_m: sample spacing (m).
        sigma_m: the heights' 1-sigma ([N] or one value; None: no noise floor subtracted).

    Raises:
        RoughnessError: not a 1-D profile, a bad spacing, or a band above the profile's Nyquist.
    """
    s = settings or RoughnessSettings()
    z = np.asarray(profile, np.float64)
    if z.ndim != 1 or not (math.isfinite(spacing_m) and spacing_m > 0):
        raise RoughnessError(f"need a 1-D profile and a positive spacing, got {z.shape}, {spacing_m}")
    if s.band_cycles_per_m[1] > 0.5 / spacing_m:
        raise RoughnessError(f"band up to {s.band_cycles_per_m[1]} cycle/m needs a spacing <= "
                             f"{0.5 / s.band_cycles_per_m[1]:.3f} m, got {spacing_m}")
    run = _longest_run(z, int(math.floor(s.max_gap_m / spacing_m + 1e-9)))
    length = run.size * spacing_m
    if length < s.min_length_m:
        return Roughness(math.nan, "", float(length))
    n_seg = min(run.size, max(8, int(round(s.segment_m / spacing_m))))
    step = max(1, n_seg // 2)
    window = np.hanning(n_seg)  # [S]
    t = np.arange(n_seg, dtype=np.float64)
    psd = np.zeros(n_seg // 2 + 1)
    count = 0
    for start in range(0, run.size - n_seg + 1, step):
        seg = run[start: start + n_seg]
        seg = seg - np.polyval(np.polyfit(t, seg, 1), t)  # detrended
        psd += 2.0 * spacing_m * np.abs(np.fft.rfft(window * seg)) ** 2 / float(np.sum(window**2))
        count += 1
    psd /= count
    n = np.fft.rfftfreq(n_seg, d=spacing_m)  # [S/2+1] cycle/m
    if sigma_m is not None:
        sig = np.asarray(sigma_m, np.float64)
        sig = sig[np.isfinite(sig)] if sig.ndim else np.array([float(sig)])
        if sig.size:
            psd = np.maximum(psd - 2.0 * float(np.median(sig)) ** 2 * spacing_m, 0.0)
    band = (n >= s.band_cycles_per_m[0]) & (n <= s.band_cycles_per_m[1])
    gd = float(np.mean(psd[band] * (n[band] / ISO8608_N0) ** 2))
    return Roughness(gd, iso8608_class(gd), float(length))
