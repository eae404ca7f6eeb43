"""The node's output publishers: elevation map, preview, far-field map (when on), fused map, TF and
(for viewers) point cloud and preview markers."""

from __future__ import annotations

from typing import Any

from grid_map_msgs.msg import GridMap
from roadbev_msgs.msg import RoadPreview
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from msg_bridge.pipeline_io import OutputMessages
from roadbev_core.config import FarFieldConfig, MapConfig, TopicsConfig

__all__ = ["OutputPublishers"]


class OutputPublishers:
    """The output publishers, fed from the worker thread."""

    def __init__(self, node: Any, qos: Any, topics: TopicsConfig, road_map: MapConfig,
                 far_field: FarFieldConfig | None = None) -> None:

        self._elevation = node.create_publisher(GridMap, topics.elevation, qos)
        self._preview = node.create_publisher(RoadPreview, topics.preview, qos)
        self._points = node.create_publisher(PointCloud2, topics.points, qos) if topics.points else None
        self._markers = (node.create_publisher(MarkerArray, topics.preview_markers, qos) if topics.preview_markers
                         else None)
        self._map = node.create_publisher(GridMap, road_map.topic, qos)
        # advertised only with the far field on (far_field.enabled is fixed after start)
        self._far = node.create_publisher(GridMap, far_field.topic, qos) if far_field and far_field.enabled else None
        self._tf = node.create_publisher(TFMessage, "/tf", qos)

    def publish_tf(self, msg: Any) -> None:
        """A ``tf2_msgs/TFMessage`` on ``/tf`` (e.g. ``odom`` -> ``base_link`` from the odometry)."""
        self._tf.publish(msg)

    def points_wanted(self) -> bool:
        """The point cloud is only built for a viewer that listens (it is the largest message)."""
        return self._points is not None and self._points.get_subscription_count() > 0

    def preview_markers_wanted(self) -> bool:
        """The preview's markers are only built for a viewer that listens."""
        return self._markers is not None and self._markers.get_subscription_count() > 0

    def publish(self, messages: OutputMessages) -> None:
        """Publish (the GridMap first: latency is measured on it; the TF before the messages in
        ``roadbev_road`` is not needed: tf2 buffers wait for it)."""
        self._elevation.publish(messages.elevation)
        if messages.tf is not None:
            self._tf.publish(messages.tf)
        self._preview.publish(messages.preview)
        if messages.elevation_far is not None and self._far is not None:
            self._far.publish(messages.elevation_far)
        if messages.road_map is not None:
            self._map.publish(messages.road_map)
        if messages.points is not None and self._points is not None:
            self._points.publish(messages.points)
        if messages.preview_markers is not None and self._markers is not None:
            self._markers.publish(messages.preview_markers)
