"""The demo's drive section: the map mosaic, hazard matching, the message's plane slopes, the drive recipe.

The section end to end (map on and off, equal to ``roadbev eval``) is in ``test_demo.py``, on the
demo fixture's drive.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.fusion import MapWindow
from roadbev_core.hazards import Hazard
from roadbev_core.preview import REFERENCE_CONTACT_PLANE, REFERENCE_ROAD, ContactPlane, PreviewProfiles, TrackProfile
from roadbev_lab.demo.drive import (
    DRIVE_SEED,
    DriveDemoError,
    MapMosaic,
    TrueFeature,
    drive_config,
    match_hazards,
    message_plane_slopes,
    mosaic,
)
from roadbev_lab.evaluation.arrival import TimedPreview


def _window(values: np.ndarray, centre: tuple[float, float], res: float = 0.1, stamp: int = 0) -> MapWindow:
    v = np.asarray(values, np.float32)
    return MapWindow(v, np.full_like(v, 0.01), np.where(np.isfinite(v), 1.0, np.nan).astype(np.float32),
                     np.zeros_like(v), res, centre, stamp)


def test_mosaic_pastes_windows_on_one_lattice_the_later_known_cell_wins() -> None:
    first = _window(np.full((4, 2), 1.0), (0.2, 0.0))  # x 0..0.4, y -0.1..0.1
    second_values = np.full((4, 2), 2.0)
    second_values[0, 0] = np.nan  # unknown in the later window: the earlier value stays (it is not there)
    second_values[3, 1] = np.nan  # x 0.2..0.3 row, y -0.1..0 column: first had it, keeps 1.0
    second = _window(second_values, (0.4, 0.0), stamp=1)  # x 0.2..0.6
    m = mosaic([first, second])
    assert m.elevation.shape == (6, 2) and m.resolution == pytest.approx(0.1)
    assert m.extent() == pytest.approx((0.0, 0.6, -0.1, 0.1))
    xs, _ys = m.cell_centres()
    assert xs == pytest.approx([0.55, 0.45, 0.35, 0.25, 0.15, 0.05])
    # x 0.55 (only the second window), x 0.25/0.35 overlap (the second wins), x 0.05/0.15 only the first
    assert np.isnan(m.elevation[0, 0]) and m.elevation[0, 1] == 2.0
    assert np.all(m.elevation[1:3] == 2.0)
    assert m.elevation[3, 0] == 2.0 and m.elevation[3, 1] == 1.0
    assert np.all(m.elevation[4:] == 1.0)
    assert m.observations[3, 1] == 1.0 and m.uncertainty[1, 0] == pytest.approx(0.01)


def test_mosaic_refuses_nothing_and_windows_off_the_lattice() -> None:
    with pytest.raises(DriveDemoError):
        mosaic([])
    with pytest.raises(DriveDemoError, match="lattice"):
        mosaic([_window(np.ones((2, 2)), (0.0, 0.0)), _window(np.ones((2, 2)), (0.05, 0.0))])
    with pytest.raises(DriveDemoError, match="resolutions"):
        mosaic([_window(np.ones((2, 2)), (0.0, 0.0)), _window(np.ones((2, 2)), (0.0, 0.0), res=0.2)])


def _flat_map() -> MapMosaic:
    e = np.zeros((100, 20), np.float32)  # x 0..10, y -1..1 at 0.1 m
    e[:, :5] = np.nan  # y > 0.5 never seen
    return MapMosaic(e, np.zeros_like(e), np.ones_like(e), 0.1, (5.0, 0.0), np.zeros_like(e))


def _hazard(kind: str, x: float, y: float, h: float) -> Hazard:
    return Hazard(kind, x, y, 0.3, 0.3, h, 0.005, 1.0, 0.09)


def test_match_hazards_pairs_by_kind_and_distance_and_counts_false_alarms() -> None:
    m = _flat_map()
    features = [
        TrueFeature("speed_bump", 2.0, 3.0, 0.06),  # centre off the map, but a bump spans the lane: scored
        TrueFeature("pothole", 5.0, -0.5, -0.05),
        TrueFeature("pothole", 7.0, 0.85, -0.06),  # in the unseen strip: not scored
        TrueFeature("pothole", 8.0, 0.0, -0.02),  # under 3 cm: not scored, but its detection is no false alarm
        TrueFeature("pothole", 12.0, 0.0, -0.05),  # beyond the map
    ]
    hazards = [_hazard("bump", 2.3, 0.0, 0.055), _hazard("pothole", 5.1, 0.3, -0.05),  # 0.8 m across: no match
               _hazard("pothole", 8.1, 0.0, -0.02), _hazard("bump", 9.0, 0.0, 0.04)]
    matches, false = match_hazards(hazards, features, m)
    assert [f.x for f, _ in matches] == [2.0, 5.0]
    assert matches[0].detection == hazards[0] and matches[1].detection is None
    # the pothole detection 0.8 m across is next to a placed feature along x: not a false alarm either
    assert false == [hazards[3]]


def test_message_plane_slopes_are_the_gradient_of_the_carried_plane() -> None:
    plane = ContactPlane(0.01, roll=0.02, pitch=-0.03, height_sigma_m=0.001, roll_sigma=0.001, pitch_sigma=0.001)
    track = TrackProfile("front_left", 0.8, 0.2, np.zeros(3, np.float32), np.zeros(3, np.float32))
    msg = TimedPreview(0, REFERENCE_CONTACT_PLANE,
                       PreviewProfiles(2.8, 0.1, (track,), reference=REFERENCE_CONTACT_PLANE, contact_plane=plane))
    slopes = message_plane_slopes(msg)
    assert slopes is not None
    x, y = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    z = plane.height_at(x, y)
    assert slopes[0] == pytest.approx(z[1] - z[0]) and slopes[1] == pytest.approx(z[2] - z[0])
    road = TimedPreview(0, REFERENCE_ROAD, PreviewProfiles(2.2, 0.1, (track,)))
    assert message_plane_slopes(road) is None


def test_the_drive_recipe_is_the_contract_drive_with_its_own_seed() -> None:
    config = drive_config(12, image_scale=0.25)
    assert config.drive.seed == DRIVE_SEED == 330_000  # not a benchmark's (310000+, 320000+) nor tuning's
    assert config.drive.speed_mps == 10.0 and config.drive.frame_rate_hz == 10.0
    assert {"speed_bump", "pothole"} <= set(config.drive.road.features)
    assert config.tail_s >= 1.0 + 0.1  # the ride's 1 s horizon beyond the last frame + latency
    assert config.drive.camera.width == 240 and math.isclose(drive_config().drive.camera.width, 960)
