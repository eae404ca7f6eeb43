"""The preview-stream benchmark's reading of a recording: one stream, or which messages leave it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from benchmarks.bench_preview_stream import CONTROLLER_STATUS, summarise
from msg_bridge import BagWriter, bag_factory
from msg_bridge.preview import road_preview_message
from roadbev_core.config import GridSpec
from roadbev_core.preview import REFERENCE_CONTACT_PLANE, ContactPlane, PreviewProfiles, wheel_track_profiles

GRID = GridSpec()
PREVIEW = "/roadbev/preview"


def _profiles(speed: float | None, plane: bool) -> PreviewProfiles:
    elevation = np.zeros(GRID.shape, np.float32)
    sigma = np.full(GRID.shape, 0.005, np.float32)
    profiles = wheel_track_profiles(elevation, sigma, GRID, vehicle_speed=speed, reference_distance=2.8)
    if not plane:
        return profiles
    return replace(profiles, reference=REFERENCE_CONTACT_PLANE,
                   contact_plane=ContactPlane(0.0, 0.0, 0.0, 0.03, 0.017, 0.017, "body"))


def _record(path: Path, messages: list[tuple[PreviewProfiles, str]]) -> Path:
    factory = bag_factory()
    with BagWriter(path) as writer:
        writer.add_topic(PREVIEW, "roadbev_msgs/msg/RoadPreview")
        writer.add_topic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
        for i, (profiles, frame_id) in enumerate(messages):
            stamp = (i + 1) * 100_000_000
            writer.write(PREVIEW, road_preview_message(profiles, factory, stamp_ns=stamp, frame_id=frame_id), stamp)
        values = [factory.new("diagnostic_msgs/msg/KeyValue", key=k, value=v)
                  for k, v in (("received", str(len(messages))), ("refused", "1"))]
        status = factory.new("diagnostic_msgs/msg/DiagnosticStatus", level=0, name=CONTROLLER_STATUS,
                             message="", hardware_id="", values=values)
        header = road_preview_message(messages[0][0], factory, stamp_ns=1, frame_id="x").header
        writer.write("/diagnostics", factory.new("diagnostic_msgs/msg/DiagnosticArray", header=header,
                                                 status=[status]), 10**9)
    return path


def test_one_contact_plane_stream_with_speeds_counts_as_one_stream(tmp_path: Path) -> None:
    out = summarise(_record(tmp_path / "a.mcap", [(_profiles(10.0, True), "base_link")] * 3))
    assert out["previews"] == 3 and out["in_one_stream_pct"] == 100.0
    assert out["contact_plane_sources"] == {"body": 3}
    assert out["controller"] == {"received": "3", "refused": "1"}


@pytest.mark.parametrize("odd", ["per_frame", "no_speed"])
def test_a_message_out_of_the_stream_is_counted(tmp_path: Path, odd: str) -> None:
    other = (_profiles(None, False), "roadbev_road") if odd == "per_frame" else (_profiles(None, True), "base_link")
    out = summarise(_record(tmp_path / "b.mcap", [(_profiles(10.0, True), "base_link"), other]))
    assert out["in_one_stream_pct"] == 50.0
    if odd == "per_frame":
        assert out["frame_ids"] == {"base_link": 1, "roadbev_road": 1} and out["references"]["road"] == 1
    else:
        assert out["without_speed"] == 1 and out["without_times_of_arrival"] == 1
