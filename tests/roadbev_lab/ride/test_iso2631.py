"""ISO 2631-1 Wk: the analogue and digital responses against the standard's table, weighted RMS."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_lab.ride.iso2631 import WK_TABLE, WeightingError, WkFilter, weighted_rms, wk_response


@pytest.mark.parametrize("f", [0.5, 1.0, 2.0, 4.0, 6.3, 8.0, 12.5, 16.0, 31.5])
def test_wk_matches_the_standards_table(f: float) -> None:
    assert wk_response(f) == pytest.approx(WK_TABLE[f], rel=0.005)
    assert WkFilter(1000.0).response(f) == pytest.approx(WK_TABLE[f], rel=0.005)


def test_wk_shape() -> None:
    # band limited: small far below 0.4 Hz and far above 100 Hz, largest between 5 and 8 Hz
    f = np.logspace(-2, 2.5, 400)
    h = wk_response(f)
    assert h[0] < 0.01 and h[-1] < 0.05
    assert 5.0 < f[np.argmax(h)] < 8.0


def test_weighted_rms_of_a_sine_is_its_gain() -> None:
    fs, f = 1000.0, 4.0
    t = np.arange(0, 20.0, 1 / fs)
    a = 2.0 * np.sin(2 * math.pi * f * t)
    rms = weighted_rms(a, fs, start=int(5 * fs))  # skip the filter's transient
    assert rms == pytest.approx(2.0 / math.sqrt(2) * WK_TABLE[f], rel=0.01)


def test_bad_inputs() -> None:
    with pytest.raises(WeightingError):
        WkFilter(200.0)
    with pytest.raises(WeightingError):
        WkFilter(1000.0)(np.array([0.0, math.nan]))
    with pytest.raises(WeightingError):
        weighted_rms(np.zeros(10), 1000.0, start=10)
