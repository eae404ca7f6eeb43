"""HazardReport <-> roadbev_msgs/RoadHazardArray, and the severity cost <-> nav_msgs/OccupancyGrid."""

from __future__ import annotations

import math

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, bag_factory, serialize
from msg_bridge.bag import deserialize
from msg_bridge.hazards import (
    cost_from_occupancy_grid,
    hazards_from_message,
    occupancy_grid_message,
    road_hazards_message,
)
from roadbev_core.hazard_tracking import HazardReport, TrackedHazard, TrackRoughness


def rclpy_hazard_messages_built() -> bool:
    """Whether the installed roadbev_msgs has the hazard messages (the interfaces were rebuilt
    after they were added: scripts/setup_venv.sh does it when interfaces/ changes)."""
    try:
        from roadbev_msgs.msg import RoadHazardArray  # noqa: F401
    except ImportError:
        return False
    return True


NOT_BUILT = "roadbev_msgs in this venv predates RoadHazardArray: run scripts/setup_venv.sh (interfaces changed)"


@pytest.fixture(params=["rclpy", "typestore"])
def factory(request: pytest.FixtureRequest) -> MessageFactory:
    from msg_bridge import RclpyFactory

    if request.param == "rclpy":
        if not rclpy_hazard_messages_built():
            pytest.skip(NOT_BUILT)
        return RclpyFactory()
    return bag_factory()


def _report(speed: float = 8.0) -> HazardReport:
    bump = TrackedHazard(3, "bump", 20.0, 0.1, 0.2, 0.02, 0.45, 1.92, 0.05, 0.004, 0.9, 6, 0, 1_000_000_000,
                         1_500_000_000, first_reported_ns=1_100_000_000, first_reported_distance_m=5.2,
                         distance_ahead_m=2.4)
    pothole = TrackedHazard(4, "pothole", 26.0, 0.5, 0.26, 0.015, 0.6, 0.6, -0.04, 0.005, 0.7, 2, 0,
                            1_400_000_000, 1_500_000_000, first_reported_ns=1_500_000_000)
    cost = np.zeros((5, 3), np.int8)
    cost[0, 0], cost[4, 2], cost[2, 1] = 100, -1, 40
    roughness = [TrackRoughness("front_left", 0.8, 6e-5, "B", 9.6), TrackRoughness("front_right", -0.8, math.nan,
                                                                                   "", 2.0)]
    return HazardReport(1_500_000_000, [bump, pothole], cost, 0.03, (21.0, 0.2), roughness, speed)


def test_round_trip(factory: MessageFactory) -> None:
    report = _report()
    msg = road_hazards_message(report, factory, frame_id="odom")
    decoded = hazards_from_message(msg)
    assert (decoded.stamp_ns, decoded.frame_id, decoded.vehicle_speed) == (1_500_000_000, "odom", 8.0)
    bump, pothole = decoded.hazards
    assert (bump.id, bump.kind, pothole.kind) == (3, "bump", "pothole")
    assert (bump.x, bump.y, bump.z) == pytest.approx((20.0, 0.1, 0.2))
    assert (bump.length_m, bump.width_m, bump.height_m, bump.height_sigma_m) == pytest.approx((0.45, 1.92, 0.05, 0.004))
    assert pothole.height_m == pytest.approx(-0.04)
    assert (bump.first_seen_ns, bump.first_reported_ns, bump.detections) == (1_000_000_000, 1_100_000_000, 6)
    assert bump.first_reported_distance_m == pytest.approx(5.2)
    assert bump.time_to_arrival_s == pytest.approx(2.4 / 8.0)  # distance ahead / speed
    assert math.isnan(pothole.distance_ahead_m) and math.isnan(pothole.time_to_arrival_s)
    assert [r.iso_class for r in decoded.roughness] == ["B", ""]
    assert decoded.roughness[0].gd_n0 == pytest.approx(6e-5) and math.isnan(decoded.roughness[1].gd_n0)


def test_without_speed_no_time_to_arrival() -> None:
    msg = road_hazards_message(_report(speed=math.nan), bag_factory())
    assert all(math.isnan(h.time_to_arrival) for h in msg.hazards)


def test_serialises_as_cdr() -> None:
    msg = road_hazards_message(_report(), bag_factory())
    back = deserialize(serialize(msg), "roadbev_msgs/msg/RoadHazardArray")
    for a, b in zip(hazards_from_message(back).hazards, hazards_from_message(msg).hazards, strict=True):
        assert a == pytest.approx(b, nan_ok=True)  # float32 fields: equal to float32 precision


def test_malformed_hazards_raise_message_error() -> None:
    factory = bag_factory()
    msg = road_hazards_message(_report(), factory)
    msg.hazards[0].kind = "kerb"
    with pytest.raises(MessageError, match="kind"):
        hazards_from_message(msg)
    msg = road_hazards_message(_report(), factory)
    msg.hazards[1].confidence = 1.5
    with pytest.raises(MessageError, match="confidence"):
        hazards_from_message(msg)
    msg = road_hazards_message(_report(), factory)
    msg.hazards[1].length = -1.0
    with pytest.raises(MessageError, match=">= 0"):
        hazards_from_message(msg)


def test_occupancy_grid_order_and_round_trip(factory: MessageFactory) -> None:
    report = _report()
    msg = occupancy_grid_message(report.cost, 0.03, (21.0, 0.2), factory, stamp_ns=5, frame_id="odom")
    info = msg.info
    assert (info.width, info.height) == (5, 3)  # width along x = the window's rows
    assert (info.origin.position.x, info.origin.position.y) == pytest.approx((21.0 - 0.075, 0.2 - 0.045))
    data = np.asarray(msg.data, np.int8).reshape(info.height, info.width)  # [y, x] from the origin
    assert data[2, 4] == 100  # grid_map [0, 0] = largest x, largest y = OccupancyGrid's far corner
    assert data[0, 0] == -1  # grid_map [4, 2] = smallest x and y = the origin cell
    assert data[1, 2] == 40
    cost, res, centre = cost_from_occupancy_grid(msg)
    np.testing.assert_array_equal(cost, report.cost)
    assert res == pytest.approx(0.03) and centre == pytest.approx((21.0, 0.2))


def test_bad_cost_grids_are_refused() -> None:
    factory = bag_factory()
    with pytest.raises(MessageError, match=r"-1\.\.100"):
        occupancy_grid_message(np.full((2, 2), 101, np.int16), 0.03, (0.0, 0.0), factory, stamp_ns=0)
    with pytest.raises(MessageError):
        occupancy_grid_message(np.zeros(4, np.int8), 0.03, (0.0, 0.0), factory, stamp_ns=0)
    msg = occupancy_grid_message(np.zeros((2, 2), np.int8), 0.03, (0.0, 0.0), factory, stamp_ns=0)
    msg.info.width = 3
    with pytest.raises(MessageError, match="width x height"):
        cost_from_occupancy_grid(msg)
