"""The node's fused-map services, without ROS: ``~/clear_map``, ``~/save_map`` and
``~/get_submap`` (as elevation_mapping's), ``~/save_map_to`` (a path, as grid_map's
``ProcessFile`` services take one), and why no map can be served.

The handlers take and fill the service's request and response objects by attribute only
(``std_srvs/Trigger``, ``grid_map_msgs/GetGridMap``, ``grid_map_msgs/ProcessFile``), so they run
on rclpy messages in the node and on plain objects in tests.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from msg_bridge import MessageFactory
from msg_bridge.grid_map import fused_map_message
from msg_bridge.outputs import save_map_bag
from roadbev_core.config import RoadbevConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.fusion import MapWindow

__all__ = ["MAP_SUFFIX", "FusedMapSource", "MapServices", "SavePathRefused", "map_file"]

MAP_SUFFIX = ".mcap"  # a saved map is an MCAP bag


class SavePathRefused(RoadbevError):
    """A path ``~/save_map_to`` does not write to, and why."""


def map_file(file_path: str, save_dir: str) -> Path:
    """Where ``~/save_map_to`` writes the map asked for at ``file_path``: ``~`` expanded, a relative
    path taken from ``save_dir`` (``map.save_dir``, itself ``~`` expanded and taken from the working
    directory), ``.mcap`` appended to a name that lacks it. The file must not exist (never
    overwritten) and its folder must exist and be writable; ``save_dir`` itself is created, as
    ``~/save_map`` does.

    Raises:
        SavePathRefused: the cause, naming the path.
    """
    if not file_path.strip():
        raise SavePathRefused("file_path is empty (~/save_map writes into map.save_dir under a name of its own)")
    folder = Path(save_dir).expanduser().resolve()
    path = (folder / Path(file_path).expanduser()).resolve()  # an absolute file_path replaces the folder
    if path.suffix != MAP_SUFFIX:
        path = path.with_name(path.name + MAP_SUFFIX)
    if path.is_dir():
        raise SavePathRefused(f"{path} is a folder: name a file in it")
    if path.exists() or path.is_symlink():
        raise SavePathRefused(f"{path} exists: it is not overwritten (remove it, or name another file)")
    if path.parent == folder:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SavePathRefused(f"cannot create map.save_dir {folder}: {exc}") from None
    if not path.parent.exists():
        raise SavePathRefused(f"the folder {path.parent} does not exist (only map.save_dir is created)")
    if not path.parent.is_dir():
        raise SavePathRefused(f"{path.parent} is not a folder")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise SavePathRefused(f"the folder {path.parent} is not writable")
    return path


class FusedMapSource(Protocol):
    """What the services need of :class:`roadbev_core.pipeline.Pipeline`."""

    last_map: MapWindow | None

    @property
    def map_active(self) -> bool: ...

    def clear_map(self) -> None: ...


@dataclass
class MapServices:
    """The fused map's services and state in words.

    Args:
        pipeline: holds the newest fused map.
        config: the node's config now (a parameter change replaces it).
        motion_samples: how many odometry and speed samples have been taken so far.
        resolve: a topic as the graph names it (remapped, fully qualified).
        now_s: the node's clock, seconds.
        factory: builds the GridMap of ``~/get_submap``.
        info: writes an info line to the log.
        warn: writes a warning line to the log.
        report: ``report(kind, reason)``: a problem for the diagnostics and the log.
    """

    pipeline: FusedMapSource
    config: Callable[[], RoadbevConfig]
    motion_samples: Callable[[], int]
    resolve: Callable[[str], str]
    now_s: Callable[[], float]
    factory: MessageFactory
    info: Callable[[str], object]
    warn: Callable[[str], object]
    report: Callable[[str, str], None]
    cleared_at: float | None = None  # node-clock seconds of the last ~/clear_map

    def clear_map(self, request: Any, response: Any) -> Any:
        """``~/clear_map`` (std_srvs/Trigger), as elevation_mapping's: the fused map starts afresh."""
        self.pipeline.clear_map()
        self.cleared_at = self.now_s()
        response.success = True
        response.message = "fused map cleared"
        self.info("fused map cleared (~/clear_map)")
        return response

    def save_map(self, request: Any, response: Any) -> Any:
        """``~/save_map`` (std_srvs/Trigger): the newest fused map to ``map.save_dir`` as an MCAP
        bag (one GridMap, as published); the reply names the file or says why not."""
        window = self.pipeline.last_map
        if window is None:
            response.success, response.message = False, f"no fused map to save: {self.why_no_map()}"
            return response
        config = self.config()
        # absolute: a relative map.save_dir is taken from the node's working directory, which a
        # launch file or a service call does not show
        path = Path(config.map.save_dir).expanduser().resolve() / f"roadbev_map_{window.stamp_ns}.mcap"
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_map_bag(path, window, config)
        except (RoadbevError, OSError) as exc:
            response.success, response.message = False, f"cannot save the map to {path}: {exc}"
            self.report("save map", response.message)
            return response
        response.success, response.message = True, str(path)
        self.info(f"fused map saved to {path}")
        return response

    def save_map_to(self, request: Any, response: Any) -> Any:
        """``~/save_map_to`` (grid_map_msgs/ProcessFile): the newest fused map to
        ``request.file_path`` (:func:`map_file`: a relative path from ``map.save_dir``, ``.mcap``
        appended when missing, never over an existing file) as an MCAP bag, the GridMap on
        ``request.topic_name`` (``map_topic`` when empty). The response carries ``success`` only:
        the file written goes to the log, and so does why not (a refusal as a warning; a failure
        to write, which is the node's, to the diagnostics too)."""
        response.success = False
        window = self.pipeline.last_map
        if window is None:
            self.warn(f"~/save_map_to: no fused map to save: {self.why_no_map()}")
            return response
        config = self.config()
        try:
            path = map_file(request.file_path, config.map.save_dir)
        except SavePathRefused as exc:
            self.warn(f"~/save_map_to {request.file_path!r} refused: {exc}")
            return response
        topic = request.topic_name.strip() or config.map.topic
        topic = topic if topic.startswith("/") else f"/{topic}"
        try:
            save_map_bag(path, window, config, topic=topic)
        except (RoadbevError, OSError) as exc:
            self.report("save map", f"cannot save the map to {path}: {exc}")
            return response
        response.success = True
        self.info(f"fused map saved to {path} (~/save_map_to, topic {topic})")
        return response

    def get_submap(self, request: Any, response: Any) -> Any:
        """``~/get_submap`` (grid_map_msgs/GetGridMap, as elevation_mapping's): the cells of the
        newest fused map within ``length_x`` x ``length_y`` around ``position`` in ``frame_id`` (the
        map's frame; a length <= 0 takes the whole map along it), with the ``layers`` asked for (all
        when none). The service has no status field: when nothing can be served the answer is a map
        without layers, and the reason goes to the log (a client's request is not the node's
        fault, so the diagnostics are left alone)."""
        window = self.pipeline.last_map
        frame = self.config().map.frame
        reason = ""
        if window is None:
            reason = f"no fused map: {self.why_no_map()}"
        elif request.frame_id.lstrip("/") not in ("", frame):
            reason = f"frame {request.frame_id!r}: the map is served in its own frame, {frame!r}"
        else:
            window = window.crop((request.position_x, request.position_y), (request.length_x, request.length_y))
            if window is None:
                reason = (f"no cell of the map within {request.length_x:g} x {request.length_y:g} m around "
                          f"({request.position_x:g}, {request.position_y:g}) in {frame!r}")
        if reason or window is None:
            self.warn(f"~/get_submap: {reason}")
            response.map.header.frame_id = frame
            return response
        msg = fused_map_message(window, self.factory, frame_id=frame)
        wanted = list(request.layers)
        unknown = [name for name in wanted if name not in msg.layers]
        if unknown:
            self.warn(f"~/get_submap: no layer {', '.join(unknown)} (the map has {', '.join(msg.layers)})")
        if wanted:
            keep = [i for i, name in enumerate(msg.layers) if name in wanted]
            msg.layers = [msg.layers[i] for i in keep]
            msg.data = [msg.data[i] for i in keep]
            msg.basic_layers = [name for name in msg.basic_layers if name in msg.layers]
        response.map = msg
        return response

    def why_no_map(self) -> str:
        """Why the node holds no fused map now, the first cause that applies."""
        config = self.config()
        topics = config.topics
        if not config.map.enabled:
            return "map.enabled is false"
        if self.cleared_at is not None:
            return (f"the map was cleared by ~/clear_map at {self.cleared_at:.3f} s and no frame has been fused "
                    "since")
        if self.motion_samples() == 0:
            odometry = (f"odometry on /tf ({config.map.frame} -> {topics.base_frame})" if topics.odom_from_tf
                        else f"odometry on {self.resolve(topics.odom)}" if topics.odom else "")
            sources = [odometry, f"speed on {self.resolve(topics.speed)}" if topics.speed else ""]
            named = " or ".join(s for s in sources if s)
            return f"no {named} received yet" if named else "neither odom_topic nor speed_topic is set"
        return "no frame has been fused yet (frames need odometry around their stamps, map.odom_max_age_s)"

    def state(self) -> str:
        """The fused map in a few words, for the diagnostics: fusing, or why not."""
        if not self.config().map.enabled:
            return "off (map.enabled false)"
        if self.pipeline.map_active:
            return "fusing"
        return f"waiting: {self.why_no_map()}"
