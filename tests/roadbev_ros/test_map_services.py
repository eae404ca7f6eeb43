"""The fused-map services without ROS: clear, save, sub-map, and why there is no map."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from msg_bridge import bag_factory
from msg_bridge.bag import read_messages
from msg_bridge.grid_map import decode_grid_map
from roadbev_core.config import RoadbevConfig
from roadbev_core.fusion import MapWindow
from roadbev_ros import map_services
from roadbev_ros.map_services import MapServices

STAMP_NS = 1_700_000_000 * 1_000_000_000


def window() -> MapWindow:
    elevation = np.arange(20 * 10, dtype=np.float32).reshape(20, 10) * 1e-3
    ones = np.ones_like(elevation)
    return MapWindow(elevation, ones * 0.01, ones, ones * 0.1, 0.1, (5.0, 0.0), STAMP_NS)


class Holder:
    """The pipeline's fused map."""

    def __init__(self, last_map: MapWindow | None = None, map_active: bool = False) -> None:
        self.last_map = last_map
        self.map_active = map_active

    def clear_map(self) -> None:
        self.last_map = None


class Services:
    def __init__(self, params: dict[str, Any] | None = None, last_map: MapWindow | None = None) -> None:
        self.config = RoadbevConfig.from_params(params or {})
        self.pipeline = Holder(last_map)
        self.motion_samples = 0
        self.info: list[str] = []
        self.warnings: list[str] = []
        self.problems: list[tuple[str, str]] = []
        self.services = MapServices(self.pipeline, lambda: self.config, lambda: self.motion_samples,
                                    lambda topic: "/car" + topic, lambda: 12.5, bag_factory(), self.info.append,
                                    self.warnings.append, lambda kind, reason: self.problems.append((kind, reason)))


def trigger() -> SimpleNamespace:
    return SimpleNamespace(success=None, message="")


def submap_request(frame_id: str = "odom", position: tuple[float, float] = (5.0, 0.0),
                   length: tuple[float, float] = (0.0, 0.0), layers: tuple[str, ...] = ()) -> SimpleNamespace:
    return SimpleNamespace(frame_id=frame_id, position_x=position[0], position_y=position[1], length_x=length[0],
                           length_y=length[1], layers=list(layers))


def submap_response() -> SimpleNamespace:
    return SimpleNamespace(map=SimpleNamespace(header=SimpleNamespace(frame_id=""), layers=[]))


@pytest.mark.parametrize(("params", "samples", "why"), [
    ({"map.enabled": False}, 0, "map.enabled is false"),
    ({}, 0, "no odometry on /car/odom received yet"),
    ({"speed_topic": "/speed"}, 0, "no odometry on /car/odom or speed on /car/speed received yet"),
    ({"odom_topic": ""}, 0, "neither odom_topic nor speed_topic is set"),
    ({"odom_topic": "", "odom_from_tf": True, "map_frame": "world"}, 0,
     "no odometry on /tf (world -> base_link) received yet"),
    ({}, 3, "no frame has been fused yet (frames need odometry around their stamps, map.odom_max_age_s)"),
])
def test_why_there_is_no_map_names_the_first_cause(params: dict[str, Any], samples: int, why: str) -> None:
    s = Services(params)
    s.motion_samples = samples
    assert s.services.why_no_map() == why
    response = s.services.save_map(None, trigger())
    assert (response.success, response.message) == (False, f"no fused map to save: {why}")
    assert s.problems == []  # nothing to save is not a problem of the node


def test_the_map_state_says_fusing_or_why_not() -> None:
    s = Services({"map.enabled": False})
    assert s.services.state() == "off (map.enabled false)"
    s.config = RoadbevConfig.from_params({})
    assert s.services.state() == "waiting: no odometry on /car/odom received yet"
    s.pipeline.map_active = True
    assert s.services.state() == "fusing"


def test_clear_map_forgets_the_map_and_says_when() -> None:
    s = Services(last_map=window())
    s.motion_samples = 5
    response = s.services.clear_map(None, trigger())
    assert (response.success, response.message) == (True, "fused map cleared")
    assert s.pipeline.last_map is None and s.info == ["fused map cleared (~/clear_map)"]
    assert s.services.why_no_map() == ("the map was cleared by ~/clear_map at 12.500 s and no frame has been "
                                       "fused since")


def test_save_map_writes_one_grid_map_to_an_absolute_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    s = Services({"map.save_dir": "maps"}, last_map=window())
    response = s.services.save_map(None, trigger())
    assert response.success, response.message
    path = tmp_path / "maps" / f"roadbev_map_{STAMP_NS}.mcap"
    assert response.message == str(path) and s.info == [f"fused map saved to {path}"]
    (item,) = read_messages(path, ["/roadbev/map"])
    decoded = decode_grid_map(item.msg)
    assert decoded.frame_id == "odom"
    np.testing.assert_array_equal(decoded.layers["elevation"], window().elevation)
    again = s.services.save_map(None, trigger())  # the file exists: refused, reported
    assert not again.success and again.message.startswith(f"cannot save the map to {path}: ")
    assert s.problems == [("save map", again.message)]


def process_file(file_path: str, topic_name: str = "") -> SimpleNamespace:
    return SimpleNamespace(file_path=file_path, topic_name=topic_name)


def test_save_map_to_writes_where_asked_relative_paths_in_save_dir(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    s = Services({"map.save_dir": "maps"}, last_map=window())
    response = s.services.save_map_to(process_file("drive_1"), SimpleNamespace(success=None))
    assert response.success is True
    path = tmp_path / "maps" / "drive_1.mcap"  # relative: in map.save_dir (created), .mcap added
    assert s.info == [f"fused map saved to {path} (~/save_map_to, topic /roadbev/map)"]
    (item,) = read_messages(path, ["/roadbev/map"])
    np.testing.assert_array_equal(decode_grid_map(item.msg).layers["elevation"], window().elevation)
    other = tmp_path / "elsewhere" / "road.mcap"
    other.parent.mkdir()
    response = s.services.save_map_to(process_file(str(other), "surface"), SimpleNamespace(success=None))
    assert response.success is True and [i.topic for i in read_messages(other)] == ["/surface"]
    assert s.problems == [] and s.warnings == []


@pytest.mark.parametrize(("file_path", "cause"), [
    ("", "file_path is empty (~/save_map writes into map.save_dir under a name of its own)"),
    ("taken.mcap", "{dir}/taken.mcap exists: it is not overwritten (remove it, or name another file)"),
    ("taken", "{dir}/taken.mcap exists: it is not overwritten (remove it, or name another file)"),
    ("sub", "{dir}/sub.mcap is a folder: name a file in it"),
    ("missing/map.mcap", "the folder {dir}/missing does not exist (only map.save_dir is created)"),
    ("taken.mcap/map.mcap", "{dir}/taken.mcap is not a folder"),
])
def test_save_map_to_refuses_with_the_true_cause_and_never_overwrites(tmp_path: Path, file_path: str,
                                                                       cause: str) -> None:
    s = Services({"map.save_dir": str(tmp_path)}, last_map=window())
    (tmp_path / "taken.mcap").write_bytes(b"keep me")
    (tmp_path / "sub.mcap").mkdir()
    response = s.services.save_map_to(process_file(file_path), SimpleNamespace(success=None))
    assert response.success is False
    assert s.warnings == [f"~/save_map_to {file_path!r} refused: {cause.format(dir=tmp_path)}"]
    assert (tmp_path / "taken.mcap").read_bytes() == b"keep me" and s.problems == []


def test_save_map_to_without_a_map_or_a_writable_folder_says_why(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    s = Services({"map.save_dir": str(tmp_path), "map.enabled": False})
    assert s.services.save_map_to(process_file("a"), SimpleNamespace(success=None)).success is False
    assert s.warnings == ["~/save_map_to: no fused map to save: map.enabled is false"]
    s = Services({"map.save_dir": str(tmp_path)}, last_map=window())
    s.services.clear_map(None, trigger())
    s.services.save_map_to(process_file("a"), SimpleNamespace(success=None))
    assert s.warnings[-1].startswith("~/save_map_to: no fused map to save: the map was cleared by ~/clear_map")
    s.pipeline.last_map = window()
    monkeypatch.setattr(map_services.os, "access", lambda path, mode: False)  # root may write anywhere
    assert s.services.save_map_to(process_file("a"), SimpleNamespace(success=None)).success is False
    assert s.warnings[-1] == f"~/save_map_to 'a' refused: the folder {tmp_path} is not writable"


def test_get_submap_serves_the_cells_and_layers_asked_for() -> None:
    s = Services(last_map=window())
    response = s.services.get_submap(submap_request(length=(0.6, 0.3), layers=("elevation", "age", "slope")),
                                     submap_response())
    sub = decode_grid_map(response.map)
    assert sub.frame_id == "odom" and list(sub.layers) == ["elevation", "age"]
    assert sub.layers["elevation"].shape == (6, 4)  # centres within ±0.3 m (x), ±0.15 m (y) of (5, 0)
    assert list(response.map.basic_layers) == ["elevation"]
    assert s.warnings == ["~/get_submap: no layer slope (the map has elevation, uncertainty, observations, age)"]
    whole = decode_grid_map(s.services.get_submap(submap_request(frame_id="/odom"), submap_response()).map)
    assert whole.layers["elevation"].shape == (20, 10) and len(whole.layers) == 4


@pytest.mark.parametrize(("request_", "has_map", "reason"), [
    (submap_request(), False, "no fused map: no odometry on /car/odom received yet"),
    (submap_request(frame_id="base_link"), True, "frame 'base_link': the map is served in its own frame, 'odom'"),
    (submap_request(position=(50.0, 0.0), length=(1.0, 1.0)), True,
     "no cell of the map within 1 x 1 m around (50, 0) in 'odom'"),
])
def test_get_submap_answers_a_map_without_layers_and_logs_why(request_: SimpleNamespace, has_map: bool,
                                                              reason: str) -> None:
    s = Services(last_map=window() if has_map else None)
    response = s.services.get_submap(request_, submap_response())
    assert response.map.layers == [] and response.map.header.frame_id == "odom"
    assert s.warnings == [f"~/get_submap: {reason}"] and s.problems == []
