"""The hazard tracker over moving map windows: features followed in odom, reported once, retired
behind the car; the severity cost; roughness along the wheel tracks."""

from __future__ import annotations

import functools
import itertools
import math
from typing import cast

import numpy as np
import pytest

from roadbev_core.ego_motion import PlanarPose
from roadbev_core.fusion import MapWindow
from roadbev_core.hazard_tracking import HazardReport, HazardTracker, TrackerError, TrackerSettings, distance_ahead
from roadbev_lab.synth.heightfield import roughness_field

RES = 0.03


def _road(x: np.ndarray, y: np.ndarray, rough: np.ndarray | None = None) -> np.ndarray:
    """[R, C] a road rising 1 % with a 5 cm speed bump across it at x = 20 m (0.45 m long) and a
    4 cm deep pothole (0.6 x 0.6 m) at (26, 0.5) m."""
    X, Y = np.meshgrid(x, y, indexing="ij")
    z = 0.01 * X
    z += np.where(np.abs(X - 20.0) < 0.225, 0.05 * np.cos(np.pi * (X - 20.0) / 0.45) ** 2, 0.0)
    z -= np.where((np.abs(X - 26.0) < 0.3) & (np.abs(Y - 0.5) < 0.3), 0.04, 0.0)
    if rough is not None:
        z += rough
    return cast("np.ndarray", z.astype(np.float32))


@functools.cache
def _field(road_class: str) -> np.ndarray:
    """[4000, 64] ISO 8608 roughness of a class, 3 cm cells from x = 0, columns from y = -0.96 m."""
    return roughness_field((4000, 64), RES, road_class, np.random.default_rng(7))


def _window(base_x: float, stamp_ns: int, noise: float = 0.0, rng: np.random.Generator | None = None,
            rough_class: str | None = None) -> MapWindow:
    """The window a fused map would publish with base_link at (base_x, 0), heading +x: from 1 m
    behind to 8.68 m ahead, 1.92 m wide, grid_map order."""
    n_rows, n_cols = 324, 64
    centre = (round((base_x + 3.84) / RES) * RES, 0.0)
    x = centre[0] + 0.5 * n_rows * RES - (np.arange(n_rows) + 0.5) * RES
    y = centre[1] + 0.5 * n_cols * RES - (np.arange(n_cols) + 0.5) * RES
    rough = None
    if rough_class is not None:  # a fixed field in odom: cells follow the map's lattice
        rough = _field(rough_class)[np.clip(np.rint(x / RES).astype(int), 0, 3999)][:, ::-1]
    z = _road(x, y, rough)
    if noise > 0 and rng is not None:
        z = z + rng.normal(0.0, noise, z.shape).astype(np.float32)
    sigma = np.full(z.shape, max(noise, 0.002), np.float32)
    return MapWindow(z, sigma, np.ones_like(z), np.zeros_like(z), RES, centre, stamp_ns)


def _drive(tracker: HazardTracker, start: float, stop: float, step: float, noise: float = 0.0,
           rng: np.random.Generator | None = None, rough_class: str | None = None) -> list[HazardReport]:
    reports = []
    for k, bx in enumerate(np.arange(start, stop, step)):
        stamp = 1_000_000_000 + int(k * step / 10.0 * 1e9)  # 10 m/s
        window = _window(float(bx), stamp, noise, rng, rough_class)
        reports.append(tracker.update(window, PlanarPose(stamp, float(bx), 0.0, 0.0, 10.0)))
    return reports


def test_features_are_tracked_reported_once_and_retired_behind_the_car() -> None:
    tracker = HazardTracker()
    reports = _drive(tracker, 5.0, 34.0, 1.0, noise=0.002, rng=np.random.default_rng(0))
    ids: dict[str, set[int]] = {"bump": set(), "pothole": set()}
    for rep in reports:
        for h in rep.hazards:
            ids[h.kind].add(h.id)
    assert len(ids["bump"]) == 1 and len(ids["pothole"]) == 1  # one track each, however many windows saw it
    bump = next(t for t in tracker.retired if t.kind == "bump")  # it left the map behind the car
    assert bump.x == pytest.approx(20.0, abs=0.05)
    assert bump.height_m == pytest.approx(0.05, rel=0.15)
    assert bump.detections >= 8
    # first seen at the window's far edge (8.68 m ahead of base_link, 5.9 m ahead of the front
    # axle), reported at the second detection, one metre later
    assert 3.5 < bump.first_reported_distance_m < 6.2
    assert bump.first_reported_ns is not None and bump.first_reported_ns > bump.first_seen_ns
    pothole = next(h for rep in reports for h in rep.hazards if h.kind == "pothole")
    assert pothole.height_m == pytest.approx(-0.04, rel=0.15)
    assert pothole.y == pytest.approx(0.5, abs=0.05)
    assert pothole.length_m == pytest.approx(0.6, abs=0.1) and pothole.width_m == pytest.approx(0.6, abs=0.1)
    assert 0.0 < pothole.confidence <= 1.0 and pothole.height_sigma_m > 0
    # nearest first, and the distance ahead shrinks as the car approaches
    both = [rep for rep in reports if len(rep.hazards) == 2]
    assert both and all(rep.hazards[0].kind == "bump" for rep in both)
    ahead = [h.distance_ahead_m for rep in reports for h in rep.hazards if h.kind == "pothole"]
    assert all(a > b for a, b in itertools.pairwise(ahead))


def test_a_flat_noisy_road_reports_nothing_and_a_single_glitch_is_not_reported() -> None:
    tracker = HazardTracker()
    rng = np.random.default_rng(1)
    for k in range(10):
        w = _window(40.0 + k, 1_000_000_000 + k * 100_000_000, noise=0.003, rng=rng)
        if k == 4:  # one window with a 6 cm blob that the next window does not confirm
            w.elevation[100:110, 20:30] += 0.06
        rep = tracker.update(w, PlanarPose(w.stamp_ns, 40.0 + k, 0.0, 0.0, 10.0))
        assert rep.hazards == []
    assert tracker.tracks == []


def test_severity_cost_and_unknown_cells() -> None:
    tracker = HazardTracker(TrackerSettings(full_cost_height_m=0.05))
    w = _window(14.0, 1_000_000_000)
    w.elevation[:5] = np.nan
    rep = tracker.update(w)
    assert rep.cost.shape == w.elevation.shape and rep.cost.dtype == np.int8
    assert np.all(rep.cost[:5] == -1)
    xs, _ = w.cell_centres()
    on_bump = np.argmin(np.abs(xs - 20.0))
    assert rep.cost[on_bump].min() >= 90  # the 5 cm crest: full cost
    assert np.median(rep.cost[np.abs(xs - 16.0) < 1.0]) <= 2  # the smooth road around it
    assert rep.roughness == [] and math.isnan(rep.speed_mps)  # no pose: no wheel tracks, no speed


@pytest.mark.parametrize("road_class", ["A", "C"])
def test_roughness_along_the_wheel_tracks(road_class: str) -> None:
    tracker = HazardTracker()
    reports = _drive(tracker, 45.0, 75.0, 1.0, rough_class=road_class)
    last = reports[-1].roughness
    assert [r.name for r in last] == ["front_left", "front_right"]
    assert [r.lateral_offset_m for r in last] == [0.8, -0.8]
    assert all(r.iso_class == road_class for r in last), last
    assert all(r.length_m > 5.0 for r in last)


def test_distance_ahead_uses_the_heading_and_the_near_edge() -> None:
    base = PlanarPose(0, 1.0, 2.0, math.pi / 2, 5.0)  # heading +y
    assert distance_ahead(base, 1.0, 12.0, 4.0, 0.4, 2.8) == pytest.approx(10.0 - 0.2 - 2.8)


def test_bad_input_is_refused() -> None:
    with pytest.raises(TrackerError):
        TrackerSettings(confirm_hits=0)
    tracker = HazardTracker()
    w = _window(14.0, 2_000_000_000)
    with pytest.raises(TrackerError, match="layers"):
        tracker.update(w._replace(uncertainty=w.uncertainty[:10]))
    tracker.update(w)
    with pytest.raises(TrackerError, match="older"):
        tracker.update(w._replace(stamp_ns=1))
    tracker.reset()
    tracker.update(w._replace(stamp_ns=1))  # after a reset the clock may start again
