"""The viewer markers: the preview's wheel tracks coloured by σ, the hazards as boxes and labels."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, bag_factory, serialize
from msg_bridge.bag import deserialize
from msg_bridge.markers import (
    BUMP_RGB,
    HAZARD_MIN_ALPHA,
    POTHOLE_RGB,
    PREVIEW_LINE_WIDTH_M,
    hazard_markers,
    preview_markers,
    sigma_colours,
)
from roadbev_core.hazard_tracking import HazardReport, TrackedHazard
from roadbev_core.preview import REFERENCE_CONTACT_PLANE, ContactPlane, PreviewProfiles, TrackProfile

LINE_STRIP, CUBE, TEXT_VIEW_FACING, DELETEALL = 4, 1, 9, 3
SIGMA_MAX = 0.02


def _track(name: str, offset: float, elevation: list[float], sigma: list[float]) -> TrackProfile:
    return TrackProfile(name, offset, 0.2, np.array(elevation, np.float32), np.array(sigma, np.float32))


def _profiles(plane: ContactPlane | None = None) -> PreviewProfiles:
    nan = math.nan
    left = _track("left", 0.8, [0.01, 0.02, 0.03, nan, 0.05, 0.06, 0.07, 0.08],
               [0.0, 0.005, 0.01, nan, 0.01, nan, 0.015, 0.03])
    right = _track("right", -0.8, [nan, 0.0, -0.01, -0.02, nan, 0.04, nan, nan],
                   [nan, 0.01, 0.01, 0.01, nan, 0.01, nan, nan])
    if plane is None:
        return PreviewProfiles(start_distance=2.0, spacing=0.5, tracks=(left, right))
    return PreviewProfiles(start_distance=2.0, spacing=0.5, tracks=(left, right), reference=REFERENCE_CONTACT_PLANE,
                           contact_plane=plane)


def _xyz(marker: Any) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in marker.points])


def _rgb(colours: Any) -> np.ndarray:
    return np.array([[c.r, c.g, c.b] for c in colours])


def test_sigma_colour_scale_runs_green_yellow_red() -> None:
    rgb = sigma_colours(np.array([0.0, 0.005, 0.01, 0.015, 0.02, 0.5, math.nan]), SIGMA_MAX)
    np.testing.assert_allclose(rgb, np.array([[0, 1, 0], [0.5, 1, 0], [1, 1, 0], [1, 0.5, 0], [1, 0, 0], [1, 0, 0],
                                              [1, 0, 0]]))
    with pytest.raises(MessageError, match="sigma_max_m"):
        sigma_colours(np.zeros(2), 0.0)


def test_preview_strips_per_track_broken_at_unknown_samples(factory: MessageFactory) -> None:
    profiles = _profiles()
    msg = preview_markers(profiles, factory, stamp_ns=3_000_000_001, frame_id="roadbev_road", sigma_max_m=SIGMA_MAX)
    first, *strips = msg.markers
    assert first.action == DELETEALL  # the previous array's strips go
    assert all(m.header.frame_id == "roadbev_road" for m in msg.markers)
    assert all((m.header.stamp.sec, m.header.stamp.nanosec) == (3, 1) for m in msg.markers)
    assert all(m.type == LINE_STRIP for m in strips)
    # left: samples 0-2, then 4 alone (its neighbour 5 has no sigma: not drawn), then 6-7;
    # right: samples 1-3 (5 is alone)
    assert [(m.ns, m.id, len(m.points)) for m in strips] == [("left", 0, 3), ("left", 1, 2), ("right", 0, 3)]
    x = profiles.distances()
    left, right = profiles.tracks
    np.testing.assert_allclose(_xyz(strips[0]), np.array([[x[i], 0.8, left.elevation[i]] for i in range(3)]),
                               atol=1e-7)
    np.testing.assert_allclose(_xyz(strips[1])[:, 0], x[6:8])
    np.testing.assert_allclose(_xyz(strips[2]), np.array([[x[i], -0.8, right.elevation[i]] for i in (1, 2, 3)]),
                               atol=1e-7)
    # every point coloured by its own sigma: green 0, yellow-green 0.005, yellow 0.01; orange 0.015, red 0.03
    np.testing.assert_allclose(_rgb(strips[0].colors), np.array([[0, 1, 0], [0.5, 1, 0], [1, 1, 0]]), atol=1e-6)
    np.testing.assert_allclose(_rgb(strips[1].colors), np.array([[1, 0.5, 0], [1, 0, 0]]), atol=1e-6)
    assert all(len(m.colors) == len(m.points) for m in strips)
    assert strips[0].scale.x == pytest.approx(PREVIEW_LINE_WIDTH_M)
    assert strips[0].pose.orientation.w == 1.0


def test_contact_plane_strips_lie_on_the_plane(factory: MessageFactory) -> None:
    plane = ContactPlane(0.02, 0.01, 0.015, 0.001, 0.001, 0.001)
    profiles = _profiles(plane)
    msg = preview_markers(profiles, factory, stamp_ns=0, frame_id="base_link", sigma_max_m=SIGMA_MAX)
    strips = msg.markers[1:]
    assert all(m.header.frame_id == "base_link" for m in msg.markers)
    xyz = _xyz(strips[0])
    expected = profiles.tracks[0].elevation[:3] + plane.height_at(xyz[:, 0], xyz[:, 1])
    np.testing.assert_allclose(xyz[:, 2], expected, atol=1e-6)
    assert not np.allclose(xyz[:, 2], profiles.tracks[0].elevation[:3], atol=1e-3)  # the plane is not flat here


def test_a_preview_without_known_samples_only_clears(factory: MessageFactory) -> None:
    empty = _track("left", 0.8, [math.nan] * 4, [math.nan] * 4)
    profiles = PreviewProfiles(start_distance=1.0, spacing=0.1, tracks=(empty,))
    msg = preview_markers(profiles, factory, stamp_ns=0, frame_id="roadbev_road", sigma_max_m=SIGMA_MAX)
    assert [m.action for m in msg.markers] == [DELETEALL]


def _report() -> HazardReport:
    bump = TrackedHazard(3, "bump", 20.0, 0.1, 0.2, 0.02, 0.45, 1.92, 0.05, 0.004, 1.0, 6, 0, 1_000_000_000,
                         1_500_000_000, first_reported_ns=1_100_000_000, distance_ahead_m=2.4)
    pothole = TrackedHazard(4, "pothole", 26.0, 0.5, math.nan, 0.015, 0.6, 0.6, -0.04, 0.005, 0.0, 2, 0,
                            1_400_000_000, 1_500_000_000, first_reported_ns=1_500_000_000)
    return HazardReport(1_500_000_000, [bump, pothole], np.zeros((2, 2), np.int8), 0.03, (21.0, 0.2), [], 8.0)


def test_hazards_are_boxes_coloured_by_kind_faded_by_confidence_with_labels(factory: MessageFactory) -> None:
    msg = hazard_markers(_report(), factory, frame_id="odom")
    first, bump, bump_label, pothole, pothole_label = msg.markers
    assert first.action == DELETEALL  # retired hazards go
    assert all(m.header.frame_id == "odom" for m in msg.markers)
    assert all((m.header.stamp.sec, m.header.stamp.nanosec) == (1, 500_000_000) for m in msg.markers)
    assert [(m.ns, m.id, m.type) for m in (bump, bump_label, pothole, pothole_label)] == [
        ("hazards", 3, CUBE), ("hazard_labels", 3, TEXT_VIEW_FACING), ("hazards", 4, CUBE),
        ("hazard_labels", 4, TEXT_VIEW_FACING)]
    # the bump's box stands on the road's level (0.2 m) up to its crest; the pothole's (level
    # unknown: 0) hangs below it down to its floor
    assert (bump.pose.position.x, bump.pose.position.y, bump.pose.position.z) == pytest.approx((20.0, 0.1, 0.225))
    assert (bump.scale.x, bump.scale.y, bump.scale.z) == pytest.approx((0.45, 1.92, 0.05))
    assert pothole.pose.position.z == pytest.approx(-0.02) and pothole.scale.z == pytest.approx(0.04)
    assert (bump.color.r, bump.color.g, bump.color.b) == pytest.approx(BUMP_RGB)
    assert (pothole.color.r, pothole.color.g, pothole.color.b) == pytest.approx(POTHOLE_RGB)
    assert bump.color.a == pytest.approx(1.0) and pothole.color.a == pytest.approx(HAZARD_MIN_ALPHA)
    assert bump_label.text == "bump +5.0 cm\nconfidence 1.00"
    assert pothole_label.text == "pothole -4.0 cm\nconfidence 0.00"
    assert bump_label.pose.position.z > bump.pose.position.z + 0.5 * bump.scale.z  # above the box


def test_no_hazards_only_clears(factory: MessageFactory) -> None:
    msg = hazard_markers(_report()._replace(hazards=[]), factory)
    assert [m.action for m in msg.markers] == [DELETEALL]


def test_markers_serialise_for_bags() -> None:
    factory = bag_factory()
    for msg in (preview_markers(_profiles(), factory, stamp_ns=7, frame_id="roadbev_road", sigma_max_m=SIGMA_MAX),
                hazard_markers(_report(), factory)):
        back = deserialize(serialize(msg, "visualization_msgs/msg/MarkerArray"), "visualization_msgs/msg/MarkerArray")
        assert [(m.ns, m.id, m.type, len(m.points), m.text) for m in back.markers] == [
            (m.ns, m.id, m.type, len(m.points), m.text) for m in msg.markers]
