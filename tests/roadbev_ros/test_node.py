"""The node in-process over real DDS: pairing, IMU interpolation, drops, bad input, parameters."""

from __future__ import annotations

import functools
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from msg_bridge import stamp_from_header
from msg_bridge.preview import preview_from_message
from roadbev_core.config import DEFAULT_BACKEND

from ._ros_harness import MS, START_NS, Harness, PitchBackend, wait_for

FRAME_NS = 100 * MS  # 10 Hz


def _outputs_reach(h: Harness, n: int) -> bool:
    return wait_for(lambda: len(h.elevation) == n)


def _values(diagnostics: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in diagnostics.status[0].values}


def pitch_ramp(t_ns: int) -> float:
    """Pitch that changes by 0.1 rad per second, so interpolation errors show."""
    return 0.05 + 0.1 * (t_ns - START_NS) * 1e-9


@pytest.fixture
def harness(ros: Any, request: pytest.FixtureRequest) -> Iterator[Harness]:
    options = getattr(request, "param", {})
    h = Harness(ros, **options)
    try:
        yield h
    finally:
        h.close()


def feed(h: Harness, k: int, **kwargs: Any) -> int:
    stamp = START_NS + k * FRAME_NS
    h.imu_around(stamp + 3 * MS, pitch_ramp)  # IMU ticks are not aligned with the images
    h.publish_frame(stamp, **kwargs)
    return stamp


def test_every_frame_gives_an_elevation_map_with_the_interpolated_pitch(harness: Harness) -> None:
    stamps = []
    for k in range(10):
        stamps.append(feed(harness, k))
        msg = harness.wait_output(stamps[-1])  # one at a time: no set may be dropped as busy
        assert msg.header.frame_id == "roadbev_road"
        assert msg.layers == ["elevation", "uncertainty"]
        assert harness.elevation_value(msg) == pytest.approx(pitch_ramp(stamps[-1]), abs=1e-5)
    counts = harness.node.counts()
    assert counts["frames_in"] == 10 and counts["outputs"] == 10, counts
    # the preview comes with every map, stamped alike; no speed topic: no time of arrival
    assert wait_for(lambda: len(harness.previews) == 10)
    preview = preview_from_message(harness.previews[-1])
    assert sorted(stamp_from_header(m) for m in harness.previews) == stamps
    assert [t.name for t in preview.profiles.tracks] == ["left", "right"]
    assert preview.profiles.time_of_arrival() is None


@pytest.mark.parametrize("harness", [{"compressed": True}], indirect=True)
def test_compressed_transport(harness: Harness) -> None:
    """image_transport:=compressed: jpeg/png on .../compressed, decoded in the worker."""
    for k in range(3):
        stamp = feed(harness, k)
        assert harness.elevation_value(harness.wait_output(stamp)) == pytest.approx(pitch_ramp(stamp), abs=1e-5)
    # a CompressedImage that does not decode is refused and the node goes on
    bad = harness.frame_messages(START_NS + 3 * FRAME_NS)["left"]
    bad.data = b"not a jpeg"
    feed(harness, 3, replace={"left": bad})
    assert wait_for(lambda: harness.node.health.problems["bad input"] == 1)
    harness.wait_output(feed(harness, 4))


@pytest.mark.parametrize("harness", [{"delay_s": 0.15, "params": {"max_latency_s": 0.0}}], indirect=True)
def test_slow_inference_keeps_the_newest_set_and_counts_drops(harness: Harness) -> None:
    stamps = []
    for k in range(12):  # 40 Hz into a 6.7 Hz backend
        stamps.append(feed(harness, k))
        time.sleep(0.025)
    last = harness.wait_output(stamps[-1], timeout=15.0)  # the newest set is never dropped (no latency bound)
    assert last is not None
    counts = harness.node.counts()
    assert counts["dropped_busy"] > 0, harness.node.health.last_error
    assert counts["outputs"] + counts["dropped_busy"] + counts["dropped_sync"] + counts["dropped_invalid"] == 12, counts
    assert counts["outputs"] == len(harness.output_stamps())
    assert harness.output_stamps() == sorted(harness.output_stamps())


def _slow_chosen_fast_pace(name: str, grid: Any, **_options: Any) -> PitchBackend:
    return PitchBackend(grid, 0.0 if name == "bm" else 0.3, name=f"stub-{name}")


def test_a_backend_slower_than_the_camera_hands_the_frames_to_the_pace_backend(ros: Any) -> None:
    h = Harness(ros, params={"max_latency_s": 0.0, "diagnostics_period_s": 0.1},
                backend_factory=_slow_chosen_fast_pace)
    try:
        stamps = []
        for k in range(20):  # a 10 Hz camera, a 300 ms backend (paced while the camera's period is under 333 ms)
            stamps.append(feed(h, k))
            time.sleep(0.1)
        h.wait_output(stamps[-1], timeout=15.0)
        counts = h.node.counts()
        assert counts["outputs"] >= 17, counts  # the first frame measures the chosen backend's cost
        assert wait_for(lambda: int(h.latest_diagnostics().get("paced_frames", "0")) >= 15, 3.0), \
            h.latest_diagnostics()
        pace = h.latest_diagnostics()["pace"]
        assert pace.startswith("stub-bm answers") and "stub-ensemble takes 3" in pace, pace
        period_ms = int(pace.split("the camera's period is ")[1].split(" ms")[0])
        assert 95 <= period_ms <= 250, pace  # the sets' arrivals: 100 ms apart, and the feeder's own time
    finally:
        h.close()

    fits = Harness(ros, params={"max_latency_s": 0.0, "diagnostics_period_s": 0.1, "pace_load": 10.0},
                   backend_factory=_slow_chosen_fast_pace)
    try:  # allowed ten periods a frame, the chosen backend answers (and falls behind)
        stamps = [feed(fits, k) for k in range(3)]
        fits.wait_output(stamps[-1], timeout=15.0)
        assert wait_for(lambda: fits.latest_diagnostics().get("pace", "").startswith("stub-ensemble answers"), 3.0)
        assert fits.latest_diagnostics()["paced_frames"] == "0"
    finally:
        fits.close()


def _keeping_chosen_fast_pace(name: str, grid: Any, **_options: Any) -> PitchBackend:
    return PitchBackend(grid, 0.0 if name == "bm" else 0.06, name=f"stub-{name}")


def test_at_speed_the_pace_backend_answers_the_frames_a_chosen_backend_keeping_up_would_answer_late(ros: Any) -> None:
    from geometry_msgs.msg import TwistStamped
    from rclpy.parameter import Parameter

    h = Harness(ros, params={"max_latency_s": 0.0, "diagnostics_period_s": 0.1, "speed_topic": "/twist",
                             "speed_topic_type": "twist_stamped", "pace_lead_m": 0.5},
                backend_factory=_keeping_chosen_fast_pace)
    try:
        pub = h.feeder.create_publisher(TwistStamped, "/twist", 10)
        assert wait_for(lambda: pub.get_subscription_count() > 0)

        def frame_at_speed(k: int, mps: float) -> int:
            stamp = START_NS + k * 2 * FRAME_NS  # a 5 Hz camera: the chosen backend's 60 ms a frame fit it
            speed = TwistStamped()
            speed.twist.linear.x = mps
            speed.header.stamp.sec, speed.header.stamp.nanosec = divmod(stamp - 10 * MS, 1_000_000_000)
            pub.publish(speed)
            assert wait_for(lambda: h.node.pipeline.speed_at(stamp) == mps)
            feed(h, 2 * k)
            time.sleep(0.2)
            return stamp

        # 30 m/s: the chosen backend's 60 ms more a frame are 1.8 m of travel, more than pace_lead_m
        stamps = [frame_at_speed(k, 30.0) for k in range(10)]
        h.wait_output(stamps[-1], timeout=15.0)
        assert wait_for(lambda: int(h.latest_diagnostics().get("paced_frames", "0")) >= 7, 3.0), \
            h.latest_diagnostics()
        pace = h.latest_diagnostics()["pace"]
        assert pace.startswith("stub-bm answers") and "at 30.0 m/s" in pace and "(pace_lead_m 0.5)" in pace, pace
        # the rule off: the chosen backend, which keeps up, answers every frame again
        assert h.node.set_parameters([Parameter("pace_lead_m", value=0.0)])[0].successful
        paced = int(h.latest_diagnostics()["paced_frames"])
        stamps = [frame_at_speed(k, 30.0) for k in range(10, 14)]
        h.wait_output(stamps[-1], timeout=15.0)
        assert wait_for(lambda: h.latest_diagnostics().get("pace", "").startswith("stub-ensemble answers"), 3.0)
        assert int(h.latest_diagnostics()["paced_frames"]) == paced
    finally:
        h.close()


@pytest.mark.parametrize("harness", [{"delay_s": 0.15, "params": {"max_latency_s": 0.1, "diagnostics_period_s": 0.1}}],
                         indirect=True)
def test_an_output_later_than_the_latency_bound_is_not_published(harness: Harness) -> None:
    for k in range(3):
        feed(harness, k)
        time.sleep(0.3)
    assert wait_for(lambda: harness.node.counts()["dropped_stale"] == 3, 5.0), harness.node.counts()
    assert harness.node.counts()["outputs"] == 0 and not harness.elevation
    assert "max_latency_s 0.1): not published" in harness.node.health.last_error

    def error_said() -> bool:
        with harness.lock:
            status = harness.diagnostics[-1].status[0] if harness.diagnostics else None
        return status is not None and status.level == b"\x02" and "later than max_latency_s" in status.message

    assert wait_for(error_said, 3.0)
    assert harness.latest_diagnostics()["dropped_stale"] == "3"


def _bad_image(h: Harness, stamp: int, **fields: Any) -> Any:
    msg = h.frame_messages(stamp)["left"]
    for name, value in fields.items():
        setattr(msg, name, value)
    return msg


def _nan_imu(stamp: int) -> Any:
    from sensor_msgs.msg import Imu

    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.orientation.x = float("nan")
    return msg


def test_bad_input_is_reported_and_the_node_recovers(harness: Harness) -> None:
    from sensor_msgs.msg import CameraInfo

    h = harness
    k = 0

    def good() -> None:
        nonlocal k
        stamp = feed(h, k)
        k += 1
        h.wait_output(stamp)

    def bad(expected_kind: str, **kwargs: Any) -> None:
        nonlocal k
        before = h.node.health.problems[expected_kind]
        feed(h, k, **kwargs)
        k += 1
        time.sleep(0.2)  # let the worker see the bad set before a good one replaces it
        good()  # recovers at once (an unpaired image is found out when the next set completes)
        assert wait_for(lambda: h.node.health.problems[expected_kind] > before, 5.0), (
            f"{expected_kind} not reported; problems {dict(h.node.health.problems)}, last {h.node.health.last_error}"
        )

    good()
    stamp = START_NS + k * FRAME_NS
    bad("bad input", replace={"left": _bad_image(h, stamp, data=bytes(10))})  # data too short
    stamp = START_NS + k * FRAME_NS
    bad("bad input", replace={"left": _bad_image(h, stamp, encoding="yuv422")})
    stamp = START_NS + k * FRAME_NS
    zero_info = CameraInfo()
    zero_info.header.stamp.sec, zero_info.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    zero_info.width, zero_info.height = 64, 48
    bad("bad input", replace={"left_info": zero_info})  # uncalibrated: P all zero
    stamp = START_NS + k * FRAME_NS
    bad("bad frame", replace={"right": h.frame_messages(stamp)["right"].__class__(
        header=h.frame_messages(stamp)["right"].header, height=24, width=32, encoding="rgb8", step=96,
        data=bytes(32 * 24 * 3))})  # right image of another size
    bad("unpaired", skip=("right",))  # a left image without a right one ...
    bad("unpaired", skip=("left_info", "right_info"))  # ... or without camera infos
    # IMU: NaN orientation, then a frame with no IMU near its stamp
    before = h.node.health.problems["bad imu"]
    h.pub["imu"].publish(_nan_imu(START_NS + k * FRAME_NS))
    assert wait_for(lambda: h.node.health.problems["bad imu"] > before, 5.0)
    stamp = START_NS + (k + 20) * FRAME_NS  # two seconds after the last IMU sample
    before = h.node.health.problems["imu stale"]
    h.publish_frame(stamp)
    assert wait_for(lambda: h.node.health.problems["imu stale"] > before, 5.0)
    k += 21
    good()
    # out-of-order and duplicate stamps
    old = START_NS + (k - 3) * FRAME_NS
    before = h.node.health.problems["stamp order"]
    h.publish_frame(old)
    h.publish_frame(START_NS + (k - 1) * FRAME_NS)  # the last processed frame again
    assert wait_for(lambda: h.node.health.problems["stamp order"] >= before + 2, 5.0)
    good()
    # every left image is accounted for
    counts = h.node.counts()
    accounted = (counts["outputs"] + counts["dropped_busy"] + counts["dropped_sync"] + counts["dropped_invalid"]
                 + counts["dropped_stale"])
    assert accounted + counts["queued"] == counts["frames_in"], counts
    # diagnostics report the problems and the backend
    assert wait_for(lambda: "problem.imu stale" in h.latest_diagnostics(), 3.0)
    diag = h.latest_diagnostics()
    for key in ("problem.bad input", "problem.unpaired", "problem.bad imu", "problem.stamp order",
                "problem.bad frame"):
        assert int(diag[key]) >= 1, diag
    assert diag["backend"] == f"stub-{DEFAULT_BACKEND}"
    assert int(diag["outputs"]) >= 9


def test_nonsense_parameters_are_rejected_with_a_reason(harness: Harness) -> None:
    from rclpy.parameter import Parameter

    node = harness.node

    def set_param(name: str, value: Any) -> Any:
        return node.set_parameters([Parameter(name, value=value)])[0]

    for name, value, reason in [
        ("sync_slop_s", -1.0, "out of range"),  # rclpy checks the declared range first
        ("backend", "magic", "one of"),
        ("backend", "mono", "cannot run"),  # the stub factory refuses it
        ("resolution", 0.07, "whole number"),
        ("preview.track_offsets_m", [0.8, -3.0], "leaves the grid"),
        ("imu_to_camera_rpy_deg", [1.0, 2.0], "needs 3"),
        ("pace_backend", "bm:plane_parallax_px=16,mode", "pace_backend takes NAME=VALUE"),
        ("pace_backend", "magic:block_size=9", "pace_backend must be empty or one of"),
    ]:
        result = set_param(name, value)
        assert not result.successful, (name, value)
        assert reason in result.reason, result.reason
    assert node.health.problems["parameter"] == 8  # each rejection is in the diagnostics

    # a read-only parameter cannot change
    assert not set_param("image_transport", "compressed").successful
    # good changes are applied; a grid change rebuilds the backend on the new grid
    assert set_param("sync_slop_s", 0.03).successful
    assert node.sync.slop_ns == 30 * MS
    assert set_param("x_max", 3.06).successful
    assert node.pipeline.backend.grid.x_max == pytest.approx(3.06)
    stamp = feed(harness, 0)
    msg = harness.wait_output(stamp)
    assert msg.data[0].layout.dim[0].size * msg.data[0].layout.dim[1].size == 30 * 64


def test_costly_or_crashing_parameter_changes_are_rejected_and_the_node_keeps_running(ros: Any) -> None:
    """Changes that crashed or froze the node before: each is a rejection with the reason, and the
    old backend keeps answering."""
    from rclpy.parameter import Parameter

    def factory(name: str, grid: Any, **options: Any) -> Any:
        from ._ros_harness import PitchBackend

        if name == "mono":  # a checkpoint whose config asks for 10^6 channels
            raise RuntimeError("[enforce fail] could not allocate 4000000000000 bytes")
        return PitchBackend(grid)

    h = Harness(ros, backend_factory=factory)
    try:
        node = h.node
        backend = node.pipeline.backend
        for params, reason in [
            ([Parameter("resolution", value=0.001), Parameter("x_max", value=200.0)], "voxels, more than the limit"),
            ([Parameter("resolution", value=0.001)], "voxels, more than the limit"),
            ([Parameter("sync_slop_s", value=1.0), Parameter("sync_queue_size", value=1000)], "stamp combinations"),
            ([Parameter("backend", value="mono")], "RuntimeError"),
        ]:
            result = node.set_parameters_atomically(params)
            assert not result.successful and reason in result.reason, result.reason
            assert node.pipeline.backend is backend and node.config.backend.name == DEFAULT_BACKEND
        h.wait_output(feed(h, 0))  # still answering with the old backend
    finally:
        h.close()


@pytest.mark.parametrize(
    "harness",
    [{"params": {"speed_topic": "/odom"}}, {"params": {"speed_topic": "/twist", "speed_topic_type": "twist_stamped"}}],
    indirect=True,
)
def test_speed_topic_gives_times_of_arrival_and_a_viewer_gets_points_and_preview_markers(harness: Harness) -> None:
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import MarkerArray

    from msg_bridge.point_cloud import point_cloud_to_array

    odometry = harness.params["speed_topic"] == "/odom"
    msg_type = Odometry if odometry else TwistStamped
    pub = harness.feeder.create_publisher(msg_type, harness.params["speed_topic"], 10)
    clouds: list[Any] = []
    harness.feeder.create_subscription(PointCloud2, "/roadbev/points", clouds.append, 10)
    markers: list[Any] = []
    harness.feeder.create_subscription(MarkerArray, "/roadbev/preview_markers", markers.append, 10)
    assert wait_for(lambda: pub.get_subscription_count() > 0 and harness.node.count_subscribers("/roadbev/points") > 0
                    and harness.node.count_subscribers("/roadbev/preview_markers") > 0)
    speed = msg_type()
    (speed.twist.twist if odometry else speed.twist).linear.x = 5.0
    first = START_NS  # speeds are matched to frames by stamp (SPEED_MAX_AGE_S), as offline
    speed.header.stamp.sec, speed.header.stamp.nanosec = divmod(first - 50_000_000, 1_000_000_000)
    pub.publish(speed)
    assert wait_for(lambda: harness.node.pipeline.speed_at(first) is not None)
    stamp = feed(harness, 0)
    harness.wait_output(stamp)
    assert wait_for(lambda: len(harness.previews) == 1)
    profiles = preview_from_message(harness.previews[0]).profiles
    toa = profiles.time_of_arrival()
    assert toa is not None
    assert profiles.vehicle_speed == pytest.approx(5.0)
    # a speed turns the map on (dead reckoned): the contact-plane stream, arrivals at the front axle
    assert profiles.reference == "contact_plane" and profiles.reference_distance == pytest.approx(2.8)
    np.testing.assert_allclose(toa, (profiles.distances() - 2.8) / 5.0, rtol=1e-5, atol=1e-6)
    # a viewer listens on the point cloud topic: one point per estimated cell
    assert wait_for(lambda: len(clouds) == 1)
    names, points = point_cloud_to_array(clouds[0])
    assert points.shape[0] == 40 * 64 and "z" in names
    np.testing.assert_allclose(points[:, names.index("z")], pitch_ramp(stamp), atol=1e-5)
    # and on the preview's markers: a line per wheel track in the preview's frame, on its contact plane
    assert wait_for(lambda: len(markers) == 1)
    strips = [m for m in markers[0].markers if m.type == 4]  # LINE_STRIP
    assert {m.ns for m in strips} == {t.name for t in profiles.tracks}
    assert all(m.header.frame_id == "base_link" for m in markers[0].markers)
    track = profiles.track(strips[0].ns)
    xyz = np.array([[p.x, p.y, p.z] for p in strips[0].points])
    first = int(round((xyz[0, 0] - profiles.start_distance) / profiles.spacing))
    assert profiles.contact_plane is not None
    expected = track.elevation[first: first + len(xyz)] + profiles.contact_plane.height_at(xyz[:, 0], xyz[:, 1])
    np.testing.assert_allclose(xyz[:, 2], expected, atol=1e-5)


def test_backend_options_come_from_parameters(ros: Any) -> None:
    """``<backend>.<option>`` parameters (as ``roadbev eval --params`` reads them) reach the factory."""
    from rclpy.parameter import Parameter

    seen: list[dict[str, Any]] = []

    def factory(name: str, grid: Any, **options: Any) -> Any:
        from ._ros_harness import PitchBackend

        seen.append({"name": name, **options})
        if options.get("patch_cells", 1) % 2 == 0:
            raise ValueError("patch_cells must be odd")
        return PitchBackend(grid)

    h = Harness(ros, params={"bm.block_size": 7}, backend_factory=factory)
    try:
        node = h.node
        # options of other backends are not passed; the pace backend (bm) gets its own
        assert seen[-2:] == [{"name": DEFAULT_BACKEND}, {"name": "bm", "block_size": 7}]
        assert node.set_parameters([Parameter("backend", value="bm")])[0].successful
        assert seen[-1] == {"name": "bm", "block_size": 7}
        result = node.set_parameters([Parameter("backend", value="bev_sweep")])[0]
        assert result.successful
        node.declare_parameter("bev_sweep.patch_cells", 3)  # declaring sets it: a new backend
        assert seen[-1] == {"name": "bev_sweep", "patch_cells": 3}
        bad = node.set_parameters([Parameter("bev_sweep.patch_cells", value=4)])[0]
        assert not bad.successful and "odd" in bad.reason
        assert node.set_parameters([Parameter("bev_sweep.patch_cells", value=5)])[0].successful
        assert seen[-1] == {"name": "bev_sweep", "patch_cells": 5}
    finally:
        h.close()


@pytest.mark.parametrize("harness", [{"params": {"diagnostics_period_s": 0.1, "diagnostics.max_stamp_age_s": 0.0}}],
                         indirect=True)
def test_a_looped_bag_resets_once_per_pass_with_a_warning(harness: Harness,
                                                             capfd: pytest.CaptureFixture[str]) -> None:
    """A bag that starts again (stamps jump back and stay back, as ``roadbev replay --loop`` does)
    is a reset of the synchroniser, the IMU history and the pipeline with one WARN a pass, counted
    in the diagnostics. The first frame of a pass is held until the second confirms the jump, then
    both are emitted at once: the node's newest-set mailbox may answer only the second."""
    passes = 3

    def accounted() -> int:
        counts = harness.node.counts()
        return counts["outputs"] + counts["dropped_busy"]

    for n in range(passes):
        for i, k in enumerate(range(30, 50, 5)):  # the same 1.5 s of "bag" every pass
            feed(harness, k)
            time.sleep(0.02)  # a camera's pace (50 Hz), inside the diagnostics' rate bound (100 Hz)
            if n > 0 and i == 0:
                continue  # held until the next frame confirms the jump
            done = 4 * n + i + 1
            assert wait_for(lambda d=done: accounted() == d), harness.node.counts()  # type: ignore[misc]
    node = harness.node
    assert node.health.time_jumps == passes - 1
    assert dict(node.health.problems) == {}, node.health.last_error
    counts = node.counts()
    assert counts["frames_in"] == accounted() == 4 * passes and counts["dropped_sync"] == 0, counts
    assert counts["outputs"] >= 4 * passes - (passes - 1), counts
    # every diagnostics message since the first output is OK, and it counts the jumps
    assert wait_for(lambda: harness.latest_diagnostics().get("time_jumps") == str(passes - 1))
    with harness.lock:
        levels = [m.status[0].level for m in harness.diagnostics if int(_values(m)["outputs"]) > 0]
        said = {m.status[0].message for m in harness.diagnostics if int(_values(m)["outputs"]) > 0}
    assert levels and set(levels) == {b"\x00"}, (levels, said)
    log = capfd.readouterr().err
    assert log.count("stamps went back") == passes - 1, log
    assert log.count("WARN") == passes - 1, log


def test_mono_backend_needs_only_the_left_camera(ros: Any) -> None:
    from ._ros_harness import PitchBackend

    class MonoStub(PitchBackend):
        needs_stereo = False

    h = Harness(ros, backend_factory=lambda name, grid, **o: MonoStub(grid, name="mono-stub"))
    try:
        assert h.node.sync.n_topics == 2
        stamp = feed(h, 0, skip=("right", "right_info"))
        assert h.elevation_value(h.wait_output(stamp)) == pytest.approx(pitch_ramp(stamp), abs=1e-5)
    finally:
        h.close()


def test_with_odometry_the_node_publishes_the_fused_map_its_tf_and_clears_it_on_request(harness: Harness,
                                                                                         tmp_path: Any) -> None:
    from grid_map_msgs.msg import GridMap
    from nav_msgs.msg import Odometry
    from std_srvs.srv import Trigger
    from tf2_msgs.msg import TFMessage

    from msg_bridge.grid_map import decode_grid_map
    from msg_bridge.tf import transforms_from_tf

    maps: list[Any] = []
    tfs: list[Any] = []
    harness.feeder.create_subscription(GridMap, "/roadbev/map", maps.append, 10)
    harness.feeder.create_subscription(TFMessage, "/tf", tfs.append, 10)
    odom = harness.feeder.create_publisher(Odometry, "/odom", 50)
    assert wait_for(lambda: odom.get_subscription_count() > 0)

    def publish_odometry(k: int) -> None:
        msg = Odometry()
        stamp = START_NS + k * FRAME_NS
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x = 1.0 * k  # 10 m/s
        msg.pose.pose.orientation.w = 1.0
        msg.twist.twist.linear.x = 10.0
        odom.publish(msg)

    for k in range(8):
        publish_odometry(k + 1)  # the sample after the frame's stamp: the node waits for it
        harness.wait_output(feed(harness, k))
    assert wait_for(lambda: len(maps) == 8 and len(tfs) == 8)
    decoded = decode_grid_map(maps[-1])
    assert decoded.frame_id == "odom" and set(decoded.layers) == {"elevation", "uncertainty", "observations", "age",
                                                                 "datum_uncertainty"}
    assert np.isfinite(decoded.layers["elevation"]).sum() > 1000
    tf = transforms_from_tf(tfs[-1])[0]
    assert (tf.parent, tf.child) == ("left", "roadbev_road")  # the left images' frame_id
    np.testing.assert_allclose(tf.translation, tf.rotation @ np.array([0.0, 0.0, -1.10]), atol=1e-5)
    preview = preview_from_message(harness.previews[-1])
    assert preview.frame_id == "base_link" and preview.profiles.contact_plane is not None
    from rclpy.parameter import Parameter

    from msg_bridge.bag import read_messages

    assert harness.node.set_parameters([Parameter("map.save_dir", value=str(tmp_path))])[0].successful
    saver = harness.feeder.create_client(Trigger, f"/{harness.node.get_name()}/save_map")
    assert saver.wait_for_service(timeout_sec=10.0)
    saved = saver.call_async(Trigger.Request())
    assert wait_for(saved.done) and saved.result().success, saved.result().message
    stored = [item.msg for item in read_messages(saved.result().message, ["/roadbev/map"])]
    assert len(stored) == 1 and set(decode_grid_map(stored[0]).layers) == set(decoded.layers)
    from grid_map_msgs.srv import GetGridMap

    submap = harness.feeder.create_client(GetGridMap, f"/{harness.node.get_name()}/get_submap")
    assert submap.wait_for_service(timeout_sec=10.0)
    window = harness.node.pipeline.last_map
    assert window is not None
    xs, ys = window.cell_centres()
    ask = GetGridMap.Request(frame_id="odom", position_x=float(xs.mean()), position_y=float(ys.mean()),
                             length_x=0.6, length_y=0.3, layers=["elevation", "uncertainty"])
    answer = submap.call_async(ask)
    assert wait_for(answer.done)
    sub = decode_grid_map(answer.result().map)
    assert set(sub.layers) == {"elevation", "uncertainty"} and sub.frame_id == "odom"
    assert sub.layers["elevation"].shape[0] * window.resolution <= 0.6 + window.resolution + 1e-6
    assert sub.layers["elevation"].shape[1] * window.resolution <= 0.3 + window.resolution + 1e-6
    wrong = submap.call_async(GetGridMap.Request(frame_id="base_link", length_x=1.0, length_y=1.0))
    assert wait_for(wrong.done) and list(wrong.result().map.layers) == []  # only the map's frame is served
    from grid_map_msgs.srv import ProcessFile

    save_to = harness.feeder.create_client(ProcessFile, f"/{harness.node.get_name()}/save_map_to")
    assert save_to.wait_for_service(timeout_sec=10.0)
    named = save_to.call_async(ProcessFile.Request(file_path="drive_7", topic_name="/road/map"))
    assert wait_for(named.done) and named.result().success  # relative: in map.save_dir, .mcap added
    assert [item.topic for item in read_messages(tmp_path / "drive_7.mcap")] == ["/road/map"]
    twice = save_to.call_async(ProcessFile.Request(file_path=str(tmp_path / "drive_7.mcap")))
    assert wait_for(twice.done) and not twice.result().success  # never over an existing file
    client = harness.feeder.create_client(Trigger, f"/{harness.node.get_name()}/clear_map")
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(Trigger.Request())
    assert wait_for(future.done) and future.result().success
    assert harness.node.pipeline.fused is not None and harness.node.pipeline.fused.empty
    assert Path(saved.result().message).is_absolute()
    # the map was cleared: no sub-map to serve, an answer without layers
    empty = submap.call_async(GetGridMap.Request(frame_id="odom", position_x=10.0, length_x=1.0, length_y=1.0))
    assert wait_for(empty.done) and list(empty.result().map.layers) == []
    again = saver.call_async(Trigger.Request())  # the reply says why there is nothing to save now
    assert wait_for(again.done) and not again.result().success
    assert "cleared by ~/clear_map" in again.result().message, again.result().message


def test_a_frame_without_coverage_warns_on_diagnostics_with_its_likely_cause(ros: Any) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    from ._ros_harness import PitchBackend

    class Blind(PitchBackend):
        """Answers nothing while ``blind`` (as bev_sweep on a textureless road)."""

        blind = True

        def estimate(self, frame: Any) -> Any:
            out = super().estimate(frame)
            if self.blind:
                out.elevation[:] = np.nan
            return out

    backends: list[Blind] = []

    def factory(name: str, grid: Any, **options: Any) -> Blind:
        backends.append(Blind(grid))
        return backends[-1]

    h = Harness(ros, backend_factory=factory, params={"diagnostics_period_s": 0.1, "pace_backend": ""})
    try:
        h.wait_output(feed(h, 0))
        assert wait_for(lambda: h.latest_diagnostics().get("coverage_pct") == "0.0", 5.0)
        values = h.latest_diagnostics()
        # the harness's images have texture and a clean rectification: the hint names base_height
        assert values["self_check"].startswith("coverage 0.0 % (low): ") and "base_height" in values["self_check"]
        assert h.diagnostics[-1].status[0].level == DiagnosticStatus.WARN
        backends[-1].blind = False
        h.wait_output(feed(h, 1))
        assert wait_for(lambda: h.latest_diagnostics().get("coverage_pct") == "100.0", 5.0)
        assert h.latest_diagnostics()["self_check"] == "coverage 100.0 %"
    finally:
        h.close()


def test_the_outputs_are_advertised_before_the_backend_loads_and_the_inputs_after(ros: Any) -> None:
    """A recorder beside the node matches its outputs while the backend loads; a replay waiting
    for the node's subscriptions then cannot start before the recorder can get the first output."""
    from roadbev_ros.node import RoadBevNode

    from ._ros_harness import stub_factory

    tag = uuid.uuid4().hex[:8]
    name = f"roadbev_order_{tag}"
    observer = ros.create_node(f"observer_{tag}")
    seen: dict[str, set[str]] = {}

    def topics_of(by_node: Any) -> set[str]:
        try:
            return {topic for topic, _ in by_node(name, "/")}
        except Exception:  # the node is not in the graph yet
            return set()

    def factory(backend: str, grid: Any, **options: Any) -> Any:
        wait_for(lambda: "/roadbev/elevation" in topics_of(observer.get_publisher_names_and_types_by_node))
        seen["publishers"] = topics_of(observer.get_publisher_names_and_types_by_node)
        seen["subscriptions"] = topics_of(observer.get_subscriber_names_and_types_by_node)
        return stub_factory()(backend, grid, **options)

    node = RoadBevNode(node_name=name, backend_factory=factory)
    try:
        assert {"/roadbev/elevation", "/roadbev/preview", "/diagnostics"} <= seen["publishers"], seen
        assert not {"/stereo/left/image_rect", "/imu/data"} & seen["subscriptions"], seen
        assert wait_for(lambda: "/stereo/left/image_rect" in topics_of(observer.get_subscriber_names_and_types_by_node))
    finally:
        node.shutdown()
        node.destroy_node()
        observer.destroy_node()


def test_an_input_that_never_arrived_is_named_when_the_images_are_dropped(harness: Harness) -> None:
    h = harness
    for k in range(14):  # past the synchroniser's queue of 10 per topic: the oldest left images drop
        feed(h, k, skip=("left_info", "right_info"))
        arrived = functools.partial(lambda n: h.node.counts()["frames_in"] == n, k + 1)
        assert wait_for(arrived, 5.0)  # one at a time: the sensor QoS keeps 5
    assert wait_for(lambda: h.node.health.problems["unpaired"] > 0, 5.0)
    reason = h.node.health.last_error
    assert "nothing received on /stereo/left/camera_info (left info), /stereo/right/camera_info (right info)" in reason
    assert "/stereo/left/image_rect (" not in reason  # the images did arrive
    assert "queue overflow" not in reason


@pytest.mark.parametrize("transport", ["raw", "compressed"])
def test_logs_and_diagnostics_name_the_remapped_topics(ros: Any, transport: str) -> None:
    from roadbev_ros.node import LEFT_IMAGE, LEFT_INFO, RoadBevNode

    from ._ros_harness import SMALL_GRID, stub_factory

    node = RoadBevNode(node_name=f"roadbev_{uuid.uuid4().hex[:8]}", backend_factory=stub_factory(),
                       parameter_overrides={**SMALL_GRID, "image_transport": transport},
                       cli_args=["--ros-args", "-r", "/stereo/left/image_rect:=/cam_front/left/image_rect",
                                 "-r", "/stereo/left/camera_info:=/cam_front/left/camera_info"])
    try:
        suffix = "/compressed" if transport == "compressed" else ""
        # a remapped base topic moves its compressed transport with it, as image_transport does
        assert node._resolved_image_topic("/stereo/left/image_rect") == "/cam_front/left/image_rect" + suffix
        assert node._inputs[LEFT_IMAGE] == "/cam_front/left/image_rect" + suffix
        assert node._inputs[LEFT_INFO] == "/cam_front/left/camera_info"
        subscribed = {name for name, _ in node.get_subscriber_names_and_types_by_node(node.get_name(), "/")}
        assert "/cam_front/left/image_rect" + suffix in subscribed
        assert "/stereo/left/image_rect" + suffix not in subscribed
        node._publish_diagnostics()  # nothing publishes the remapped topic: the hint names it
        assert node.health.input_hint.startswith("nothing publishes /cam_front/left/image_rect" + suffix)
    finally:
        node.shutdown()
        node.destroy_node()


def test_the_camera_mount_comes_through_a_chain_of_static_transforms(harness: Harness) -> None:
    """base_link -> camera_link -> the images' frame, from two static broadcasters, over DDS."""
    from tf2_msgs.msg import TFMessage

    from msg_bridge import RclpyFactory
    from msg_bridge.tf import StaticTransform, tf_message
    from roadbev_core.geometry import rotation_from_rpy
    from roadbev_ros.node import TF_STATIC_QOS

    tilt = rotation_from_rpy(0.0, 0.05, 0.0)
    optical = rotation_from_rpy(-np.pi / 2, 0.0, -np.pi / 2)
    body = harness.feeder.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
    driver = harness.feeder.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
    factory = RclpyFactory()
    body.publish(tf_message([StaticTransform("base_link", "camera_link", tilt, np.array([1.7, 0.0, 1.2]))], factory))
    driver.publish(tf_message([StaticTransform("camera_link", "left", optical, np.array([0.0, 0.05, 0.0]))], factory))
    harness.wait_output(feed(harness, 0))  # the images' frame_id ("left") joins the chain
    expected = np.array([1.7, 0.0, 1.2]) + tilt @ np.array([0.0, 0.05, 0.0])
    assert wait_for(lambda: harness.node.pipeline.camera_mount[1] is not None, 5.0)
    position, rotation = harness.node.pipeline.camera_mount
    assert rotation is not None
    np.testing.assert_allclose(position, expected, atol=1e-9)
    np.testing.assert_allclose(rotation, tilt @ optical, atol=1e-9)


def test_save_map_without_motion_names_the_missing_input(harness: Harness) -> None:
    from std_srvs.srv import Trigger

    saver = harness.feeder.create_client(Trigger, f"/{harness.node.get_name()}/save_map")
    assert saver.wait_for_service(timeout_sec=10.0)
    harness.wait_output(feed(harness, 0))  # a frame, but no odometry: no map
    reply = saver.call_async(Trigger.Request())
    assert wait_for(reply.done) and not reply.result().success
    assert reply.result().message == "no fused map to save: no odometry on /odom received yet"


@pytest.mark.parametrize("harness", [{"params": {"publish_odom_tf": True}}], indirect=True)
def test_publish_odom_tf_rebroadcasts_the_odometry_as_tf(harness: Harness) -> None:
    from nav_msgs.msg import Odometry
    from tf2_msgs.msg import TFMessage

    from msg_bridge.tf import transforms_from_tf

    tfs: list[Any] = []
    harness.feeder.create_subscription(TFMessage, "/tf", tfs.append, 10)
    odom = harness.feeder.create_publisher(Odometry, "/odom", 50)
    assert wait_for(lambda: odom.get_subscription_count() > 0)
    msg = Odometry()
    msg.header.stamp.sec, msg.header.frame_id, msg.child_frame_id = 5, "odom", "base_link"
    msg.pose.pose.position.x, msg.pose.pose.position.z = 12.5, 0.3
    msg.pose.pose.orientation.w = 1.0
    odom.publish(msg)
    assert wait_for(lambda: any(t.parent == "odom" for m in tfs for t in transforms_from_tf(m)), 5.0)
    (tf,) = [t for m in tfs for t in transforms_from_tf(m) if t.parent == "odom"]
    assert tf.child == "base_link"
    np.testing.assert_allclose(tf.translation, [12.5, 0.0, 0.3])


def test_an_odometry_teleport_is_refused_and_named(harness: Harness) -> None:
    from nav_msgs.msg import Odometry

    odom = harness.feeder.create_publisher(Odometry, "/odom", 50)
    assert wait_for(lambda: odom.get_subscription_count() > 0)

    def publish(k: int, x: float) -> None:
        msg = Odometry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(START_NS + k * 20 * MS, 1_000_000_000)
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.orientation.w, msg.twist.twist.linear.x = x, 1.0, 10.0
        odom.publish(msg)

    for k in range(3):
        publish(k, 0.2 * k)
    publish(3, 1e6)
    assert wait_for(lambda: harness.node.health.problems["bad odometry"] == 1, 5.0)
    assert "refused: a move of" in harness.node.health.last_error
    assert harness.node.pipeline.ego.newest is not None and harness.node.pipeline.ego.newest.x < 1.0


# the stale-output guard off: the test is about a stamp glitch, and a loaded machine must not drop
# the frames it waits for
@pytest.mark.parametrize("harness", [{"params": {"max_latency_s": 0.0}}], indirect=True)
def test_one_camera_set_stamped_far_ahead_leaves_the_map_alone(harness: Harness) -> None:
    """A stamp glitch (one set +1000 s, the IMU normal) is dropped and counted; the next good frame
    is not taken for a bag restart: nothing is reset and the map keeps what it fused."""
    from nav_msgs.msg import Odometry

    odom = harness.feeder.create_publisher(Odometry, "/odom", 50)
    assert wait_for(lambda: odom.get_subscription_count() > 0)

    def publish_odometry(k: int) -> None:
        msg = Odometry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(START_NS + k * FRAME_NS, 1_000_000_000)
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.orientation.w, msg.twist.twist.linear.x = 1.0 * k, 1.0, 10.0
        odom.publish(msg)

    for k in range(4):
        publish_odometry(k + 1)
        harness.wait_output(feed(harness, k))
    fused = harness.node.pipeline.fused
    assert fused is not None and not fused.empty
    before = harness.node.health.problems["stamp order"]
    harness.publish_frame(START_NS + 4 * FRAME_NS + 1000 * 10**9)  # the glitch: no IMU near it
    time.sleep(0.3)
    for k in range(4, 7):
        publish_odometry(k + 1)
        harness.wait_output(feed(harness, k))
    assert harness.node.health.time_jumps == 0
    assert harness.node.health.problems["stamp order"] > before  # counted, named
    assert harness.node.pipeline.fused is fused and not fused.empty
    assert harness.node._fused == 7  # every good frame fused into the one map


def test_a_rig_no_road_camera_has_is_a_named_fault_and_the_node_goes_on(harness: Harness) -> None:
    from dataclasses import replace

    from msg_bridge.camera_info import camera_info_from_stereo

    from ._ros_harness import CAMERA

    stamp = START_NS
    wide = replace(CAMERA, baseline=CAMERA.baseline * 1e7)  # a baseline of about a thousand kilometres
    bad = camera_info_from_stereo(wide, harness.factory, right=True, stamp_ns=stamp, frame_id="right")
    harness.imu_around(stamp + 3 * MS, pitch_ramp)
    harness.publish_frame(stamp, replace={"right_info": bad})
    assert wait_for(lambda: harness.node.health.problems["implausible input"] == 1, 5.0)
    assert "stereo baseline" in harness.node.health.last_error
    assert wait_for(lambda: "problem.implausible input" in harness.latest_diagnostics(), 3.0)
    harness.wait_output(feed(harness, 1))  # the next good frame is answered


class _Failing:
    name = "failing"
    needs_stereo = True

    def __init__(self, grid: Any) -> None:
        self.grid = grid
        self.calls = 0

    def estimate(self, frame: Any) -> Any:
        self.calls += 1
        if self.calls > 1:  # the warm-up passes, the frames fail
            raise RuntimeError("the accelerator went away")
        from roadbev_core.frame import Estimate

        return Estimate(np.zeros(self.grid.shape, np.float32), np.full(self.grid.shape, 0.01, np.float32))


def test_a_backend_exception_and_a_malformed_tf_are_named_and_the_node_goes_on(ros: Any) -> None:
    from tf2_msgs.msg import TFMessage

    from msg_bridge import RclpyFactory
    from msg_bridge.tf import StaticTransform, tf_message
    from roadbev_ros.node import TF_STATIC_QOS

    h = Harness(ros, backend_factory=lambda name, grid, **options: _Failing(grid))
    try:
        feed(h, 0)
        assert wait_for(lambda: h.node.health.problems["backend error"] == 1, 5.0)
        assert "RuntimeError: the accelerator went away" in h.node.health.last_error
        tf = tf_message([StaticTransform("base_link", "left", np.eye(3), np.zeros(3))], RclpyFactory())
        tf.transforms[0].transform.rotation.w = 0.0  # not a rotation
        h.feeder.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS).publish(tf)
        assert wait_for(lambda: h.node.health.problems["bad tf"] == 1, 5.0)
        feed(h, 1)
        assert wait_for(lambda: h.node.health.problems["backend error"] == 2, 5.0)  # still running
    finally:
        h.close()


@pytest.mark.parametrize("harness", [{"params": {"base_frame": "chassis"}}], indirect=True)
def test_the_body_frame_is_a_parameter(harness: Harness) -> None:
    from tf2_msgs.msg import TFMessage

    from msg_bridge import RclpyFactory
    from msg_bridge.tf import StaticTransform, tf_message
    from roadbev_ros.node import TF_STATIC_QOS

    mount = np.array([1.5, 0.1, 1.3])
    body = harness.feeder.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
    body.publish(tf_message([StaticTransform("chassis", "left", np.eye(3), mount)], RclpyFactory()))
    harness.wait_output(feed(harness, 0))
    assert wait_for(lambda: harness.node.pipeline.camera_mount[1] is not None, 5.0)
    np.testing.assert_allclose(harness.node.pipeline.camera_mount[0], mount)


def _publish_tf(harness: Harness, publisher: Any, transforms: list[Any], stamp_ns: int) -> None:
    """``transforms`` on /tf at ``stamp_ns``, and wait until the node holds them."""
    from msg_bridge import RclpyFactory
    from msg_bridge.tf import tf_message

    publisher.publish(tf_message(transforms, RclpyFactory(), stamp_ns=stamp_ns))
    buffer = harness.node._tf.buffer

    def held() -> bool:
        try:
            return all(np.array_equal(buffer.lookup(t.parent, t.child, stamp_ns)[1], t.translation) for t in transforms)
        except Exception:
            return False

    assert wait_for(held, 5.0), "the node did not receive the /tf"


def test_the_camera_mount_comes_through_a_moving_bracket_on_tf_at_each_frames_stamp(harness: Harness) -> None:
    """base_link -> bracket (/tf_static) -> camera_link (/tf, moving) -> left (/tf_static), over DDS;
    when the bracket's /tf stops, the frame goes on with the last mount and the gap is named."""
    from tf2_msgs.msg import TFMessage

    from msg_bridge import RclpyFactory
    from msg_bridge.tf import StaticTransform, tf_message
    from roadbev_core.geometry import rotation_from_rpy
    from roadbev_ros.node import TF_QOS, TF_STATIC_QOS

    optical = rotation_from_rpy(-np.pi / 2, 0.0, -np.pi / 2)
    static = harness.feeder.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
    dynamic = harness.feeder.create_publisher(TFMessage, "/tf", TF_QOS)
    assert wait_for(lambda: dynamic.get_subscription_count() > 0)
    static.publish(tf_message([StaticTransform("base_link", "bracket", np.eye(3), np.array([1.6, 0.0, 1.0])),
                               StaticTransform("camera_link", "left", optical, np.zeros(3))], RclpyFactory()))

    def bracket_z(t_ns: int) -> float:
        return 0.1 + 0.2 * (t_ns - START_NS) * 1e-9  # the bracket rises 2 cm per frame

    for k in range(3):
        stamp = START_NS + k * FRAME_NS
        for t in (stamp - 30 * MS, stamp + 30 * MS):  # samples around the frame, none at its stamp
            lift = StaticTransform("bracket", "camera_link", np.eye(3), np.array([0.0, 0.0, bracket_z(t)]))
            _publish_tf(harness, dynamic, [lift], t)
        harness.wait_output(feed(harness, k))
        position, rotation = harness.node.pipeline.camera_mount
        np.testing.assert_allclose(position, [1.6, 0.0, 1.0 + bracket_z(stamp)], atol=1e-9)  # interpolated
        assert rotation is not None
        np.testing.assert_allclose(rotation, optical, atol=1e-9)
    assert harness.node.health.problems["tf missing"] == 0
    harness.wait_output(feed(harness, 5))  # 170 ms after the bracket's last /tf: beyond tf_tolerance_s
    assert harness.node.health.problems["tf missing"] == 1
    error = harness.node.health.last_error
    assert error.startswith("tf missing: no transform base_link -> left for the camera mount: Lookup would require "
                            "extrapolation into the future."), error
    assert error.endswith("the frame goes on with the mount last taken from /tf ([1.6, 0.0, 1.14] m)")
    assert wait_for(lambda: "problem.tf missing" in harness.latest_diagnostics(), 3.0)
    assert harness.latest_diagnostics()["camera_mount"] == "/tf base_link -> left at [1.6, 0.0, 1.14] m"


@pytest.mark.parametrize("harness", [{"params": {"odom_topic": "", "odom_from_tf": True}}], indirect=True)
def test_odom_from_tf_builds_the_fused_map_from_the_tf_odometry(harness: Harness) -> None:
    from tf2_msgs.msg import TFMessage

    from msg_bridge.tf import StaticTransform
    from roadbev_ros.node import TF_QOS

    dynamic = harness.feeder.create_publisher(TFMessage, "/tf", TF_QOS)
    assert wait_for(lambda: dynamic.get_subscription_count() > 0)
    for k in range(5):
        for j in (k, k + 1):  # the sample after the frame's stamp too: the node waits for it
            pose = StaticTransform("odom", "base_link", np.eye(3), np.array([1.0 * j, 0.0, 0.0]))  # 10 m/s
            _publish_tf(harness, dynamic, [pose], START_NS + j * FRAME_NS)
        harness.wait_output(feed(harness, k))
    assert harness.node._fused == 5 and harness.node.pipeline.ego.newest is not None
    assert harness.node.pipeline.ego.newest.speed == pytest.approx(10.0)
    assert harness.node.health.problems["tf missing"] == 0


def test_the_far_field_is_published_on_its_own_topic_only_when_on(ros: Any) -> None:
    """far_field.enabled: a second GridMap (same layers, the far-field grid) on /roadbev/elevation_far;
    the grid's own map is unchanged, and without it the topic is not even advertised."""
    from grid_map_msgs.msg import GridMap

    from msg_bridge.grid_map import grid_map_to_arrays
    from roadbev_core.config import GridSpec

    from ._ros_harness import PitchBackend

    class FarPitch(PitchBackend):
        far_field = True

    def factory(name: str, grid: Any, **options: Any) -> Any:
        return FarPitch(grid, name=f"stub-{name}")

    params = {"far_field.enabled": True, "far_field.x_max": 4.56}  # beyond the small grid (x to 3.36 m)
    h = Harness(ros, params=params, backend_factory=factory)
    received: list[Any] = []
    try:
        h.feeder.create_subscription(GridMap, "/roadbev/elevation_far", received.append, h._spun.qos)
        assert wait_for(lambda: h.node._out._far is not None and h.node._out._far.get_subscription_count() > 0)
        stamp = feed(h, 0)
        near = h.wait_output(stamp)
        assert wait_for(lambda: len(received) == 1)
        far = grid_map_to_arrays(received[0])
        assert far.grid == GridSpec(x_min=3.36, x_max=4.56, resolution=0.12)  # horizontal extent from the info
        assert far.stamp_ns == stamp and far.frame_id == near.header.frame_id
        assert list(received[0].layers) == ["elevation", "uncertainty"] == list(near.layers)
        assert grid_map_to_arrays(near).grid.shape == (40, 64)
        assert h.node._status.health.far_field == "on"
    finally:
        h.close()
    off = Harness(ros, params={"far_field.enabled": False})
    try:
        assert off.node._out._far is None and off.node._status.health.far_field == "off"
    finally:
        off.close()
    # asked for with a backend that has none: the node runs the grid and says why on /diagnostics
    without = Harness(ros, params=params)
    try:
        state = without.node._status.health.far_field
        assert state.startswith("off: backend 'stub") and "does not estimate the far field" in state, state
        assert without.node.pipeline.config.far_grid is None
        stamp = feed(without, 0)
        assert without.wait_output(stamp).header.stamp is not None
    finally:
        without.close()
