"""Evaluation bags: writing a drive, reading it back into frames + truth, bags from elsewhere; the far field's
truth, and roadbev eval's code scoring it."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from msg_bridge import BagError, BagWriter, bag_factory, bag_topics, read_messages
from msg_bridge.camera_info import camera_info_from_stereo
from msg_bridge.grid_map import grid_map_message
from msg_bridge.image import array_to_image
from msg_bridge.imu import imu_message
from roadbev_core.config import FarFieldConfig, GridSpec, ImuConfig, RoadbevConfig, StereoCamera, TopicsConfig
from roadbev_core.frame import Frame
from roadbev_core.labels import ElevationLabel
from roadbev_lab.evaluation.evalbag import (
    FAR_GROUND_TRUTH_TOPIC,
    BagTopics,
    bag_frames,
    grid_fields,
    read_eval_bag,
    write_eval_bag,
)
from roadbev_lab.evaluation.offline import OfflineEvalError, prepare_bag, run_prepared
from roadbev_lab.synth import DriveConfig
from tests.msg_bridge._msg_bridge_fakes import FakeConfig, FakeDrive

RAW_TOPICS = {
    "/roadbev/grid_config": 1,
    "/stereo/left/image_rect": 4,
    "/stereo/right/image_rect": 4,
    "/stereo/left/camera_info": 4,
    "/stereo/right/camera_info": 4,
    "/imu/data": 71,  # 100 Hz from 50 ms before the first frame to 50 ms after the last (0.7 s)
    "/ground_truth/elevation": 4,
}


def test_raw_bag_round_trip(tmp_path: Path, fake_drive: FakeDrive) -> None:
    path = tmp_path / "drive.mcap"
    counts = write_eval_bag(path, fake_drive, compression="none")
    assert counts == RAW_TOPICS
    assert {t: i.count for t, i in bag_topics(path).items()} == RAW_TOPICS
    bag = read_eval_bag(path)
    assert len(bag) == 4 and bag.stereo and not bag.compressed
    assert bag.grid == fake_drive.config.grid
    assert bag.camera == fake_drive.config.camera
    assert bag.skipped == {} and bag.notes == []
    originals = list(fake_drive)
    samples = list(bag)
    assert [s.inputs.stamp_ns for s in samples] == fake_drive.stamps()
    _, frames = bag_frames(path)
    for sample, (frame, _), original in zip(samples, frames, originals, strict=True):
        np.testing.assert_array_equal(sample.inputs.left, original.frame.left)
        np.testing.assert_array_equal(sample.inputs.right, original.frame.right)
        np.testing.assert_array_equal(sample.truth, original.truth.elevation)
        assert frame.attitude.roll == pytest.approx(original.frame.attitude.roll, abs=1e-9)
        assert frame.attitude.pitch == pytest.approx(original.frame.attitude.pitch, abs=1e-9)


def test_imu_is_interpolated_to_stamps_between_samples(tmp_path: Path) -> None:
    # frames at 5 Hz starting 3 ms off the 100 Hz IMU grid: every attitude needs slerp
    drive = FakeDrive(replace(FakeConfig(), start_stamp_ns=1_700_000_000_003_000_000, frames=3))
    write_eval_bag(tmp_path / "d.mcap", drive)
    _, frames = bag_frames(tmp_path / "d.mcap")
    assert len(frames) == 3
    for frame, _ in frames:
        truth = drive.attitude_at(frame.stamp_ns)
        assert frame.attitude.pitch == pytest.approx(truth.pitch, abs=2e-5)
        assert frame.attitude.roll == pytest.approx(truth.roll, abs=2e-5)
    # the pipeline, fed the bag's IMU as live, computes the same attitudes
    from roadbev_core.config import RoadbevConfig
    from roadbev_core.pipeline import replay
    from roadbev_lab.evaluation.frames import pipeline_for

    bag = read_eval_bag(tmp_path / "d.mcap")

    class Recorder:
        name, needs_stereo, grid = "bm", True, bag.grid

        def __init__(self) -> None:
            self.attitudes: list[tuple[float, float]] = []

        def estimate(self, frame):  # type: ignore[no-untyped-def]
            from roadbev_core.frame import Estimate

            self.attitudes.append((frame.attitude.roll, frame.attitude.pitch))
            nan = np.full(bag.grid.shape, np.nan, np.float32)
            return Estimate(nan, nan.copy())

    backend = Recorder()
    pipeline = pipeline_for(backend, RoadbevConfig())
    for _ in replay(pipeline, bag, bag.imu, inputs_of=lambda s: s.inputs):
        pass
    assert backend.attitudes == [(f.attitude.roll, f.attitude.pitch) for f, _ in frames]


def test_compressed_bag_and_grid_config(tmp_path: Path, fake_drive: FakeDrive) -> None:
    path = tmp_path / "compressed"
    counts = write_eval_bag(path, fake_drive, compressed=True, jpeg_quality=95)
    assert counts["/stereo/left/image_rect/compressed"] == 4
    assert (path / "metadata.yaml").is_file()
    bag = read_eval_bag(path)
    assert bag.compressed and bag.topics.left_image == "/stereo/left/image_rect/compressed"
    assert bag.topics == BagTopics.of(TopicsConfig(), compressed=True)
    sample = next(iter(bag))
    assert sample.inputs.left.shape == (48, 64, 3)
    config = json.loads(next(read_messages(path, ["/roadbev/grid_config"])).msg.data)
    assert config["grid"] == fake_drive.config.grid.to_dict()
    assert config["camera"]["baseline"] == pytest.approx(0.12)
    assert config["drive"]["frames"] == 4


def test_the_independent_reader_decodes_an_eval_bag(tmp_path: Path, fake_drive: FakeDrive) -> None:
    write_eval_bag(tmp_path / "d.mcap", fake_drive, compressed=True)
    with (tmp_path / "d.mcap").open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        topics = [channel.topic for _, channel, _, _ in reader.iter_decoded_messages()]
    assert len(topics) == sum(RAW_TOPICS.values())
    assert topics[0] == "/roadbev/grid_config"


def test_the_grid_fields_among_the_parameters() -> None:
    params = {"base_height": 1.5, "x_min": 1, "imu_max_age_s": 0.05, "left_image_topic": "/cam/left"}
    assert grid_fields(params) == {"base_height": 1.5, "x_min": 1.0}


def test_params_set_base_height_extrinsic_and_topics(tmp_path: Path, fake_drive: FakeDrive) -> None:
    write_eval_bag(tmp_path / "d.mcap", fake_drive)
    grid = {"base_height": 1.5, "z_min": -0.3, "z_max": 0.3}
    grid |= {"x_min": 1.0}  # horizontal: the ground truth's info wins
    bag = read_eval_bag(tmp_path / "d.mcap", grid_overrides=grid)
    assert (bag.grid.base_height, bag.grid.z_min, bag.grid.n_rows) == (1.5, -0.3, 164)
    assert any("horizontal grid parameters ignored" in n for n in bag.notes)
    imu = ImuConfig(imu_to_camera_rpy_deg=(0.0, 2.0, 0.0))
    first = bag_frames(tmp_path / "d.mcap", imu=imu, grid_overrides=grid)[1][0].frame
    assert first.attitude.degrees[1] == pytest.approx(np.degrees(0.03) + 2.0, abs=1e-6)
    with pytest.raises(BagError, match="no left images"):
        read_eval_bag(tmp_path / "d.mcap", TopicsConfig(left_image="/cam/left"))
    with pytest.raises(BagError, match="grid parameters are invalid"):
        read_eval_bag(tmp_path / "d.mcap", grid_overrides={"base_height": 0.1})


def _foreign_bag(path: Path, *, stereo: bool, truth_grid: GridSpec | None, imu_span: tuple[int, int]) -> list[int]:
    """A bag as another tool might record it: mono or stereo, one CameraInfo, sparse IMU."""
    f = bag_factory()
    camera = FakeConfig().camera
    stamps = [10_000_000_000 + i * 100_000_000 for i in range(5)]
    with BagWriter(path) as bag:
        bag.add_topic("/stereo/left/image_rect", "sensor_msgs/msg/Image")
        bag.add_topic("/stereo/left/camera_info", "sensor_msgs/msg/CameraInfo")
        bag.add_topic("/imu/data", "sensor_msgs/msg/Imu")
        if stereo:
            bag.add_topic("/stereo/right/image_rect", "sensor_msgs/msg/Image")
            bag.add_topic("/stereo/right/camera_info", "sensor_msgs/msg/CameraInfo")
            bag.write("/stereo/right/camera_info", camera_info_from_stereo(camera, f, right=True), 1)
        if truth_grid is not None:
            bag.add_topic("/ground_truth/elevation", "grid_map_msgs/msg/GridMap")
        bag.write("/stereo/left/camera_info", camera_info_from_stereo(camera, f, stamp_ns=1), 1)
        for stamp in range(imu_span[0], imu_span[1] + 1, 50_000_000):
            bag.write("/imu/data", imu_message(f, stamp_ns=stamp, orientation_xyzw=(0, 0.0499792, 0, 0.9987503)), stamp)
        for i, stamp in enumerate(stamps):
            pixels = np.full((48, 64), i * 10, np.uint8)
            bag.write("/stereo/left/image_rect", array_to_image(pixels, f, stamp_ns=stamp), stamp)
            if stereo and i != 2:  # the right image of frame 2 was dropped
                bag.write("/stereo/right/image_rect", array_to_image(pixels, f, stamp_ns=stamp), stamp)
            if truth_grid is not None and i % 2 == 0:
                gt = grid_map_message({"elevation": np.full(truth_grid.shape, 0.01 * i)}, truth_grid, f, stamp_ns=stamp)
                bag.write("/ground_truth/elevation", gt, stamp)
    return stamps


def test_a_foreign_stereo_bag_with_another_window(tmp_path: Path) -> None:
    window = GridSpec(x_min=3.0, x_max=9.0, y_min=-1.5, y_max=1.5, resolution=0.06)
    imu_span = (9_900_000_000, 10_300_000_000)  # ends 100 ms before the last frame
    stamps = _foreign_bag(tmp_path / "f.mcap", stereo=True, truth_grid=window, imu_span=imu_span)
    bag = read_eval_bag(tmp_path / "f.mcap")
    assert bag.grid.shape == window.shape and bag.grid.x_min == 3.0 and bag.grid.base_height == 1.1
    # frame 2 lacks its right image; frame 4 lies 100 ms after the last IMU sample (limit 0.1 s ok)
    assert bag.stamps == [stamps[0], stamps[1], stamps[3], stamps[4]]
    assert bag.skipped == {"no right image with the same stamp": 1}
    samples = list(bag)
    assert [s.truth is not None for s in samples] == [True, False, False, True]
    assert samples[0].inputs.left.ndim == 2  # mono8 images stay grey
    truth = samples[3].truth
    assert truth is not None and truth[0, 0] == pytest.approx(0.04)
    _, frames = bag_frames(tmp_path / "f.mcap")
    assert len(frames) == 4 and frames[1].frame.attitude.pitch == pytest.approx(0.1, abs=1e-6)
    # with a stricter age limit, the frame 100 ms after the last IMU sample has no attitude
    _, strict = bag_frames(tmp_path / "f.mcap", imu=ImuConfig(max_age_s=0.05))
    assert [f.frame.stamp_ns for f in strict] == [stamps[0], stamps[1], stamps[3]]


def test_a_mono_bag_without_ground_truth(tmp_path: Path) -> None:
    _foreign_bag(tmp_path / "m.mcap", stereo=False, truth_grid=None, imu_span=(9_000_000_000, 11_000_000_000))
    bag = read_eval_bag(tmp_path / "m.mcap", grid_overrides={"x_min": 3.0, "x_max": 6.0})
    assert not bag.stereo and len(bag) == 5 and bag.camera.baseline == 0.0
    assert (bag.grid.x_min, bag.grid.x_max) == (3.0, 6.0)
    assert all(s.truth is None and s.inputs.right is None for s in bag)


def test_a_bag_without_imu_has_no_frame_with_an_attitude(tmp_path: Path) -> None:
    _foreign_bag(tmp_path / "n.mcap", stereo=False, truth_grid=None, imu_span=(0, -1))
    bag = read_eval_bag(tmp_path / "n.mcap")
    assert bag.imu == [] and any("no IMU orientation" in n for n in bag.notes)
    _, frames = bag_frames(tmp_path / "n.mcap")
    assert frames == []


def test_evaluation_bags_feed_the_models() -> None:
    import torch

    from roadbev_core.models.presets import model_config
    from roadbev_lab.evaluation.evalbag import bag_frames
    from roadbev_lab.training.datasets import LabelledFrames, ModelInputs

    bag = Path(__file__).resolve().parents[3] / "bags" / "sample_drive.mcap"
    source = LabelledFrames(*bag_frames(bag), what=str(bag))
    assert len(source) == 20 and source.grid.shape == (164, 64)
    item = ModelInputs(source, model_config("tiny", "mono"), source.grid)[0]
    assert item["left"].shape == (3, 128, 224) and "right" not in item and "grey" not in item
    assert torch.isfinite(item["elevation"]).float().mean() > 0.5


# --- the far field ----------------------------------------------------------------------------
FAR = FarFieldConfig(enabled=True).grid(GridSpec())


@dataclass(frozen=True)
class FarConfig(FakeConfig):
    far_grid: GridSpec | None = field(default=FAR)


class FarSample(NamedTuple):
    frame: Frame
    truth: ElevationLabel
    points_road: np.ndarray
    far_truth: ElevationLabel | None


class FarDrive(FakeDrive):
    """The fake drive with a far-field truth per frame (a ramp along x, the first column unlabelled)."""

    def __iter__(self) -> Iterator[FarSample]:  # type: ignore[override]
        grid = getattr(self.config, "far_grid", None)
        for sample in super().__iter__():
            far = None
            if grid is not None:
                heights = np.broadcast_to(0.01 * (grid.x_centres() - 7.0)[:, None], grid.shape).astype(np.float32)
                heights = heights.copy()
                heights[:, 0] = np.nan
                far = ElevationLabel(heights, np.isfinite(heights), np.isfinite(heights).astype(np.int32))
            yield FarSample(sample.frame, sample.truth, sample.points_road, far)


def _grid_config(path: Path) -> dict[str, object]:
    (item,) = list(read_messages(path, ["/roadbev/grid_config"]))
    return dict(json.loads(item.msg.data))


def test_the_far_field_truth_is_written_and_read_back(tmp_path: Path) -> None:
    drive = FarDrive(FarConfig())
    path = tmp_path / "far.mcap"
    counts = write_eval_bag(path, drive, compression="none")
    assert counts[FAR_GROUND_TRUTH_TOPIC] == counts["/ground_truth/elevation"] == 4
    described = _grid_config(path)
    assert described["far_grid"] == FAR.to_dict()
    bag = read_eval_bag(path)
    assert bag.far_grid == FAR and bag.grid == GridSpec()
    for sample, original in zip(bag, drive, strict=True):
        assert original.far_truth is not None and sample.far_truth is not None
        np.testing.assert_array_equal(sample.far_truth, original.far_truth.elevation)
        np.testing.assert_array_equal(sample.truth, original.truth.elevation)


def test_a_drive_without_a_far_field_writes_the_bag_as_before(tmp_path: Path) -> None:
    camera = StereoCamera(50.0, 50.0, 31.5, 23.5, 0.12, 64, 48)
    config = DriveConfig(frames=2, camera=camera)
    path = tmp_path / "near.mcap"
    write_eval_bag(path, FarDrive(config), compression="none")  # type: ignore[arg-type]
    assert FAR_GROUND_TRUTH_TOPIC not in bag_topics(path)
    described = _grid_config(path)
    assert "far_grid" not in described and "far_grid" not in described["drive"]  # type: ignore[operator]
    assert read_eval_bag(path).far_grid is None and next(iter(read_eval_bag(path))).far_truth is None
    with_far = tmp_path / "with_far.mcap"
    write_eval_bag(with_far, FarDrive(replace(config, far_grid=FAR)), compression="none")  # type: ignore[arg-type]
    assert _grid_config(with_far)["drive"]["far_grid"] == FAR.to_dict()  # type: ignore[index]


def test_roadbev_eval_turns_the_far_field_on_for_a_bag_with_its_truth(tmp_path: Path) -> None:
    path = tmp_path / "far.mcap"
    write_eval_bag(path, FarDrive(FarConfig()), compression="none")
    prepared = prepare_bag(path, RoadbevConfig.from_params({"backend": "bm", "require_imu": False}))
    assert prepared.config.far_grid == FAR and prepared.pipeline.far_backend is not None
    metrics = run_prepared(prepared).metrics
    far = metrics["far_field"]
    assert far["estimated"] and far["grid"] == FAR.to_dict() and far["frames_with_truth"] == 4
    assert far["labelled_cells"] == 4 * FAR.n_rows * (FAR.n_cols - 1) and len(far["bands"]) == 8
    # a backend that does not estimate the far field: the grid is evaluated, the key says why not
    refused = prepare_bag(path, RoadbevConfig.from_params({"backend": "bev_sweep", "require_imu": False}))
    assert refused.config.far_grid is None and refused.pipeline.far_backend is None
    assert "does not estimate the far field" in refused.far_refused
    key = run_prepared(refused, max_frames=1).metrics["far_field"]
    assert key == {"estimated": False, "reason": refused.far_refused, "grid": FAR.to_dict()}


def test_a_far_field_truth_that_does_not_continue_the_grid_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "gap.mcap"
    gap = GridSpec(x_min=8.04, x_max=15.0, resolution=0.12, z_min=-0.5, z_max=0.5)
    write_eval_bag(path, FarDrive(FarConfig(far_grid=gap)), compression="none")
    assert read_eval_bag(path).far_grid == gap
    with pytest.raises(OfflineEvalError, match="does not start at the grid's far edge"):
        prepare_bag(path, RoadbevConfig.from_params({"backend": "bm"}))
