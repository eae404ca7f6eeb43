"""The real RSRD dataset layout (Road Surface Reconstruction Dataset, Tsinghua, 2024).

On disk::

    <root>/<split>/<sequence>/left_half/<time>.jpg     960 x 540 rectified left image
    <root>/<split>/<sequence>/right_half/<time>.jpg    right image
    <root>/<split>/<sequence>/pcd/<time>.pcd           LiDAR point cloud (LiDAR frame)

plus, from the authors' release, ``calib_<YYYYMMDD>_half.pkl`` per recording day (``K``, ``B``
baseline in millimetres, ``R``/``T`` LiDAR -> left camera, ``Width``, ``Height``) and
``sample_info/<split>/*.pkl`` (lists of dicts: ``time``, ``path``, ``pitch``, ``roll``, ...).

Pickle runs code while it loads, so this module opens only the calibration and sample-info files
the caller names explicitly (never a path found by searching); pass only files you trust, such
as the authors' own release.

Each sample becomes a :class:`Frame` cropped to the paper's 960 x 528 (rows 0..527, see
:meth:`StereoCamera.rsrd_half`), the camera attitude from the LiDAR attitude and extrinsics
(:func:`rsrd_camera_attitude`) and an elevation label from the point cloud
(:func:`roadbev_core.labels.elevation_map_from_camera`).
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from roadbev_core.config import RSRD_CROP_TOP, GridSpec, StereoCamera
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude, rsrd_camera_attitude
from roadbev_core.labels import elevation_map_from_camera

__all__ = [
    "CROP_HEIGHT",
    "CROP_WIDTH",
    "RsrdCalibration",
    "RsrdError",
    "RsrdSet",
    "load_calibration",
    "load_sample_info",
    "read_pcd",
]

CROP_WIDTH, CROP_HEIGHT = 960, 528  # the paper's input size

_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "<i1", ("I", 2): "<i2", ("I", 4): "<i4",
              ("I", 8): "<i8", ("U", 1): "<u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8"}


class RsrdError(RoadbevError, ValueError):
    """An RSRD file that is missing, malformed or inconsistent with the others."""


def read_pcd(path: str | Path) -> np.ndarray:
    """x, y, z [N, 3] float64 of a PCD file (``DATA ascii`` or ``binary``; NaN points dropped).

    Raises:
        RsrdError: unreadable header, unsupported encoding or truncated data.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RsrdError(f"cannot read point cloud {path}: {exc.strerror}") from exc
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = raw.find(b"\n", offset)
        if end < 0:
            raise RsrdError(f"{path}: PCD header has no DATA line")
        line = raw[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    try:
        fields = header["FIELDS"]
        sizes = [int(v) for v in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(v) for v in header.get("COUNT", ["1"] * len(fields))]
        n_points = int(header["POINTS"][0])
        encoding = header["DATA"][0].lower()
    except (KeyError, IndexError, ValueError) as exc:
        raise RsrdError(f"{path}: malformed PCD header ({exc})") from exc
    if not {"x", "y", "z"} <= set(fields) or not len(fields) == len(sizes) == len(types) == len(counts):
        raise RsrdError(f"{path}: PCD needs x, y, z fields with matching SIZE/TYPE/COUNT")
    if encoding == "ascii":
        text = raw[offset:].decode("ascii", errors="replace").split()
        width = sum(counts)
        if len(text) < n_points * width:
            raise RsrdError(f"{path}: ASCII PCD has {len(text) // max(width, 1)} of {n_points} points")
        table = np.array(text[: n_points * width], dtype=np.float64).reshape(n_points, width)
        starts = np.cumsum([0, *counts[:-1]])
        xyz = np.stack([table[:, starts[fields.index(a)]] for a in "xyz"], axis=1)
    elif encoding == "binary":
        try:
            dtype = np.dtype([(f"{f}_{i}", _PCD_TYPES[(t.upper(), s)], (c,))
                              for i, (f, s, t, c) in enumerate(zip(fields, sizes, types, counts, strict=True))])
        except KeyError as exc:
            raise RsrdError(f"{path}: unsupported PCD field type {exc.args[0]}") from exc
        if len(raw) - offset < n_points * dtype.itemsize:
            raise RsrdError(f"{path}: binary PCD is truncated ({len(raw) - offset} bytes for {n_points} points)")
        records = np.frombuffer(raw, dtype=dtype, count=n_points, offset=offset)
        xyz = np.stack([records[f"{a}_{fields.index(a)}"][:, 0].astype(np.float64) for a in "xyz"], axis=1)
    else:
        raise RsrdError(f"{path}: PCD encoding {encoding!r} is not supported (ascii or binary)")
    return xyz[np.all(np.isfinite(xyz), axis=1)]


@dataclass(frozen=True)
class RsrdCalibration:
    """A recording day's rig: the cropped 960 x 528 camera and the LiDAR -> left-camera extrinsics."""

    camera: StereoCamera
    R: np.ndarray  # [3, 3] p_cam = R @ p_lidar + T
    T: np.ndarray  # [3]


def _load_pickle(path: Path) -> Any:
    try:
        with path.open("rb") as handle:
            return pickle.load(handle)  # only files the user named (module docstring)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError) as exc:
        raise RsrdError(f"cannot load {path}: {exc}") from exc


def load_calibration(path: str | Path) -> RsrdCalibration:
    """Read an RSRD ``calib_*_half.pkl`` the caller trusts (pickle: see the module docstring)."""
    path = Path(path)
    data = _load_pickle(path)
    try:
        K = np.asarray(data["K"], dtype=np.float64).reshape(3, 3)
        baseline_m = float(data["B"]) / 1000.0  # the file gives millimetres
        R = np.asarray(data["R"], dtype=np.float64).reshape(3, 3)
        T = np.asarray(data["T"], dtype=np.float64).reshape(3)
        width, height = int(data["Width"]), int(data["Height"])
    except (KeyError, TypeError, ValueError) as exc:
        raise RsrdError(f"{path}: not an RSRD calibration (needs K, B, R, T, Width, Height): {exc}") from exc
    if width < CROP_WIDTH or height < RSRD_CROP_TOP + CROP_HEIGHT:
        raise RsrdError(f"{path}: images of {width}x{height} are smaller than the {CROP_WIDTH}x{CROP_HEIGHT} crop")
    camera = StereoCamera.from_K(K, baseline_m, width, height).cropped(0, RSRD_CROP_TOP, CROP_WIDTH, CROP_HEIGHT)
    return RsrdCalibration(camera=camera, R=R, T=T)


def load_sample_info(paths: list[str | Path]) -> list[dict[str, Any]]:
    """Concatenate the sample lists of the named ``sample_info`` pickles (trusted files only)."""
    samples: list[dict[str, Any]] = []
    for path in paths:
        data = _load_pickle(Path(path))
        if not isinstance(data, list) or not all(isinstance(d, dict) and "time" in d and "path" in d for d in data):
            raise RsrdError(f"{path}: not an RSRD sample list (dicts with 'time' and 'path')")
        samples.extend(data)
    return samples


def _stamp_ns(time_stem: str) -> int:
    """'20230317075641.200' (local clock, taken as UTC) -> nanoseconds since the epoch; 0 if odd."""
    try:
        whole, _, frac = time_stem.partition(".")
        moment = datetime.strptime(whole, "%Y%m%d%H%M%S").replace(tzinfo=timezone.utc)
        return int(moment.timestamp()) * 1_000_000_000 + int(round(float(f"0.{frac or 0}") * 1e9))
    except ValueError:
        return 0


class RsrdSet:
    """RSRD samples as ``(Frame, truth)`` pairs on ``grid``.

    Args:
        root: the dataset root (holding ``<split>/<sequence>/...``).
        split: ``train`` or ``test`` (a folder name under ``root``).
        sample_info: the sample-info pickles to use (named explicitly: see the module docstring).
        calibrations: the ``calib_<YYYYMMDD>_half.pkl`` files to use; each sample takes the one of
            its recording day (the first 8 digits of its ``time``).
        grid: the label grid (default ``GridSpec()``).
    """

    def __init__(
        self,
        root: str | Path,
        split: str,
        sample_info: list[str | Path],
        calibrations: list[str | Path],
        grid: GridSpec | None = None,
    ) -> None:
        self.root = Path(root)
        self.split = split
        self.grid = grid or GridSpec()
        self.samples = load_sample_info(sample_info)
        if not self.samples:
            raise RsrdError("the sample-info files list no samples")
        self.calibrations: dict[str, RsrdCalibration] = {}
        for path in calibrations:
            day = Path(path).name.removeprefix("calib_")[:8]
            if not day.isdigit():
                raise RsrdError(f"calibration file {path} is not named calib_<YYYYMMDD>[_half].pkl")
            self.calibrations[day] = load_calibration(path)
        days = {str(s["time"])[:8] for s in self.samples} - set(self.calibrations)
        if days:
            raise RsrdError(f"no calibration given for recording day(s) {', '.join(sorted(days))}")

    def __len__(self) -> int:
        return len(self.samples)

    def sequence_dir(self, sample: dict[str, Any]) -> Path:
        """``<root>/<split>/<sequence>`` (the sample's ``path`` may carry a prefix such as ``dense/``)."""
        seq = Path(str(sample["path"]))
        for candidate in (self.root / self.split / seq.name, self.root / self.split / seq, self.root / seq):
            if candidate.is_dir():
                return candidate
        raise RsrdError(f"sequence folder of {sample['time']} not found under {self.root / self.split}")

    def _image(self, path: Path, calib: RsrdCalibration) -> np.ndarray:
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise RsrdError(f"cannot read image {path}")
        expected = (calib.camera.height + RSRD_CROP_TOP, calib.camera.width)
        if bgr.shape[0] < expected[0] or bgr.shape[1] != expected[1]:
            raise RsrdError(f"{path} is {bgr.shape[1]}x{bgr.shape[0]}, the calibration expects width {expected[1]}")
        crop = bgr[RSRD_CROP_TOP:RSRD_CROP_TOP + CROP_HEIGHT]
        return np.ascontiguousarray(crop[:, :, ::-1])  # RGB

    def __getitem__(self, index: int) -> tuple[Frame, np.ndarray]:
        sample = self.samples[index]
        time_stem = str(sample["time"])
        calib = self.calibrations[time_stem[:8]]
        folder = self.sequence_dir(sample)
        left = self._image(folder / "left_half" / f"{time_stem}.jpg", calib)
        right = self._image(folder / "right_half" / f"{time_stem}.jpg", calib)
        try:
            attitude: Attitude = rsrd_camera_attitude(float(sample["roll"]), float(sample["pitch"]), calib.R)
        except (KeyError, TypeError, ValueError) as exc:
            raise RsrdError(f"sample {time_stem}: bad or missing roll/pitch ({exc})") from exc
        points_lidar = read_pcd(folder / "pcd" / f"{time_stem}.pcd")
        points_cam = points_lidar @ calib.R.T + calib.T  # [N, 3] left optical frame
        label = elevation_map_from_camera(points_cam, attitude, self.grid)
        stamp_ns = _stamp_ns(time_stem)
        frame = Frame(left=left, right=right, camera=calib.camera, attitude=attitude, stamp_ns=stamp_ns)
        return frame, label.elevation
