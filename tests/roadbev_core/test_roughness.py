"""ISO 8608 roughness of a profile: the classes of synthetic roads are recovered from ~10 m."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.roughness import ISO8608_GD0, RoughnessError, RoughnessSettings, iso8608_class, profile_roughness
from roadbev_lab.synth.heightfield import roughness_field

RES = 0.03


@pytest.mark.parametrize("road_class", ["A", "B", "C", "D"])
def test_the_class_of_a_synthetic_road_is_recovered(road_class: str) -> None:
    estimates = []
    for seed in range(6):
        field = roughness_field((340, 40), RES, road_class, np.random.default_rng(seed))  # 10.2 m
        r = profile_roughness(field[:, 20], RES)
        assert r.iso_class == road_class
        assert r.length_m == pytest.approx(10.2)
        estimates.append(r.gd_n0)
    # the mean over drives is within 30 % of the class's geometric mean
    assert np.mean(estimates) == pytest.approx(ISO8608_GD0[road_class], rel=0.3)


def test_the_noise_floor_is_subtracted_and_gaps_are_bridged() -> None:
    field = roughness_field((340, 40), RES, "A", np.random.default_rng(3))[:, 20]
    noisy = field + np.random.default_rng(4).normal(0.0, 0.003, field.size)
    assert profile_roughness(noisy, RES).iso_class in "BC"  # 3 mm white noise reads as a rougher road
    assert profile_roughness(noisy, RES, 0.003).iso_class == "A"  # unless the sigma is given
    holed = field.copy()
    holed[100:110] = np.nan  # 0.3 m: bridged
    assert profile_roughness(holed, RES).length_m == pytest.approx(10.2)
    holed[200:240] = np.nan  # 1.2 m: the longest run is kept
    assert profile_roughness(holed, RES).length_m == pytest.approx(6.0)


def test_a_short_profile_is_unknown() -> None:
    r = profile_roughness(np.zeros(50), RES)  # 1.5 m
    assert math.isnan(r.gd_n0) and r.iso_class == ""


def test_classes_and_bad_input() -> None:
    assert [iso8608_class(g) for g in (1e-6, 40e-6, 200e-6, 1000e-6, 3000e-6, 1e-2, 1.0)] == list("ABCDEFH")
    assert iso8608_class(math.nan) == ""
    with pytest.raises(RoughnessError):
        profile_roughness(np.zeros((4, 4)), RES)
    with pytest.raises(RoughnessError, match="spacing"):
        profile_roughness(np.zeros(100), 0.5)  # Nyquist 1 cycle/m, below the band
    with pytest.raises(RoughnessError):
        RoughnessSettings(band_cycles_per_m=(0.1, 2.0))  # below 1 / segment_m
