"""The pipeline's inputs from ROS messages and its outputs as ROS messages.

Used by the node (rclpy messages, :class:`msg_bridge.RclpyFactory`) and by the offline tools that
write what the node would publish (typestore messages), so both publish the same messages:

* :func:`camera_input`: a synchronised set (left, right, left info, right info) or (left, info)
  -> :class:`roadbev_core.pipeline.CameraInput`, images refused by size before they are decoded;
* :func:`speed_from_message`: ``nav_msgs/Odometry`` or ``geometry_msgs/TwistStamped`` -> speed;
* :func:`odometry_sample`: ``nav_msgs/Odometry`` -> :class:`roadbev_core.ego_motion.PlanarPose`;
* :func:`output_messages`: a :class:`roadbev_core.pipeline.PipelineOutput` -> GridMap,
  RoadPreview, (optionally) PointCloud2 and the preview's MarkerArray, the fused map (map on) and
  the TF ``<left camera frame> -> roadbev_road``, stamped with the left image's stamp.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple, cast

from msg_bridge._common import MessageError, MessageFactory, field, stamp_from_header
from msg_bridge.camera_info import stereo_camera_from_camera_info
from msg_bridge.grid_map import elevation_grid_map, fused_map_message
from msg_bridge.image import compressed_to_rgb, image_to_rgb
from msg_bridge.markers import preview_markers
from msg_bridge.point_cloud import elevation_point_cloud
from msg_bridge.preview import road_preview_message
from msg_bridge.tf import StaticTransform, odometry_pose, tf_message
from roadbev_core.config import ConfigError, RoadbevConfig, check_image_size
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.geometry import road_frame_in_camera
from roadbev_core.pipeline import CameraInput, PipelineOutput
from roadbev_core.preview import REFERENCE_CONTACT_PLANE

__all__ = [
    "OutputMessages",
    "camera_input",
    "odometry_sample",
    "output_messages",
    "speed_from_message",
    "speed_message_type",
]



def camera_input(msgs: Sequence[Any], image_transport: str) -> CameraInput:
    """The camera set of synchronised messages: (left, right, left info, right info) or (left, info).

    Raises:
        MessageError: a malformed image or CameraInfo, or a raw image over the size limit.
    """
    if len(msgs) == 4:
        left_msg, right_msg, left_info, right_info = msgs
    else:
        (left_msg, left_info), right_msg, right_info = msgs, None, None
    if image_transport == "compressed":
        to_rgb = compressed_to_rgb
    else:
        for which, msg in (("left", left_msg), ("right", right_msg)):
            if msg is not None:  # refused by its header before any pixel is touched
                try:
                    check_image_size(int(field(msg, "width")), int(field(msg, "height")), f"{which} image")
                except ConfigError as exc:
                    raise MessageError(str(exc)) from None
        to_rgb = image_to_rgb
    left = to_rgb(left_msg)
    right = to_rgb(right_msg) if right_msg is not None else None
    camera = stereo_camera_from_camera_info(left_info, right_info)
    return CameraInput(left, right, camera, stamp_from_header(left_msg))


def speed_message_type(kind: str) -> type:
    """The rclpy message class of a speed topic (``odometry`` or ``twist_stamped``)."""
    if kind == "odometry":
        # lazy: msg_bridge loads no ROS message package at import (bags use the typestore)
        from nav_msgs.msg import Odometry

        return cast("type", Odometry)
    # lazy: msg_bridge loads no ROS message package at import (bags use the typestore)
    from geometry_msgs.msg import TwistStamped

    return cast("type", TwistStamped)


def speed_from_message(msg: Any) -> tuple[int, float]:
    """(stamp ns, speed m/s, negative when reversing) of an Odometry or a TwistStamped.

    Raises:
        MessageError: a non-finite velocity or a missing field.
    """
    twist = field(field(msg, "twist"), "twist") if hasattr(msg, "pose") else field(msg, "twist")
    linear = field(twist, "linear")
    vx, vy = float(field(linear, "x")), float(field(linear, "y"))
    speed = math.hypot(vx, vy)
    if not math.isfinite(speed):
        raise MessageError(f"non-finite speed {vx}, {vy}")
    return stamp_from_header(msg), math.copysign(speed, vx or 1.0)


def odometry_sample(msg: Any) -> PlanarPose:
    """The planar pose and twist of a ``nav_msgs/Odometry`` (``base_link`` in ``odom``).

    Raises:
        MessageError: non-finite values or a non-unit orientation.
    """
    pose = odometry_pose(msg)
    twist = field(field(msg, "twist"), "twist")
    vx = float(field(field(twist, "linear"), "x"))
    wz = float(field(field(twist, "angular"), "z"))
    if not (math.isfinite(vx) and math.isfinite(wz)):
        raise MessageError(f"Odometry at {pose.stamp_ns} ns has a non-finite twist")
    return PlanarPose(pose.stamp_ns, pose.x, pose.y, pose.yaw, vx, wz)


class OutputMessages(NamedTuple):
    """What the node publishes for one frame."""

    elevation: Any  # grid_map_msgs/GridMap
    preview: Any  # roadbev_msgs/RoadPreview
    points: Any | None  # sensor_msgs/PointCloud2 (only when asked for)
    road_map: Any | None = None  # grid_map_msgs/GridMap of the fused map (map on)
    tf: Any | None = None  # tf2_msgs/TFMessage <left camera frame> -> roadbev_road (with a camera frame)
    preview_markers: Any | None = None  # visualization_msgs/MarkerArray of the preview (only when asked for)
    elevation_far: Any | None = None  # grid_map_msgs/GridMap of the far-field grid (far_field.enabled)


def output_messages(
    output: PipelineOutput, config: RoadbevConfig, factory: MessageFactory, *, with_points: bool,
    with_preview_markers: bool = False, camera_frame: str | None = None,
) -> OutputMessages:
    """The GridMap, RoadPreview, (optionally) PointCloud2 and the preview's MarkerArray, the fused
    map, the TF and the far-field GridMap (same layers, on ``config.far_grid``) of one output.

    Args:
        with_points, with_preview_markers: build the viewers' PointCloud2, MarkerArray.
        camera_frame: the left image's ``header.frame_id``: the parent of the TF to
            ``roadbev_road`` (None: no TF).

    Raises:
        MessageError: an output without a preview (a pipeline whose config was not validated).
    """
    if output.preview is None:
        raise MessageError("the pipeline output has no preview: its wheel tracks do not fit the grid")
    grid, frame_id, stamp = config.grid, config.topics.frame_id, output.stamp_ns
    estimate = output.estimate
    elevation = elevation_grid_map(
        estimate.elevation, estimate.uncertainty, grid, factory, stamp_ns=stamp, frame_id=frame_id
    )
    preview_frame = config.topics.base_frame if output.preview.reference == REFERENCE_CONTACT_PLANE else frame_id
    preview = road_preview_message(output.preview, factory, stamp_ns=stamp, frame_id=preview_frame)
    points = None
    if with_points:
        points = elevation_point_cloud(
            estimate.elevation, estimate.uncertainty, grid, factory, stamp_ns=stamp, frame_id=frame_id
        )
    markers = None
    if with_preview_markers:
        markers = preview_markers(output.preview, factory, stamp_ns=stamp, frame_id=preview_frame,
                                  sigma_max_m=config.preview.markers_sigma_max_m)
    road_map = None if output.map is None else fused_map_message(output.map, factory, frame_id=config.map.frame)
    tf = None
    if camera_frame:
        R, t = road_frame_in_camera(output.frame.attitude, grid.base_height)
        tf = tf_message([StaticTransform(camera_frame, frame_id, R, t)], factory, stamp_ns=stamp)
    elevation_far = None
    if output.far is not None:
        far_grid = config.far_field.grid(grid)
        elevation_far = elevation_grid_map(output.far.elevation, output.far.uncertainty, far_grid, factory,
                                           stamp_ns=stamp, frame_id=frame_id)
    return OutputMessages(elevation, preview, points, road_map, tf, markers, elevation_far)
