"""The online controller: the same forces as the pure simulation on a straight road, refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_core.preview import PreviewProfiles, TrackProfile
from roadbev_core.ride import OnlinePreviewController, PreviewLqr, RideError
from roadbev_lab.evaluation.arrival import ArrivalSettings
from roadbev_lab.ride import RideSettings, perfect_previews, preview_feedforward, wheel_road

from ._roads import T0, S, bump_map, straight

CTL = PreviewLqr(dt=0.005)
SETTINGS = RideSettings(controller=CTL, latency_s=0.1, arrival=ArrivalSettings(base_height=1.10))


def test_online_forces_match_the_pure_simulation() -> None:
    speed = 10.0
    truth, road_map = straight(speed, 5.0), bump_map(0.05, at=25.0)
    stamps = [T0 + int(round(t * S)) for t in np.arange(0.05, 4.0, 0.1)]
    msgs = [replace(m, profiles=replace(m.profiles, vehicle_speed=speed))
            for m in perfect_previews(truth, road_map, stamps, GridSpec(), SETTINGS)]
    road = wheel_road(truth, road_map, SETTINGS, "front_left", T0, T0 + 4 * S)
    ff_batch, _ = preview_feedforward(msgs, road, truth, SETTINGS)
    online = OnlinePreviewController(CTL)
    ff_online = np.zeros(road.stamp_ns.size)
    pending = list(msgs)
    for j, now in enumerate(road.stamp_ns.tolist()):
        while pending and pending[0].stamp_ns + SETTINGS.latency_s * S <= now:
            m = pending.pop(0)
            online.receive(m.stamp_ns, m.profiles, wheel_x=2.8 - 1.6)  # the front axle ahead of the camera
        ff_online[j] = online.step(now)["front_left"].feedforward_n
    assert np.abs(ff_batch).max() > 100.0
    assert np.abs(ff_online - ff_batch).max() < 0.02 * np.abs(ff_batch).max()


def test_model_rides_the_previewed_road_and_reports_coverage() -> None:
    n = 300
    elevation = np.zeros(n, np.float32)
    elevation[100:120] = 0.04  # a 4 cm plateau 3-3.6 m ahead of the profile's start
    track = TrackProfile("left", 0.8, 0.2, elevation, np.zeros(n, np.float32))
    right = replace(track, name="right", lateral_offset=-0.8)
    profiles = PreviewProfiles(0.0, 0.03, (track, right), vehicle_speed=10.0)
    online = OnlinePreviewController(CTL)
    assert not online.step(T0)["front_left"].covered  # nothing held: no preview, the model at rest
    online.receive(T0, profiles, wheel_x=0.0)
    first = online.step(T0)["front_left"]
    assert first.covered and first.preview_m == pytest.approx(9.0, abs=0.1)  # to the profile's end (300 x 3 cm)
    forces = [online.step(T0 + int(k * CTL.dt * S))["front_left"] for k in range(1, 100)]
    assert max(abs(c.feedforward_n) for c in forces) > 50.0  # it prepares for the plateau
    # a reference plane tilted by 1 % along x adds its slope x speed to the road velocity
    tilted = OnlinePreviewController(CTL)
    tilted.receive(T0, profiles, wheel_x=0.0, slope_x=0.01)
    flat = OnlinePreviewController(CTL)
    flat.receive(T0, profiles, wheel_x=0.0)
    assert tilted.road_velocity_ahead("front_left", T0)[:50] == pytest.approx(
        flat.road_velocity_ahead("front_left", T0)[:50] + 0.01 * 10.0, abs=1e-3)
    # past the profile's end the wheel has no preview
    assert not online.step(T0 + int(1.0 * S))["front_left"].covered
    online.reset()
    assert not online.held and not online.state["front_left"].any()


def test_refusals() -> None:
    track = TrackProfile("left", 0.8, 0.2, np.zeros(10, np.float32), np.zeros(10, np.float32))
    both = (track, replace(track, name="right"))
    online = OnlinePreviewController(CTL)
    with pytest.raises(RideError, match="vehicle_speed"):
        online.receive(T0, PreviewProfiles(0.0, 0.03, both), 1.2)
    with pytest.raises(RideError, match="front_right"):
        online.receive(T0, PreviewProfiles(0.0, 0.03, (track,), vehicle_speed=5.0), 1.2)
    online.receive(T0, PreviewProfiles(0.0, 0.03, both, vehicle_speed=5.0), 1.2)
    with pytest.raises(RideError, match="back in time"):
        online.receive(T0 - 1, PreviewProfiles(0.0, 0.03, both, vehicle_speed=5.0), 1.2)
    with pytest.raises(RideError):
        OnlinePreviewController(CTL, wheels=("rear_left",))
