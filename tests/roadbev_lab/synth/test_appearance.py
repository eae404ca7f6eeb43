"""Appearance ranges: the weak and strong ends, what lies between, and random roads drawn from one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from roadbev_lab.synth import (
    CLEAN,
    DEFAULT_APPEARANCE,
    REAL_ROAD,
    REAL_ROAD_MIDDLE,
    Appearance,
    RoadConfig,
    SynthError,
    appearance_range,
    random_road,
)


def test_a_range_runs_from_its_weak_to_its_strong_end() -> None:
    assert REAL_ROAD.at(0.0) == REAL_ROAD.weak
    strong = REAL_ROAD.at(1.0)
    for field in dataclasses.fields(Appearance):
        assert getattr(strong, field.name) == pytest.approx(getattr(REAL_ROAD.strong, field.name))
    middle = REAL_ROAD.at(0.5)
    # the texture scale spans a decade: geometric mean; noise and glints grow with the square
    weak, strong = REAL_ROAD.weak, REAL_ROAD.strong
    assert middle.texture_scale == pytest.approx(np.sqrt(weak.texture_scale * strong.texture_scale))
    assert middle.noise_sigma == pytest.approx(weak.noise_sigma + (strong.noise_sigma - weak.noise_sigma) / 4)
    assert middle.glint_density == pytest.approx(weak.glint_density + (strong.glint_density - weak.glint_density) / 4)
    assert REAL_ROAD.weak.texture_scale < middle.texture_scale < REAL_ROAD.strong.texture_scale
    with pytest.raises(SynthError):
        REAL_ROAD.at(1.5)


def test_an_appearance_sets_exactly_its_fields_of_a_road() -> None:
    road = RoadConfig(road_class="D", features=("crack",), noise_sigma=0.7, jpeg_quality=80)
    looks = Appearance(2.0, 4.0, 0.2, 0.005, 3.0, 4.0)
    new = looks.apply(road)
    for field in dataclasses.fields(Appearance):
        assert getattr(new, field.name) == getattr(looks, field.name)
    assert (new.road_class, new.features, new.jpeg_quality) == ("D", ("crack",), 80)
    with pytest.raises(SynthError):  # RoadConfig still checks what it is given
        dataclasses.replace(looks, glint_lobe_deg=-1.0).apply(road)


def test_a_random_road_drawn_with_a_range_keeps_its_geometry_and_takes_the_range_appearance() -> None:
    for seed in range(5):
        plain = random_road(np.random.default_rng(seed), None)  # the clean appearance
        looked = random_road(np.random.default_rng(seed), REAL_ROAD)
        assert (looked.road_class, looked.features, looked.surface, looked.cross_slope, looked.grade) == (
            plain.road_class, plain.features, plain.surface, plain.cross_slope, plain.grade)
        assert REAL_ROAD.weak.texture_scale <= looked.texture_scale <= REAL_ROAD.strong.texture_scale
        assert REAL_ROAD.weak.noise_sigma <= looked.noise_sigma <= REAL_ROAD.strong.noise_sigma
        assert plain.glint_density == 0.0 and plain.texture_scale == 1.0
        assert random_road(np.random.default_rng(seed)) == looked  # the range is the default


def test_roads_built_by_hand_take_the_middle_of_the_default_range() -> None:
    assert appearance_range(DEFAULT_APPEARANCE).at(0.5) == REAL_ROAD_MIDDLE  # type: ignore[union-attr]
    road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class="B"))
    assert road.glint_density > 0.0 and road.row_offset_px > 0.0 and road.road_class == "B"


def test_appearance_names() -> None:
    assert appearance_range(None) is REAL_ROAD and appearance_range(CLEAN) is None
    assert appearance_range("real-road") is REAL_ROAD
    with pytest.raises(SynthError, match="unknown appearance"):
        appearance_range("sunny")
    with pytest.raises(SynthError, match="unknown appearance"):
        appearance_range("generator")  # scene version 1's name of the clean appearance
