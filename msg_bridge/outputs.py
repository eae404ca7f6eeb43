"""The node's output messages for one estimate, and a bag of them (``roadbev eval --out``).

:func:`output_messages` builds the ``grid_map_msgs/GridMap`` (layers ``elevation`` and
``uncertainty``), the ``roadbev_msgs/RoadPreview`` and optionally the ``sensor_msgs/PointCloud2``
of an estimate; the node publishes exactly these (with an rclpy factory), and
:class:`OutputBag` writes them with a typestore factory into an MCAP bag, stamped with the left
image's stamp and framed as the node frames them, so that any tool can score them.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from types import TracebackType
from typing import Any, NamedTuple

from msg_bridge._common import MessageFactory, TypestoreFactory
from msg_bridge.bag import BagWriter, typestore
from msg_bridge.grid_map import ROAD_FRAME, elevation_grid_map
from msg_bridge.point_cloud import elevation_point_cloud
from msg_bridge.preview import road_preview_message
from roadbev_core.config import GridSpec
from roadbev_core.frame import Estimate
from roadbev_core.preview import wheel_track_profiles

__all__ = ["OutputBag", "OutputMessages", "PreviewSettings", "output_messages"]

ELEVATION_TOPIC = "/roadbev/elevation"
PREVIEW_TOPIC = "/roadbev/preview"


class PreviewSettings(NamedTuple):
    """The node's ``preview.*`` parameters (defaults as in ``roadbev_ros.params``)."""

    track_offsets_m: Sequence[float] = (0.8, -0.8)
    tyre_width_m: float = 0.2
    spacing_m: float = 0.03
    reference_distance_m: float = 0.0

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> PreviewSettings:
        """From node parameters (``preview.track_offsets_m``...), defaults where absent."""
        d = cls()
        return cls(
            tuple(float(v) for v in params.get("preview.track_offsets_m", d.track_offsets_m)),
            float(params.get("preview.tyre_width_m", d.tyre_width_m)),
            float(params.get("preview.spacing_m", d.spacing_m)),
            float(params.get("preview.reference_distance_m", d.reference_distance_m)),
        )


class OutputMessages(NamedTuple):
    """The messages the node publishes for one estimate."""

    elevation: Any
    preview: Any
    points: Any | None


def output_messages(
    estimate: Estimate,
    grid: GridSpec,
    factory: MessageFactory,
    stamp_ns: int,
    *,
    preview: PreviewSettings,
    frame_id: str = ROAD_FRAME,
    vehicle_speed: float | None = None,
    with_points: bool = False,
) -> OutputMessages:
    """The GridMap, RoadPreview and (optionally) PointCloud2 for one estimate.

    Raises:
        ValueError: the estimate is not on ``grid``.
        PreviewError: the wheel tracks do not fit the grid.
    """
    estimate.check_grid(grid)
    profiles = wheel_track_profiles(
        estimate.elevation, estimate.uncertainty, grid,
        track_offsets_m=list(preview.track_offsets_m), tyre_width_m=preview.tyre_width_m,
        spacing_m=preview.spacing_m, vehicle_speed=vehicle_speed, reference_distance=preview.reference_distance_m,
    )
    elevation = elevation_grid_map(
        estimate.elevation, estimate.uncertainty, grid, factory, stamp_ns=stamp_ns, frame_id=frame_id
    )
    message = road_preview_message(profiles, factory, stamp_ns=stamp_ns, frame_id=frame_id)
    points = None
    if with_points:
        points = elevation_point_cloud(
            estimate.elevation, estimate.uncertainty, grid, factory, stamp_ns=stamp_ns, frame_id=frame_id
        )
    return OutputMessages(elevation, message, points)


class OutputBag:
    """An MCAP bag of the node's outputs: ``write(stamp_ns, estimate)`` per frame.

    Args:
        path: ``OUT.mcap`` (or a rosbag2 directory); must not exist.
        grid: the grid of the estimates.
        params: node parameters (``preview.*``, ``frame_id``, ``elevation_topic``,
            ``preview_topic``); defaults where absent.
    """

    def __init__(self, path: str | os.PathLike[str], grid: GridSpec, params: Mapping[str, Any] | None = None) -> None:
        params = dict(params or {})
        self.grid = grid
        self.preview = PreviewSettings.from_params(params)
        self.frame_id = str(params.get("frame_id", ROAD_FRAME))
        self.topics = (str(params.get("elevation_topic", ELEVATION_TOPIC)),
                       str(params.get("preview_topic", PREVIEW_TOPIC)))
        self._factory = TypestoreFactory(typestore())
        self._writer = BagWriter(path)
        self._writer.open()
        self._writer.add_topic(self.topics[0], "grid_map_msgs/msg/GridMap")
        self._writer.add_topic(self.topics[1], "roadbev_msgs/msg/RoadPreview")

    @property
    def counts(self) -> dict[str, int]:
        return dict(self._writer.counts)

    def write(self, stamp_ns: int, estimate: Estimate) -> None:
        """The frame's GridMap and RoadPreview, logged at the image stamp."""
        messages = output_messages(estimate, self.grid, self._factory, stamp_ns, preview=self.preview,
                                   frame_id=self.frame_id)
        self._writer.write(self.topics[0], messages.elevation, stamp_ns)
        self._writer.write(self.topics[1], messages.preview, stamp_ns)

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
