"""Wheel-track profiles: footprint averaging, ordering, coverage, uncertainty, arrival times."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_core.preview import PreviewError, PreviewProfiles, TrackProfile, wheel_track_profiles

GRID = GridSpec()


def _column_of(y: float) -> int:
    return int(np.floor((GRID.y_max - y) / GRID.resolution))


def test_profiles_are_nearest_first_and_read_under_each_wheel() -> None:
    x = GRID.x_centres()[:, None]  # [R, 1] far to near
    y = GRID.y_centres()[None, :]
    elevation = (0.01 * x + 0.1 * (y > 0)).astype(np.float32)  # left half of the road 10 cm higher
    out = wheel_track_profiles(elevation, None, GRID)
    assert [t.name for t in out.tracks] == ["left", "right"]
    assert out.spacing == pytest.approx(0.03)
    assert out.start_distance == pytest.approx(GRID.x_min + 0.015)
    np.testing.assert_allclose(out.distances(), GRID.x_centres()[::-1])
    left, right = out.track("left"), out.track("right")
    np.testing.assert_allclose(left.elevation, 0.01 * out.distances() + 0.1, atol=1e-6)
    np.testing.assert_allclose(right.elevation, 0.01 * out.distances(), atol=1e-6)
    assert np.all(np.isnan(left.uncertainty))  # no uncertainty given


def test_a_pothole_under_the_left_wheel_shows_at_its_distance() -> None:
    elevation = np.zeros(GRID.shape, np.float32)
    rows, _, _ = GRID.cell_index(np.array([4.0]), np.array([0.8]))
    col = _column_of(0.8)
    elevation[rows[0] - 1 : rows[0] + 2, col - 4 : col + 5] = -0.05  # 9 cm x 27 cm hole at x=4 m
    out = wheel_track_profiles(elevation, None, GRID, tyre_width_m=0.18)
    left, right = out.track("left"), out.track("right")
    deepest = int(np.argmin(left.elevation))
    assert out.distances()[deepest] == pytest.approx(4.0, abs=0.03)
    assert left.elevation[deepest] == pytest.approx(-0.05, abs=1e-6)
    assert np.all(right.elevation == 0)


def test_tyre_averaging_weights_partial_cells_by_area() -> None:
    elevation = np.zeros(GRID.shape, np.float32)
    col = _column_of(0.0)  # column spanning y in [-0.02, 0.01]
    elevation[:, col] = 0.09
    # a 3 cm tyre centred at y=0.005 covers the column from -0.01 to 0.01 (2/3) and 1/3 of the next
    out = wheel_track_profiles(elevation, None, GRID, track_offsets_m=[0.005], tyre_width_m=0.03)
    assert out.tracks[0].name == "track0"
    np.testing.assert_allclose(out.tracks[0].elevation, 0.06, atol=1e-6)


def test_holes_beyond_min_coverage_are_nan_and_uncertainty_is_the_mean_sigma() -> None:
    elevation = np.zeros(GRID.shape, np.float32)
    sigma = np.full(GRID.shape, 0.02, np.float32)
    elevation[:40] = np.nan  # the far 1.2 m has no estimate
    col = _column_of(-0.8)
    elevation[100, col - 5 : col + 5] = np.nan  # one hole row under the right wheel
    sigma[:, col - 20 :] = 0.04
    out = wheel_track_profiles(elevation, sigma, GRID, spacing_m=0.06)
    right = out.track("right")
    assert np.isnan(right.elevation[-20:]).all()  # far end without estimates
    assert np.isfinite(right.elevation[:-20]).all()  # half a sample window missing is still >= 50%
    np.testing.assert_allclose(right.uncertainty[:-20], 0.04, atol=1e-6)
    np.testing.assert_allclose(out.track("left").uncertainty[:-20], 0.02, atol=1e-6)
    strict = wheel_track_profiles(elevation, sigma, GRID, spacing_m=0.03, min_coverage=1.0)
    assert np.isnan(strict.track("right").elevation).sum() == 41


def test_spacing_and_max_distance() -> None:
    out = wheel_track_profiles(np.zeros(GRID.shape), None, GRID, spacing_m=0.1, max_distance_m=5.16)
    assert out.n_samples == 30
    np.testing.assert_allclose(out.distances()[[0, -1]], [2.21, 5.11])


def test_time_of_arrival_needs_a_positive_speed() -> None:
    out = wheel_track_profiles(np.zeros(GRID.shape), None, GRID, vehicle_speed=10.0, reference_distance=1.2)
    arrival = out.time_of_arrival()
    assert arrival is not None
    np.testing.assert_allclose(arrival, (out.distances() - 1.2) / 10.0, rtol=1e-6)
    assert wheel_track_profiles(np.zeros(GRID.shape), None, GRID).time_of_arrival() is None
    assert wheel_track_profiles(np.zeros(GRID.shape), None, GRID, vehicle_speed=0.0).time_of_arrival() is None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"track_offsets_m": [0.95]}, "leaves the grid"),
        ({"spacing_m": 0.0}, "spacing must be positive"),
        ({"tyre_width_m": -0.1}, "tyre width"),
        ({"min_coverage": 0.0}, "min_coverage"),
        ({"track_names": ["a"]}, "1 track names for 2 tracks"),
        ({"max_distance_m": 2.0}, "no sample"),
    ],
)
def test_bad_settings_raise_preview_error(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(PreviewError, match=message):
        wheel_track_profiles(np.zeros(GRID.shape), None, GRID, **kwargs)


def test_inputs_must_be_on_the_grid() -> None:
    with pytest.raises(PreviewError, match="the grid is"):
        wheel_track_profiles(np.zeros((3, 3)), None, GRID)
    with pytest.raises(PreviewError, match="uncertainty"):
        wheel_track_profiles(np.zeros(GRID.shape), np.zeros((3, 3)), GRID)


def test_profiles_validate_their_tracks() -> None:
    a = TrackProfile("a", 0.0, 0.2, np.zeros(3, np.float32), np.zeros(3, np.float32))
    b = TrackProfile("b", 0.0, 0.2, np.zeros(4, np.float32), np.zeros(4, np.float32))
    with pytest.raises(PreviewError, match="different lengths"):
        PreviewProfiles(2.0, 0.1, (a, b))
    with pytest.raises(PreviewError, match="equal 1-D"):
        TrackProfile("c", 0.0, 0.2, np.zeros(3), np.zeros(2))
    with pytest.raises(KeyError):
        PreviewProfiles(2.0, 0.1, (a,)).track("b")


def test_a_hidden_stretch_between_known_samples_is_bridged_with_a_sigma_that_says_so() -> None:
    from roadbev_core.preview import BRIDGE_ROUGHNESS_M2_PER_M, bridge_gaps

    # the far side of a 6 cm bump never seen: known up to its crest, then the road behind it
    e = np.full(40, np.nan)
    s = np.full(40, np.nan)
    e[:10], s[:10] = 0.06, 0.002
    e[20:35], s[20:35] = 0.0, 0.002
    out, sigma = bridge_gaps(e, s, 0.03, max_gap_m=0.5)
    np.testing.assert_allclose(out[9:21], np.linspace(0.06, 0.0, 12), atol=1e-6)  # the line between the ends
    assert np.all(np.isnan(out[35:])) and np.all(np.isnan(sigma[35:]))  # nothing beyond the last known sample
    mid = 15  # 6 samples (0.18 m) after the crest, 5 before the road: about half the drop unknown
    t, d_a, d_b = 6 / 11, 0.18, 0.15
    expected = np.sqrt(0.002**2 + BRIDGE_ROUGHNESS_M2_PER_M * d_a * d_b / 0.33 + t * (1 - t) * 0.06**2)
    assert sigma[mid] == pytest.approx(expected, rel=1e-5) and sigma[mid] > 0.025
    assert sigma[10] < sigma[mid] and sigma[19] < sigma[mid]  # larger inside than next to the ends
    # a gap longer than max_gap_m stays a gap, and 0 bridges nothing
    for out_e, _ in (bridge_gaps(e, s, 0.03, max_gap_m=0.2), bridge_gaps(e, s, 0.03, max_gap_m=0.0)):
        assert np.all(np.isnan(out_e[10:20]))
    # ends without a sigma give bridged samples without one
    _, no_sigma = bridge_gaps(e, np.full(40, np.nan), 0.03, max_gap_m=0.5)
    assert np.all(np.isnan(no_sigma))


def test_profiles_bridge_declined_cells_when_asked() -> None:
    elevation = np.zeros(GRID.shape, np.float32)
    elevation[60:70, :] = np.nan  # 30 cm of declined rows across the road
    sigma = np.full(GRID.shape, 0.003, np.float32)
    plain = wheel_track_profiles(elevation, sigma, GRID)
    bridged = wheel_track_profiles(elevation, sigma, GRID, max_gap_m=1.0)
    assert np.isnan(plain.track("left").elevation).sum() >= 9
    assert not np.isnan(bridged.track("left").elevation).any()
    gap = np.isnan(plain.track("left").elevation)
    assert np.all(bridged.track("left").uncertainty[gap] > 0.003)
