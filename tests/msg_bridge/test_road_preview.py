"""PreviewProfiles <-> roadbev_msgs/RoadPreview."""

from __future__ import annotations

import math

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, bag_factory
from msg_bridge.preview import preview_from_message, road_preview_message
from roadbev_core.config import GridSpec
from roadbev_core.preview import PreviewProfiles, wheel_track_profiles

GRID = GridSpec()


def _profiles(speed: float | None) -> PreviewProfiles:
    rng = np.random.default_rng(1)
    elevation = rng.normal(0, 0.02, GRID.shape).astype(np.float32)
    elevation[:30] = np.nan
    sigma = np.full(GRID.shape, 0.01, np.float32)
    return wheel_track_profiles(elevation, sigma, GRID, vehicle_speed=speed, reference_distance=1.5)


@pytest.mark.parametrize("speed", [None, 8.0])
def test_round_trip(factory: MessageFactory, speed: float | None) -> None:
    profiles = _profiles(speed)
    msg = road_preview_message(profiles, factory, stamp_ns=3_000_000_001)
    assert msg.header.frame_id == "roadbev_road"
    assert [t.name for t in msg.tracks] == ["left", "right"]
    assert math.isnan(msg.vehicle_speed) if speed is None else msg.vehicle_speed == speed
    assert len(msg.time_of_arrival) == (0 if speed is None else profiles.n_samples)
    decoded = preview_from_message(msg)
    assert decoded.stamp_ns == 3_000_000_001
    out = decoded.profiles
    assert out.vehicle_speed == speed
    assert out.start_distance == pytest.approx(profiles.start_distance)
    assert out.reference_distance == pytest.approx(1.5)
    for a, b in zip(out.tracks, profiles.tracks, strict=True):
        assert (a.name, a.lateral_offset, a.width) == pytest.approx((b.name, b.lateral_offset, b.width))
        np.testing.assert_array_equal(a.elevation, b.elevation)
        np.testing.assert_array_equal(a.uncertainty, b.uncertainty)
    if speed is not None:
        assert decoded.time_of_arrival is not None
        np.testing.assert_allclose(decoded.time_of_arrival, (profiles.distances() - 1.5) / speed, rtol=1e-6)


def test_malformed_previews_raise_message_error() -> None:
    factory = bag_factory()
    msg = road_preview_message(_profiles(5.0), factory, stamp_ns=0)
    msg.tracks[1].uncertainty = msg.tracks[1].uncertainty[:-1]
    with pytest.raises(MessageError, match="uncertainties"):
        preview_from_message(msg)
    msg = road_preview_message(_profiles(5.0), factory, stamp_ns=0)
    msg.tracks[1].elevation = msg.tracks[1].elevation[:-1]
    msg.tracks[1].uncertainty = msg.tracks[1].uncertainty[:-1]
    with pytest.raises(MessageError, match="different lengths"):
        preview_from_message(msg)
    msg = road_preview_message(_profiles(5.0), factory, stamp_ns=0)
    msg.spacing = 0.0
    with pytest.raises(MessageError, match="spacing"):
        preview_from_message(msg)
    msg = road_preview_message(_profiles(5.0), factory, stamp_ns=0)
    msg.time_of_arrival = msg.time_of_arrival[:3]
    with pytest.raises(MessageError, match="3 times of arrival"):
        preview_from_message(msg)


def test_a_contact_plane_preview_round_trips_with_its_plane(factory: MessageFactory) -> None:
    from dataclasses import replace

    from roadbev_core.preview import REFERENCE_CONTACT_PLANE, ContactPlane

    plane = ContactPlane(0.012, 0.004, -0.01, 0.002, 0.0005, 0.0007, "map")
    profiles = replace(_profiles(8.0), reference=REFERENCE_CONTACT_PLANE, contact_plane=plane)
    msg = road_preview_message(profiles, factory, stamp_ns=5, frame_id="base_link")
    assert msg.reference == "contact_plane" and msg.contact_plane_source == "map"
    out = preview_from_message(msg).profiles
    assert out.reference == REFERENCE_CONTACT_PLANE and out.contact_plane is not None
    for name in ("height_m", "roll", "pitch", "height_sigma_m", "roll_sigma", "pitch_sigma"):
        assert getattr(out.contact_plane, name) == pytest.approx(getattr(plane, name), abs=1e-7)
    assert out.contact_plane.height_at(np.array(2.0), np.array(0.5)) == pytest.approx(
        0.012 - 2.0 * math.tan(-0.01) + 0.5 * math.tan(0.004) / math.cos(-0.01), abs=1e-6)


def test_a_per_frame_preview_carries_no_plane_and_an_unknown_reference_is_refused(factory: MessageFactory) -> None:
    msg = road_preview_message(_profiles(None), factory, stamp_ns=5)
    assert msg.reference == "road" and msg.contact_plane_source == "" and msg.contact_plane_height == 0.0
    assert preview_from_message(msg).profiles.contact_plane is None
    msg.reference = "gravity"
    with pytest.raises(MessageError, match="reference"):
        preview_from_message(msg)
