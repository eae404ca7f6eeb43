"""The camera mount from TF without ROS: joined through a chain, looked up at the frame's stamp
through /tf links, applied once per change, and named when the transform it needs is missing."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import pytest

from msg_bridge.tf import StaticTransform
from msg_bridge.tf_buffer import TransformBuffer
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import rotation_from_rpy
from roadbev_ros.camera_mount import CameraMount

S = 1_000_000_000
T0 = 1_700_000_000 * S
OPTICAL = rotation_from_rpy(-math.pi / 2, 0.0, -math.pi / 2)  # optical axes in camera_link's


class Taker:
    def __init__(self) -> None:
        self.mounts: list[tuple[np.ndarray, np.ndarray]] = []
        self.refuse = False

    def set_camera_mount(self, position: Iterable[float], R_base_optical: np.ndarray) -> None:
        if self.refuse:
            raise RoadbevError("not a rotation")
        self.mounts.append((np.asarray(list(position)), R_base_optical))


def mount(tolerance_s: float = 0.0) -> tuple[CameraMount, TransformBuffer, Taker, list[str], list[tuple[str, str]]]:
    taker, buffer = Taker(), TransformBuffer(tolerance_s=tolerance_s)
    info: list[str] = []
    problems: list[tuple[str, str]] = []
    camera = CameraMount(taker, buffer, "base_link", lambda: (1.6, 0.0, 1.1), info.append,
                         lambda kind, reason: problems.append((kind, reason)))
    return camera, buffer, taker, info, problems


def test_a_static_chain_is_applied_once_the_frames_are_joined_and_again_only_when_it_changes() -> None:
    camera, buffer, taker, info, problems = mount()
    buffer.add(StaticTransform("base_link", "camera_link", np.eye(3), np.array([1.6, 0.0, 1.1])), static=True)
    camera.transforms_changed()
    assert taker.mounts == []  # no left image yet: its frame is not known
    assert camera.state() == "vehicle.camera_position_m [1.6, 0.0, 1.1] (no image yet)"
    camera.see_frame("", T0)  # an empty frame_id says nothing
    camera.see_frame("left_optical", T0)
    assert taker.mounts == [] and camera.camera_frame == "left_optical"  # not joined yet
    assert problems == []  # nothing places left_optical: vehicle.camera_position_m is meant
    assert camera.state() == "vehicle.camera_position_m [1.6, 0.0, 1.1] (no TF joins base_link and left_optical)"
    optical = StaticTransform("camera_link", "left_optical", OPTICAL, np.array([0.0, 0.06, 0.0]))
    buffer.add(optical, static=True)  # another broadcaster's transform: both kept
    camera.transforms_changed()  # applied at once, before the next frame
    assert len(taker.mounts) == 1
    position, rotation = taker.mounts[0]
    assert position == pytest.approx([1.6, 0.06, 1.1]) and rotation == pytest.approx(OPTICAL)
    assert info == ["camera mount from /tf_static: base_link -> left_optical at [1.6, 0.06, 1.1] m"]
    assert camera.state() == "/tf_static base_link -> left_optical at [1.6, 0.06, 1.1] m"
    camera.see_frame("left_optical", T0 + S)  # the same again: nothing new
    assert len(taker.mounts) == 1
    buffer.add(StaticTransform("base_link", "camera_link", np.eye(3), np.array([1.7, 0.0, 1.1])), static=True)
    camera.transforms_changed()  # a later transform to a child replaces the earlier one
    assert len(taker.mounts) == 2 and taker.mounts[1][0] == pytest.approx([1.7, 0.06, 1.1])
    assert problems == []


def test_a_chain_through_tf_is_looked_up_at_each_frames_stamp() -> None:
    camera, buffer, taker, info, problems = mount(tolerance_s=0.02)
    buffer.add(StaticTransform("base_link", "bracket", np.eye(3), np.array([1.6, 0.0, 1.0])), static=True)
    buffer.add(StaticTransform("camera_link", "left_optical", OPTICAL, np.zeros(3)), static=True)
    for k, z in enumerate((0.10, 0.12, 0.14)):  # the bracket raises the camera 2 cm per 100 ms
        buffer.add(StaticTransform("bracket", "camera_link", np.eye(3), np.array([0.0, 0.0, z])), T0 + k * S // 10)
    camera.see_frame("left_optical", T0)
    camera.transforms_changed()  # /tf_static news: a chain through /tf waits for a frame's stamp
    camera.see_frame("left_optical", T0 + S // 20)  # between two samples: interpolated
    camera.see_frame("left_optical", T0 + S // 5 + S // 100)  # 10 ms past the newest: held (tolerance)
    assert [round(float(p[2]), 6) for p, _ in taker.mounts] == [1.10, 1.11, 1.14]
    assert info == ["camera mount from /tf: base_link -> left_optical at [1.6, 0.0, 1.1] m"]  # logged once
    assert problems == []
    camera.see_frame("left_optical", T0 + S)  # the bracket's /tf stopped 0.8 s ago
    ((kind, reason),) = problems
    assert kind == "tf missing"
    assert reason.startswith("no transform base_link -> left_optical for the camera mount: Lookup would require "
                             "extrapolation into the future. Requested time 1700000001.000000 but the latest data is "
                             "at time 1700000000.200000")
    assert reason.endswith("the frame goes on with the mount last taken from /tf ([1.6, 0.0, 1.14] m)")
    assert len(taker.mounts) == 3  # kept


def test_a_transform_placing_the_camera_but_not_joined_to_the_body_is_named() -> None:
    camera, buffer, taker, _, problems = mount()
    buffer.add(StaticTransform("camera_link", "left_optical", OPTICAL, np.zeros(3)), static=True)
    camera.see_frame("left_optical", T0)
    buffer.add(StaticTransform("base_link", "imu_link", np.eye(3), np.zeros(3)), static=True)
    camera.see_frame("left_optical", T0)
    assert [kind for kind, _ in problems] == ["tf missing", "tf missing"]
    assert '"base_link" passed to lookupTransform argument target_frame does not exist' in problems[0][1]
    reason = problems[1][1]
    assert "Could not find a connection between 'base_link' and 'left_optical'" in reason
    assert reason.endswith("the frame goes on with vehicle.camera_position_m [1.6, 0.0, 1.1]")
    assert taker.mounts == []


def test_a_refused_mount_is_reported_and_tried_again() -> None:
    camera, buffer, taker, _, problems = mount()
    camera.see_frame("left_optical", T0)
    taker.refuse = True
    buffer.add(StaticTransform("base_link", "left_optical", np.eye(3), np.zeros(3)), static=True)
    camera.transforms_changed()
    assert problems == [("bad tf", "base_link -> left_optical: not a rotation")] and taker.mounts == []
    taker.refuse = False
    camera.see_frame("right_optical", T0)  # a frame nothing places: no mount, nothing to report
    camera.see_frame("left_optical", T0)  # the refused mount was not taken: it is tried again
    assert len(taker.mounts) == 1 and len(problems) == 1
