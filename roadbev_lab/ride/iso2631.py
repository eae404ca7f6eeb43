"""ISO 2631-1 frequency weighting Wk (vertical whole-body vibration) and weighted RMS.

ISO 2631-1:1997, "Mechanical vibration and shock - Evaluation of human exposure to whole-body
vibration - Part 1: General requirements", Annex A (normative): the weighting is the product of

* band limiting, a two-pole high-pass at f1 and a two-pole low-pass at f2 (Butterworth, Q = 1/sqrt 2)::

      Hh(s) = s^2 / (s^2 + w1 s / Q1 + w1^2),   Hl(s) = w2^2 / (s^2 + w2 s / Q1 + w2^2)

* the acceleration-velocity transition::

      Ht(s) = (1 + s / w3) / (1 + s / (Q4 w4) + s^2 / w4^2)

* the upward step::

      Hs(s) = (1 + s / (Q5 w5) + s^2 / w5^2) / (1 + s / (Q6 w6) + s^2 / w6^2) * (w5 / w6)^2

with, for Wk (Table A.2): f1 = 0.4 Hz, f2 = 100 Hz, f3 = f4 = 12.5 Hz, Q4 = 0.63, f5 = 2.37 Hz,
Q5 = 0.91, f6 = 3.35 Hz, Q6 = 0.91 (w = 2 pi f). :data:`WK_TABLE` holds the standard's
one-third-octave values of Wk (Table 3, factors), which the analogue response reproduces.

The digital filter discretises each second-order section with the bilinear transform, prewarped
at the section's own frequency (so corner frequencies stay exact); run it at >= 1 kHz so that the
100 Hz band limit lies well below Nyquist. Pure numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np

from roadbev_core.errors import RoadbevError

__all__ = ["WK_PARAMETERS", "WK_TABLE", "WeightingError", "WkFilter", "weighted_rms", "wk_response"]


class WeightingError(RoadbevError, ValueError):
    """A sample rate or signal the weighting cannot filter."""


# (f1, f2, f3, f4, Q4, f5, Q5, f6, Q6), ISO 2631-1:1997 Table A.2, weighting Wk.
WK_PARAMETERS: tuple[float, ...] = (0.4, 100.0, 12.5, 12.5, 0.63, 2.37, 0.91, 3.35, 0.91)
_Q1 = 1.0 / math.sqrt(2.0)

# ISO 2631-1:1997 Table 3: frequency (Hz) -> Wk weighting factor (the standard lists x 1000).
WK_TABLE: dict[float, float] = {
    0.5: 0.418, 0.63: 0.459, 0.8: 0.477, 1.0: 0.482, 1.25: 0.484, 1.6: 0.494, 2.0: 0.531, 2.5: 0.631,
    3.15: 0.804, 4.0: 0.967, 5.0: 1.039, 6.3: 1.054, 8.0: 1.036, 10.0: 0.988, 12.5: 0.902, 16.0: 0.768,
    20.0: 0.636, 25.0: 0.513, 31.5: 0.405, 40.0: 0.314, 50.0: 0.246, 63.0: 0.186, 80.0: 0.132,
}


def _sections() -> list[tuple[tuple[float, float, float], tuple[float, float, float], float]]:
    """The Wk cascade as analogue biquads: ((b2, b1, b0), (a2, a1, a0), prewarp w) in powers s^2, s, 1."""
    f1, f2, f3, f4, q4, f5, q5, f6, q6 = WK_PARAMETERS
    w1, w2, w3, w4, w5, w6 = (2 * math.pi * f for f in (f1, f2, f3, f4, f5, f6))
    return [
        ((1.0, 0.0, 0.0), (1.0, w1 / _Q1, w1 * w1), w1),  # high-pass
        ((0.0, 0.0, w2 * w2), (1.0, w2 / _Q1, w2 * w2), w2),  # low-pass
        ((0.0, 1.0 / w3, 1.0), (1.0 / w4**2, 1.0 / (q4 * w4), 1.0), w4),  # a-v transition
        ((1.0 / w5**2 * (w5 / w6) ** 2, 1.0 / (q5 * w5) * (w5 / w6) ** 2, (w5 / w6) ** 2),
         (1.0 / w6**2, 1.0 / (q6 * w6), 1.0), w6),  # upward step
    ]


def wk_response(frequency_hz: np.ndarray | float) -> np.ndarray:
    """|Wk| of the analogue weighting at ``frequency_hz`` [...] (a factor; 1.0 = unweighted)."""
    s = 2j * math.pi * np.asarray(frequency_hz, np.float64)
    h = np.ones(s.shape, np.complex128)
    for (b2, b1, b0), (a2, a1, a0), _ in _sections():
        h *= (b2 * s * s + b1 * s + b0) / (a2 * s * s + a1 * s + a0)
    return np.abs(h)


@dataclass(frozen=True)
class WkFilter:
    """The Wk weighting as a digital cascade of biquads at ``sample_rate_hz``.

    Attributes:
        sample_rate_hz: the signal's rate (>= 500 Hz; 1 kHz or more recommended).
    """

    sample_rate_hz: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sample_rate_hz) and self.sample_rate_hz >= 500.0):
            raise WeightingError(f"the Wk filter needs a sample rate >= 500 Hz (its band limit is 100 Hz), "
                                 f"got {self.sample_rate_hz}")

    def coefficients(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per section (b [3], a [3]) of H(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)."""
        T = 1.0 / self.sample_rate_hz
        out = []
        for (b2, b1, b0), (a2, a1, a0), w in _sections():
            k = w / math.tan(w * T / 2.0)  # prewarped bilinear: s = k (1 - z^-1) / (1 + z^-1)
            num = np.array([b2 * k * k + b1 * k + b0, 2 * (b0 - b2 * k * k), b2 * k * k - b1 * k + b0])
            den = np.array([a2 * k * k + a1 * k + a0, 2 * (a0 - a2 * k * k), a2 * k * k - a1 * k + a0])
            out.append((num / den[0], den / den[0]))
        return out

    def response(self, frequency_hz: np.ndarray | float) -> np.ndarray:
        """|H(e^{j w T})| of the digital filter at ``frequency_hz`` [...]."""
        z1 = np.exp(-2j * math.pi * np.asarray(frequency_hz, np.float64) / self.sample_rate_hz)  # z^-1
        h = np.ones(z1.shape, np.complex128)
        for b, a in self.coefficients():
            h *= (b[0] + b[1] * z1 + b[2] * z1 * z1) / (a[0] + a[1] * z1 + a[2] * z1 * z1)
        return np.abs(h)

    def __call__(self, signal: np.ndarray) -> np.ndarray:
        """The weighted signal [n] of ``signal`` [n] sampled at ``sample_rate_hz`` (zero initial state)."""
        y = np.asarray(signal, np.float64).copy()
        if y.ndim != 1 or not np.all(np.isfinite(y)):
            raise WeightingError(f"need a finite 1-D signal, got shape {y.shape}")
        for b, a in self.coefficients():
            y = _biquad(b, a, y)
        return cast("np.ndarray", y)


def _biquad(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Direct form II transposed, one section."""
    out = np.empty_like(x)
    s1 = s2 = 0.0
    b0, b1, b2 = (float(v) for v in b)
    a1, a2 = float(a[1]), float(a[2])
    for i, xi in enumerate(x.tolist()):
        yi = b0 * xi + s1
        s1 = b1 * xi - a1 * yi + s2
        s2 = b2 * xi - a2 * yi
        out[i] = yi
    return out


def weighted_rms(acceleration: np.ndarray, sample_rate_hz: float, start: int = 0) -> float:
    """ISO 2631-1 frequency-weighted RMS (m/s^2) of a vertical acceleration [n], over samples
    ``start:`` (the filter runs over the whole signal, so its transient can be skipped)."""
    aw = WkFilter(sample_rate_hz)(acceleration)[start:]
    if aw.size == 0:
        raise WeightingError("no samples to average")
    return float(np.sqrt(np.mean(aw * aw)))
