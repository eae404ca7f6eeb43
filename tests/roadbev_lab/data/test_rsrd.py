"""The RSRD layout loader on a tiny fixture written in that exact layout."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, road_to_camera, rsrd_camera_attitude
from roadbev_lab.data.rsrd import RsrdError, RsrdSet, load_calibration, read_pcd

# The real RSRD half-resolution calibration of 2023-03-17 (the authors' calib_20230317_half.pkl).
K = np.array([[1004.77867, 0.0, 498.22071], [0.0, 1004.77867, 259.51755], [0.0, 0.0, 1.0]])
R = np.array([[-0.99998663, -0.00415487, 0.00307773], [-0.00322037, 0.0347713, -0.99939011],
              [0.00404532, -0.99938666, -0.03478422]])
T = np.array([[0.00140258], [0.07049493], [-0.02065174]])
GRID = GridSpec()
PLANE_Z = 0.035  # the fixture's road lies 3.5 cm above the reference plane


def _write_pcd(path: Path, xyz: np.ndarray, binary: bool) -> None:
    n = len(xyz)
    intensity = np.arange(n, dtype=np.float32)
    header = ("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\n"
              f"TYPE F F F F\nCOUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n"
              f"DATA {'binary' if binary else 'ascii'}\n")
    records = np.column_stack([xyz.astype(np.float32), intensity])
    if binary:
        path.write_bytes(header.encode() + records.astype("<f4").tobytes())
    else:
        body = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in records)
        path.write_text(header + body + "\n")


def _assert_same_rig(got: StereoCamera, expected: StereoCamera) -> None:
    assert got.size == expected.size
    np.testing.assert_allclose([got.fx, got.fy, got.cx, got.cy, got.baseline],
                               [expected.fx, expected.fy, expected.cx, expected.cy, expected.baseline], atol=1e-3)


@pytest.fixture(scope="module")
def rsrd_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("rsrd")
    calib = {"K": K, "B": 118.809, "R": R, "T": T, "Width": 960, "Height": 540}
    (root / "calib_20230317_half.pkl").write_bytes(pickle.dumps(calib))
    samples: list[dict[str, Any]] = [
        {"time": "20230317074850.000", "path": "dense/2023-03-17-07-48-37", "pitch": 18.45, "roll": 1.23, "yaw": 90.7},
        {"time": "20230317074850.200", "path": "dense/2023-03-17-07-48-37", "pitch": 17.9, "roll": -0.8, "yaw": 90.1},
    ]
    (root / "info.pkl").write_bytes(pickle.dumps(samples))
    seq = root / "train" / "2023-03-17-07-48-37"
    for sub in ("left_half", "right_half", "pcd"):
        (seq / sub).mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i, sample in enumerate(samples):
        image = np.zeros((540, 960, 3), np.uint8)
        image[:528] = (10, 20, 200)  # BGR red above the crop line
        image[528:] = (0, 255, 0)  # the 12 bottom rows (bonnet) are cropped away
        for sub in ("left_half", "right_half"):
            cv2.imwrite(str(seq / sub / f"{sample['time']}.jpg"), image)
        attitude = rsrd_camera_attitude(sample["roll"], sample["pitch"], R)
        road = np.column_stack([rng.uniform(2.0, 7.2, 60000), rng.uniform(-1.0, 1.1, 60000), np.full(60000, PLANE_Z)])
        cam = road_to_camera(road, attitude, GRID.base_height)
        lidar = (cam - T.reshape(1, 3)) @ R  # inverse of p_cam = R p_lidar + T
        _write_pcd(seq / "pcd" / f"{sample['time']}.pcd", lidar, binary=bool(i))
    return root


def test_pcd_reader_reads_ascii_and_binary_alike(tmp_path: Path) -> None:
    xyz = np.array([[1.0, 2.0, 3.0], [-4.5, 0.25, 7.0], [np.nan, 0.0, 0.0]])
    for binary in (False, True):
        path = tmp_path / f"p{binary}.pcd"
        _write_pcd(path, xyz, binary)
        np.testing.assert_allclose(read_pcd(path), xyz[:2], rtol=1e-6)
    truncated = tmp_path / "cut.pcd"
    truncated.write_bytes((tmp_path / "pTrue.pcd").read_bytes()[:-5])
    with pytest.raises(RsrdError, match="truncated"):
        read_pcd(truncated)
    with pytest.raises(RsrdError, match="DATA"):
        (tmp_path / "bad.pcd").write_text("VERSION 0.7\nFIELDS x y z\n")
        read_pcd(tmp_path / "bad.pcd")


def test_samples_come_cropped_with_attitude_and_labels(rsrd_root: Path) -> None:
    data = RsrdSet(rsrd_root, "train", [rsrd_root / "info.pkl"], [rsrd_root / "calib_20230317_half.pkl"])
    assert len(data) == 2
    for i in range(2):
        frame, truth = data[i]
        assert frame.left.shape == (528, 960, 3) and frame.right is not None
        _assert_same_rig(frame.camera, StereoCamera.rsrd_half())  # the paper's crop of the real rig
        top = frame.left[:520]  # JPEG blurs the last rows into the (cropped) bonnet below
        assert np.all(top[:, :, 0] > 150) and np.all(top[:, :, 1] < 80)  # RGB order
        assert frame.left[-1, :, 1].mean() < 200  # the bright green bonnet rows are gone
        sample = data.samples[i]
        expected: Attitude = rsrd_camera_attitude(sample["roll"], sample["pitch"], R)
        assert frame.attitude == expected
        assert 17 < np.degrees(frame.attitude.pitch) < 22  # LiDAR pitch + ~2 deg of extrinsics
        assert np.isfinite(truth).mean() > 0.95
        np.testing.assert_allclose(truth[np.isfinite(truth)], PLANE_Z, atol=1e-4)
    assert data[1][0].stamp_ns - data[0][0].stamp_ns == 200_000_000


def test_loader_reports_missing_or_foreign_files(rsrd_root: Path, tmp_path: Path) -> None:
    with pytest.raises(RsrdError, match="no calibration"):
        RsrdSet(rsrd_root, "train", [rsrd_root / "info.pkl"], [])
    (tmp_path / "calib_20230317_half.pkl").write_bytes(pickle.dumps({"K": K}))
    with pytest.raises(RsrdError, match="not an RSRD calibration"):
        load_calibration(tmp_path / "calib_20230317_half.pkl")
    data = RsrdSet(rsrd_root, "test", [rsrd_root / "info.pkl"], [rsrd_root / "calib_20230317_half.pkl"])
    with pytest.raises(RsrdError, match="not found"):
        data[0]


def test_real_rsrd_calibration_gives_the_configured_rig(rsrd_dir: Path) -> None:
    calib = load_calibration(rsrd_dir / "calib_20230317_half.pkl")
    _assert_same_rig(calib.camera, StereoCamera.rsrd_half())
    assert abs(calib.camera.baseline - 0.118809) < 1e-9
