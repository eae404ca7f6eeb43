"""``roadbev label`` on a bag built from the real KITTI object frame (image pair, one Velodyne scan).

The bag holds what a recording would: the stereo pair, CameraInfos from ``calib.txt`` (P2/P3),
``lidar.bin`` as a PointCloud2 in the ``velodyne`` frame, ``/tf_static`` with the Velodyne ->
left optical transform from ``Tr_velo_to_cam`` and ``R0_rect``, and an IMU sample whose attitude
is the one fitted on the scan's ground. The labels must agree with a direct projection of the scan.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_core.geometry import camera_to_road, rotation_from_rpy
from roadbev_core.labels import elevation_map

STAMP = 1_317_000_000_000_000_000


@pytest.fixture(scope="module")
def kitti_frame(kitti_dir: Path):  # type: ignore[no-untyped-def]
    from roadbev_lab.data.kitti import fit_road_pose, load_frames

    frame = next(f for f in load_frames(kitti_dir) if f.points_frame == "velodyne")
    window = GridSpec(x_min=6.5, x_max=18.5, y_min=-2.0, y_max=2.0, resolution=0.1, base_height=1.65)
    pose = fit_road_pose(frame.points @ frame.rotation.T + frame.translation, window)
    return frame, pose


def _write(path: Path, frame, pose, *, tf: bool = True, scan: np.ndarray | None = None) -> None:  # type: ignore[no-untyped-def]
    from msg_bridge.tf import StaticTransform, quaternion_from_rotation
    from roadbev_lab.data.labelbag import RecordedFrame, write_recording

    q = quaternion_from_rotation(rotation_from_rpy(pose.attitude.roll, pose.attitude.pitch, 0.0))
    transforms = [StaticTransform("stereo_left_optical_frame", "velodyne", frame.rotation, frame.translation)]
    write_recording(
        path,
        frame.camera,
        [RecordedFrame(STAMP, frame.left, frame.right)],
        imu=[(STAMP, q)],
        scans=[(STAMP, "velodyne", frame.points if scan is None else scan)],
        static_transforms=transforms if tf else (),
    )


def _params(path: Path, base_height: float, extra: str = "") -> Path:
    path.write_text(
        "/**:\n  ros__parameters:\n"
        f"    base_height: {base_height:.4f}\n    x_min: 6.5\n    x_max: 18.5\n    y_min: -2.0\n    y_max: 2.0\n"
        f"    resolution: 0.1\n{extra}"
    )
    return path


def test_kitti_scan_labels_agree_with_a_direct_projection(kitti_frame, kitti_dir: Path, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from roadbev_cli.cli import main
    from roadbev_lab.data.kitti import read_calib
    from roadbev_lab.evaluation.evalbag import read_eval_bag

    frame, pose = kitti_frame
    src, out = tmp_path / "drive.mcap", tmp_path / "labelled.mcap"
    _write(src, frame, pose)
    params = _params(tmp_path / "p.yaml", pose.base_height)
    assert main(["label", str(src), str(out), "--params", str(params), "--quiet"]) == 0
    bag = read_eval_bag(out)
    assert len(bag) == 1
    grid = bag.grid
    assert grid.shape == (120, 40) and grid.base_height == pytest.approx(pose.base_height, abs=1e-4)
    (sample,) = list(bag)
    label = sample.truth
    assert sample.inputs.left.shape == frame.left.shape
    # The direct projection, from the calibration file itself: p_cam2 = R0 (Tr p) + P2 offset.
    calib = read_calib(kitti_dir / "stereo_rcnn_demo" / "demo" / "calib.txt")
    tr, r0, p2 = calib["Tr_velo_to_cam"], calib["R0_rect"], calib["P2"]
    cam = (frame.points @ tr[:, :3].T + tr[:, 3]) @ r0.T + np.linalg.solve(p2[:, :3], p2[:, 3])
    direct = elevation_map(camera_to_road(cam, pose.attitude, grid.base_height), grid, clip_z=True)
    assert label is not None
    labelled = np.isfinite(label)
    assert labelled.sum() > 0.1 * labelled.size  # one scan: ring-shaped stripes, about 18 % of the cells
    assert not (labelled & ~direct.mask).any()  # labels only where the scan has points
    diff = np.abs(label[labelled] - direct.elevation[labelled])
    # Cells where the road-surface test dropped nothing are the direct mean exactly.
    assert np.mean(diff < 1e-4) > 0.9
    assert np.median(np.abs(label[labelled])) < 0.05  # the road lies on the fitted plane


def test_missing_extrinsic_is_a_clear_error(kitti_frame, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from roadbev_cli.cli import main

    frame, pose = kitti_frame
    src = tmp_path / "no_tf.mcap"
    _write(src, frame, pose, tf=False)
    params = _params(tmp_path / "p.yaml", pose.base_height)
    assert main(["label", str(src), str(tmp_path / "o.mcap"), "--params", str(params), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "no extrinsic for the LiDAR frame 'velodyne'" in err and "/tf_static" in err
    assert not (tmp_path / "o.mcap").exists()
    # The same bag with the extrinsic as a parameter (x, y, z, roll, pitch, yaw of the LiDAR in
    # the optical frame) labels.
    R = frame.rotation  # = Rz(yaw) Ry(pitch) Rx(roll)
    rpy = np.degrees([np.arctan2(R[2, 1], R[2, 2]), -np.arcsin(R[2, 0]), np.arctan2(R[1, 0], R[0, 0])])
    xyz = ", ".join(f"{v:.6f}" for v in [*frame.translation, *rpy])
    params = _params(
        tmp_path / "p2.yaml", pose.base_height, f"    label:\n      lidar_extrinsic_xyz_rpy_deg: [{xyz}]\n"
    )
    assert main(["label", str(src), str(tmp_path / "o2.mcap"), "--params", str(params), "--quiet"]) == 0


def test_empty_scan_and_bad_params_are_clear_errors(kitti_frame, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from roadbev_cli.cli import main

    frame, pose = kitti_frame
    src = tmp_path / "empty.mcap"
    _write(src, frame, pose, scan=np.zeros((0, 3)))
    params = _params(tmp_path / "p.yaml", pose.base_height)
    assert main(["label", str(src), str(tmp_path / "o.mcap"), "--params", str(params), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "no frame got a label" in err and "empty scans" in err
    bad = _params(tmp_path / "bad.yaml", pose.base_height, "    label:\n      windw_s: 1.0\n")
    assert main(["label", str(src), str(tmp_path / "o.mcap"), "--params", str(bad), "--quiet"]) == 2
    assert "unknown parameter 'label.windw_s'" in capsys.readouterr().err
    accumulate = _params(tmp_path / "acc.yaml", pose.base_height, "    label:\n      window_s: 0.5\n")
    assert main(["label", str(src), str(tmp_path / "o.mcap"), "--params", str(accumulate), "--quiet"]) == 2
    assert "needs odometry" in capsys.readouterr().err


def test_many_bags_are_labelled_into_a_folder_with_one_summary(kitti_frame, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    from roadbev_cli.cli import main
    from roadbev_lab.evaluation.evalbag import read_eval_bag

    frame, pose = kitti_frame
    drives = tmp_path / "drives"
    drives.mkdir()
    _write(drives / "a.mcap", frame, pose)
    _write(drives / "b.mcap", frame, pose, scan=frame.points[::2])  # another drive: half the points
    (drives / "c.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00garbage" * 50)  # a corrupt one
    params = _params(tmp_path / "p.yaml", pose.base_height)
    out = tmp_path / "labelled"
    args = ["label", str(drives), str(out), "--params", str(params), "--workers", "1", "--no-progress"]
    assert main(args) == 2
    captured = capsys.readouterr()
    assert "1 of 3 bag(s) failed" in captured.err and "c.mcap" in captured.err
    summary = json.loads((out / "summary.json").read_text())
    assert [b["status"] for b in summary["bags"]] == ["done", "done", "failed"]
    one = tmp_path / "one.mcap"
    assert main(["label", str(drives / "a.mcap"), str(one), "--params", str(params), "--quiet"]) == 0
    alone, many = next(iter(read_eval_bag(one))).truth, next(iter(read_eval_bag(out / "a.mcap"))).truth
    assert alone is not None and many is not None
    assert np.array_equal(alone, many, equal_nan=True)  # the one-bag labels
    results = [b["result"] for b in summary["bags"][:2]]
    pooled = summary["pooled"]
    assert pooled["frames"] == 2 and pooled["scans"] == sum(r["scans"] for r in results) and pooled["bags"] == 2
    assert pooled["mean_labelled_pct"] == pytest.approx(sum(r["mean_labelled_pct"] for r in results) / 2)
    assert "| **pooled, 2 bag(s)** |" in (out / "report.md").read_text()
    assert not list(out.glob(".*.partial*"))
    # again: the two labelled bags are done; a removed output is labelled again
    (out / "b.mcap").unlink()
    assert main(args) == 2
    capsys.readouterr()
    again = json.loads((out / "summary.json").read_text())
    assert [b["status"] for b in again["bags"]] == ["stored", "done", "failed"]
