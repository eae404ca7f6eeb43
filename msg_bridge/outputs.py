"""A bag of the node's outputs (``roadbev eval --out``): exactly the messages the node publishes.

:class:`OutputBag` writes, per :class:`roadbev_core.pipeline.PipelineOutput`, the
``grid_map_msgs/GridMap`` and ``roadbev_msgs/RoadPreview`` (and, when they exist, the far-field
GridMap, the fused map and the ``/tf`` to ``roadbev_road``) that
:func:`msg_bridge.pipeline_io.output_messages` builds (the node's own builder, here with a
typestore factory), on the node's topics, stamped with the left image's stamp and framed as the
node frames them, so that any tool can score them.
"""

from __future__ import annotations

import os
from types import TracebackType

from msg_bridge._common import TypestoreFactory
from msg_bridge.bag import BagWriter, typestore
from msg_bridge.grid_map import fused_map_message
from msg_bridge.pipeline_io import output_messages
from roadbev_core.config import RoadbevConfig
from roadbev_core.fusion import MapWindow
from roadbev_core.pipeline import PipelineOutput


def save_map_bag(path: str | os.PathLike[str], window: MapWindow, config: RoadbevConfig, *,
                 topic: str | None = None) -> None:
    """Write one fused map (``~/save_map``) as an MCAP bag: one ``grid_map_msgs/GridMap`` on
    ``topic`` (default ``map_topic``) in ``map_frame``, as the node publishes it.

    Raises:
        BagError: the path exists or cannot be written.
    """
    topic = topic or config.map.topic
    writer = BagWriter(path)
    writer.open()
    try:
        writer.add_topic(topic, "grid_map_msgs/msg/GridMap", latched=True)
        factory = TypestoreFactory(typestore())
        writer.write(topic, fused_map_message(window, factory, frame_id=config.map.frame), window.stamp_ns)
    except BaseException:
        writer.abort()
        raise
    writer.close()

__all__ = ["OutputBag", "save_map_bag"]


class OutputBag:
    """An MCAP bag of the node's outputs: ``write(output)`` per frame.

    Args:
        path: ``OUT.mcap`` (or a rosbag2 directory); must not exist.
        config: the pipeline's config (topics, frame, grid).
    """

    def __init__(self, path: str | os.PathLike[str], config: RoadbevConfig, *, camera_frame: str | None = None
                 ) -> None:
        self.config = config
        self.camera_frame = camera_frame
        self._factory = TypestoreFactory(typestore())
        self._writer = BagWriter(path)
        self._writer.open()
        self._writer.add_topic(config.topics.elevation, "grid_map_msgs/msg/GridMap")
        self._writer.add_topic(config.topics.preview, "roadbev_msgs/msg/RoadPreview")
        self._optional: set[str] = set()  # the far field, the fused map and /tf: added with their first message

    @property
    def counts(self) -> dict[str, int]:
        return dict(self._writer.counts)

    def write(self, output: PipelineOutput) -> None:
        """The frame's GridMap and RoadPreview, logged at the image stamp."""
        messages = output_messages(output, self.config, self._factory, with_points=False,
                                   camera_frame=self.camera_frame)
        self._writer.write(self.config.topics.elevation, messages.elevation, output.stamp_ns)
        self._writer.write(self.config.topics.preview, messages.preview, output.stamp_ns)
        for topic, kind, msg in ((self.config.far_field.topic, "grid_map_msgs/msg/GridMap", messages.elevation_far),
                                 (self.config.map.topic, "grid_map_msgs/msg/GridMap", messages.road_map),
                                 ("/tf", "tf2_msgs/msg/TFMessage", messages.tf)):
            if msg is None:
                continue
            if topic not in self._optional:
                self._writer.add_topic(topic, kind)
                self._optional.add(topic)
            self._writer.write(topic, msg, output.stamp_ns)

    def close(self) -> None:
        self._writer.close()

    def abort(self) -> None:
        self._writer.abort()

    def __enter__(self) -> OutputBag:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
