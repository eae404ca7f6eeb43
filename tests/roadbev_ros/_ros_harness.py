"""Test harness: the RoadBEV node in-process, fed and observed over real DDS by a second node.

The node under test and a ``feeder`` node (publishers for the inputs, subscribers for the
outputs) spin in one executor on a background thread; the test thread publishes and waits.
A stub backend answers each frame with a flat map at the frame's pitch, so tests can check that
the IMU attitude interpolated to the image stamp reaches the backend.
"""

from __future__ import annotations

import math
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from msg_bridge import RclpyFactory, stamp_from_header
from msg_bridge.camera_info import camera_info_from_stereo
from msg_bridge.grid_map import grid_map_to_arrays
from msg_bridge.image import array_to_compressed, array_to_image
from msg_bridge.imu import imu_message
from roadbev_core.backends import BackendError
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame

MS = 1_000_000
CAMERA = StereoCamera(fx=60.0, fy=60.0, cx=31.5, cy=23.5, baseline=0.12, width=64, height=48)
# A short grid keeps every message small (40 x 64 cells).
SMALL_GRID = {"x_min": 2.16, "x_max": 3.36}
START_NS = 1_700_000_000 * 1_000_000_000


def quat_pitch(pitch: float) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a pure pitch about y."""
    return (0.0, math.sin(pitch / 2), 0.0, math.cos(pitch / 2))


class PitchBackend:
    """Stub backend: a flat map at the frame's pitch (radians), optionally slow."""

    needs_stereo = True

    def __init__(self, grid: GridSpec, delay_s: float = 0.0, name: str = "stub") -> None:
        self.grid = grid
        self.delay_s = delay_s
        self.name = name
        self.calls = 0

    def estimate(self, frame: Frame) -> Estimate:
        self.calls += 1
        if self.delay_s:
            time.sleep(self.delay_s)
        elevation = np.full(self.grid.shape, frame.attitude.pitch, np.float32)
        return Estimate(elevation, np.full(self.grid.shape, 0.01, np.float32), {"network": 0.0})


def stub_factory(delay_s: float = 0.0) -> Callable[..., PitchBackend]:
    """A backend factory for the node: 'mono' cannot be created (to test rejection)."""

    def factory(name: str, grid: GridSpec, **options: Any) -> PitchBackend:
        if name == "mono":
            raise BackendError("mono needs a checkpoint")
        return PitchBackend(grid, delay_s, name=f"stub-{name}")

    return factory


def wait_for(predicate: Callable[[], bool], timeout: float = 10.0, step: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()


class Spinning:
    """Nodes spinning in one executor on a background thread, with a ``feeder`` node for the
    test's publishers and subscribers (outputs kept in lists under one lock).

    Use as a context manager: on exit the thread stops and every node is destroyed.

    Args:
        rclpy: the initialised rclpy module.
        nodes: the nodes under test (destroyed on exit too).
    """

    def __init__(self, rclpy: Any, *nodes: Any) -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.nodes = nodes
        self.feeder = rclpy.create_node(f"feeder_{uuid.uuid4().hex[:8]}")
        self.qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.lock = threading.Lock()
        self.subscriptions: list[Any] = []
        self._executor = SingleThreadedExecutor()
        for node in (*nodes, self.feeder):
            self._executor.add_node(node)
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True)

    def _spin(self) -> None:
        while self._running:
            self._executor.spin_once(timeout_sec=0.02)

    def publisher(self, msg_type: Any, topic: str) -> Any:
        return self.feeder.create_publisher(msg_type, topic, self.qos)

    def collect(self, msg_type: Any, topic: str) -> list[Any]:
        """Subscribe ``topic``; returns the list its messages are appended to (under ``lock``)."""
        into: list[Any] = []

        def callback(msg: Any) -> None:
            with self.lock:
                into.append(msg)

        self.subscriptions.append(self.feeder.create_subscription(msg_type, topic, callback, self.qos))
        return into

    def connected(self, *publishers: Any, timeout: float = 15.0) -> bool:
        """Whether every publisher has a subscriber and every collecting subscription a publisher."""
        return wait_for(lambda: all(p.get_subscription_count() > 0 for p in publishers)
                        and all(s.get_publisher_count() > 0 for s in self.subscriptions), timeout)

    def __enter__(self) -> Spinning:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._running = False
        self._thread.join(5.0)
        self._executor.shutdown()
        for node in (*self.nodes, self.feeder):
            node.destroy_node()


class Harness:
    """Node under test + feeder, spinning on a background thread.

    Args:
        rclpy: the initialised rclpy module.
        params: node parameter overrides (the small grid is added).
        delay_s: stub backend inference time.
        backend_factory: replaces the stub backend when given.
    """

    def __init__(self, rclpy: Any, params: dict[str, Any] | None = None, delay_s: float = 0.0,
                 backend_factory: Callable[..., Any] | None = None, keep: int | None = None,
                 compressed: bool = False) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from grid_map_msgs.msg import GridMap
        from roadbev_msgs.msg import RoadPreview
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu

        from roadbev_ros.node import RoadBevNode

        tag = uuid.uuid4().hex[:8]
        self.params = {**SMALL_GRID, **(params or {})}
        self.compressed = compressed
        if compressed:
            self.params["image_transport"] = "compressed"
        self.node = RoadBevNode(
            node_name=f"roadbev_{tag}",
            backend_factory=backend_factory or stub_factory(delay_s),
            parameter_overrides=self.params,
        )
        self._spun = Spinning(rclpy, self.node)  # the node and a feeder, spun once started below
        self.feeder = self._spun.feeder
        self.factory = RclpyFactory()
        qos = self._spun.qos
        f = self.feeder
        self.pub = {
            "left": f.create_publisher(CompressedImage, "/stereo/left/image_rect/compressed", qos)
            if compressed else f.create_publisher(Image, "/stereo/left/image_rect", qos),
            "right": f.create_publisher(CompressedImage, "/stereo/right/image_rect/compressed", qos)
            if compressed else f.create_publisher(Image, "/stereo/right/image_rect", qos),
            "left_info": f.create_publisher(CameraInfo, "/stereo/left/camera_info", qos),
            "right_info": f.create_publisher(CameraInfo, "/stereo/right/camera_info", qos),
            "imu": f.create_publisher(Imu, "/imu/data", qos),
        }
        self.lock = self._spun.lock
        # outputs kept (the last ``keep`` of each; all when None) and the stamps of every map
        self.elevation: deque[Any] = deque(maxlen=keep)
        self.previews: deque[Any] = deque(maxlen=keep)
        self.diagnostics: deque[Any] = deque(maxlen=keep)
        self.stamps_seen: set[int] = set()

        def store(into: deque[Any]) -> Callable[[Any], None]:
            def callback(msg: Any) -> None:
                with self.lock:
                    into.append(msg)
                    if into is self.elevation:
                        self.stamps_seen.add(stamp_from_header(msg))
            return callback

        self.subs = [
            f.create_subscription(GridMap, "/roadbev/elevation", store(self.elevation), qos),
            f.create_subscription(RoadPreview, "/roadbev/preview", store(self.previews), qos),
            f.create_subscription(DiagnosticArray, "/diagnostics", store(self.diagnostics), qos),
        ]
        self._spun.__enter__()
        ok = wait_for(lambda: all(p.get_subscription_count() > 0 for p in self.pub.values())
                      and all(s.get_publisher_count() > 0 for s in self.subs), 15.0)
        assert ok, "discovery between the feeder and the node did not complete"
        self.left_image = np.random.default_rng(0).integers(0, 255, (CAMERA.height, CAMERA.width, 3), np.uint8)

    def close(self) -> None:
        self.node.shutdown()
        self._spun.__exit__(None, None, None)  # stops the thread, destroys the node and the feeder

    # --- inputs -------------------------------------------------------------------------------
    def publish_imu(self, stamp_ns: int, pitch: float) -> None:
        self.pub["imu"].publish(imu_message(self.factory, stamp_ns=stamp_ns, orientation_xyzw=quat_pitch(pitch)))

    def imu_around(self, stamp_ns: int, pitch_of: Callable[[int], float], span_ms: int = 30, step_ms: int = 10) -> None:
        """IMU samples every ``step_ms`` from ``stamp - span`` to ``stamp + span``."""
        for dt in range(-span_ms, span_ms + 1, step_ms):
            t = stamp_ns + dt * MS
            self.publish_imu(t, pitch_of(t))

    def frame_messages(self, stamp_ns: int) -> dict[str, Any]:
        f = self.factory
        if self.compressed:
            left = array_to_compressed(self.left_image, f, stamp_ns=stamp_ns, frame_id="left", fmt="png")
            right = array_to_compressed(self.left_image, f, stamp_ns=stamp_ns, frame_id="right", fmt="jpeg")
        else:
            left = array_to_image(self.left_image, f, stamp_ns=stamp_ns, frame_id="left")
            right = array_to_image(self.left_image, f, stamp_ns=stamp_ns, frame_id="right")
        return {
            "left": left,
            "right": right,
            "left_info": camera_info_from_stereo(CAMERA, f, stamp_ns=stamp_ns, frame_id="left"),
            "right_info": camera_info_from_stereo(CAMERA, f, right=True, stamp_ns=stamp_ns, frame_id="right"),
        }

    def publish_frame(
        self, stamp_ns: int, *, skip: tuple[str, ...] = (), replace: dict[str, Any] | None = None
    ) -> None:
        msgs = {**self.frame_messages(stamp_ns), **(replace or {})}
        for name in ("left_info", "right_info", "right", "left"):
            if name not in skip:
                self.pub[name].publish(msgs[name])

    # --- outputs ------------------------------------------------------------------------------
    def output_stamps(self) -> list[int]:
        with self.lock:
            return [stamp_from_header(m) for m in self.elevation]

    def output_for(self, stamp_ns: int) -> Any | None:
        with self.lock:
            for m in self.elevation:
                if stamp_from_header(m) == stamp_ns:
                    return m
        return None

    def wait_output(self, stamp_ns: int, timeout: float = 10.0) -> Any:
        assert wait_for(lambda: self.output_for(stamp_ns) is not None, timeout), (
            f"no elevation map for stamp {stamp_ns}; counts {self.node.counts()}, "
            f"last error {self.node.health.last_error!r}"
        )
        return self.output_for(stamp_ns)

    def elevation_value(self, msg: Any) -> float:
        data = grid_map_to_arrays(msg)
        layer = data.layers["elevation"]
        return float(np.nanmean(layer))

    def latest_diagnostics(self) -> dict[str, str]:
        with self.lock:
            if not self.diagnostics:
                return {}
            status = self.diagnostics[-1].status[0]
        return {kv.key: kv.value for kv in status.values}
