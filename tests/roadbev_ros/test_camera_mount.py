"""The camera mount from /tf_static without ROS: joined through a chain, applied once per change."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import pytest

from msg_bridge import bag_factory
from msg_bridge.tf import StaticTransform, tf_message
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import rotation_from_rpy
from roadbev_ros.camera_mount import CameraMount

FACTORY = bag_factory()
OPTICAL = rotation_from_rpy(-math.pi / 2, 0.0, -math.pi / 2)  # optical axes in camera_link's


class Taker:
    def __init__(self) -> None:
        self.mounts: list[tuple[np.ndarray, np.ndarray]] = []
        self.refuse = False

    def set_camera_mount(self, position: Iterable[float], R_base_optical: np.ndarray) -> None:
        if self.refuse:
            raise RoadbevError("not a rotation")
        self.mounts.append((np.asarray(list(position)), R_base_optical))


def mount() -> tuple[CameraMount, Taker, list[str], list[tuple[str, str]]]:
    taker = Taker()
    info: list[str] = []
    problems: list[tuple[str, str]] = []
    camera = CameraMount(taker, "base_link", info.append, lambda kind, reason: problems.append((kind, reason)))
    return camera, taker, info, problems


def test_the_mount_is_applied_once_the_frames_are_joined_and_again_only_when_it_changes() -> None:
    camera, taker, info, problems = mount()
    camera.add_static(tf_message([StaticTransform("base_link", "camera_link", np.eye(3), np.array([1.6, 0.0, 1.1]))],
                                 FACTORY))
    assert taker.mounts == []  # no left image yet: its frame is not known
    camera.see_frame("")  # an empty frame_id says nothing
    camera.see_frame("left_optical")
    assert taker.mounts == [] and camera.camera_frame == "left_optical"  # not joined yet
    optical = StaticTransform("camera_link", "left_optical", OPTICAL, np.array([0.0, 0.06, 0.0]))
    camera.add_static(tf_message([optical], FACTORY))  # another broadcaster's message: both kept
    assert len(taker.mounts) == 1
    position, rotation = taker.mounts[0]
    assert position == pytest.approx([1.6, 0.06, 1.1]) and rotation == pytest.approx(OPTICAL)
    assert info == ["camera mount from /tf_static: base_link -> left_optical at [1.6, 0.06, 1.1] m"]
    camera.add_static(tf_message([optical], FACTORY))  # the same again: nothing new
    camera.see_frame("left_optical")
    assert len(taker.mounts) == 1
    moved = StaticTransform("base_link", "camera_link", np.eye(3), np.array([1.7, 0.0, 1.1]))
    camera.add_static(tf_message([moved], FACTORY))  # a later transform to a child replaces the earlier one
    assert len(taker.mounts) == 2 and taker.mounts[1][0] == pytest.approx([1.7, 0.06, 1.1])
    assert problems == []


def test_a_malformed_transform_or_a_refused_mount_is_reported() -> None:
    camera, taker, _, problems = mount()
    camera.see_frame("left_optical")
    bad = tf_message([StaticTransform("base_link", "left_optical", np.eye(3), np.zeros(3))], FACTORY)
    bad.transforms[0].child_frame_id = ""
    camera.add_static(bad)
    assert [kind for kind, _ in problems] == ["bad tf"] and "lacks a parent or child frame" in problems[0][1]
    taker.refuse = True
    camera.add_static(tf_message([StaticTransform("base_link", "left_optical", np.eye(3), np.zeros(3))], FACTORY))
    assert problems[-1] == ("bad tf", "base_link -> left_optical: not a rotation") and taker.mounts == []
    taker.refuse = False
    camera.see_frame("right_optical")
    camera.see_frame("left_optical")  # the refused mount was not taken: it is tried again
    assert len(taker.mounts) == 1
