"""Training and evaluation data for the RoadBEV networks.

Every source yields ``(Frame, truth)`` pairs, truth an elevation map [n_rows, n_cols] float32
metres on the source's grid (NaN = no label):

* :class:`SyntheticSet`: random synthetic scenes (``roadbev_lab.synth.make_sample``), rendered
  once per seed and cached to disk as ``.npz`` (rendering costs up to ~1 s a frame);
* :class:`LabelledFrames`: frames already decoded, e.g. an evaluation bag's
  (``roadbev_lab.evaluation.evalbag.bag_frames``);
* :class:`roadbev_lab.data.rsrd.RsrdSet`: the real RSRD layout.

:class:`ModelInputs` turns any of them into tensors at a model's input size and :func:`collate`
batches them (cameras and attitudes stay Python objects: each sample has its own attitude).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import torch
from torch.utils.data import Dataset

if TYPE_CHECKING:
    from roadbev_lab.synth.appearance import AppearanceRange

from tqdm import tqdm

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude
from roadbev_core.models.presets import ModelConfig
from roadbev_core.models.roadbev import needs_full_grey, prepare_grey, prepare_image
from roadbev_lab.synth import make_sample
from roadbev_lab.synth.appearance import appearance_range

__all__ = [
    "SCENE_VERSION",
    "TEST_SEED_START",
    "ConcatSource",
    "DatasetError",
    "FrameSource",
    "LabelledFrames",
    "ModelInputs",
    "SyntheticSet",
    "collate",
]

TEST_SEED_START = 100_000  # synthetic test scenes use seeds >= this; training seeds stay below


class DatasetError(RoadbevError, ValueError):
    """A data source that cannot be read or does not fit the model's grid."""


class FrameSource(Protocol):
    """What the training and evaluation code needs from a data source."""

    grid: GridSpec

    def __len__(self) -> int: ...

    def __getitem__(self, index: int) -> tuple[Frame, np.ndarray]: ...


# What ``roadbev_lab.synth.make_sample`` renders for a seed. Bump it with any change to the
# generator's output (tests/roadbev_lab/synth/test_drive.py pins a fingerprint of one seed and
# says so when it moves): caches of an older generator then sit in another folder instead of
# being read as if they were current. (The demo's one cached bag hashes the generator's source
# instead; a training cache holds thousands of scenes that an edited comment should not re-render.)
# Version 2: the random scenes draw their pavement and camera appearance from the ``real-road``
# range (``roadbev_lab.synth.appearance``); version 1 was the ``clean`` appearance.
SCENE_VERSION = 2


def _cache_folder(
    root: Path, camera: StereoCamera, grid: GridSpec, appearance: AppearanceRange | None = None
) -> Path:
    """A sub-folder per (generator version, camera, grid, appearance range): a cache never mixes
    scenes of different generators, rigs, grids or appearances."""
    key = json.dumps({"camera": camera.to_dict(), "grid": grid.to_dict()}, sort_keys=True)
    # Versions 1 and 2 render the same scene for the same appearance (2 moved the default from
    # the clean appearance to the real-road range, and the appearance is in the key): their
    # caches share folders, and a later version gets its own.
    if SCENE_VERSION > 2:
        key += f"/scenes-v{SCENE_VERSION}"
    if appearance is not None:
        # the range's values, not only its name: a range re-measured is another set of scenes
        key += f"/appearance-{appearance.name}-{appearance!r}"
    return root / f"synth-{hashlib.sha1(key.encode()).hexdigest()[:10]}"


class SyntheticSet:
    """Random synthetic scenes, one per seed, cached as ``<cache>/synth-<hash>/<seed>.npz``.

    Args:
        cache_dir: where rendered scenes are kept (created).
        seeds: scene seeds (training below :data:`TEST_SEED_START`, test at or above it).
        camera, grid: the rig and the label grid (defaults: ``StereoCamera.rsrd_half()``, ``GridSpec()``).
        progress: show a progress bar while rendering missing scenes.
        appearance: draw each scene's appearance from this named range
            (``roadbev_lab.synth.APPEARANCE_NAMES``; None: the default, ``real-road``;
            ``clean``: the generator's own, scene version 1's default).

    Raises:
        DatasetError: no seeds, or an unknown appearance.
    """

    def __init__(
        self,
        cache_dir: str | Path,
        seeds: Iterable[int],
        *,
        camera: StereoCamera | None = None,
        grid: GridSpec | None = None,
        progress: bool = False,
        appearance: str | None = None,
    ) -> None:
        self.seeds = [int(s) for s in seeds]
        if not self.seeds:
            raise DatasetError("a synthetic set needs at least one seed")
        self.camera = camera or StereoCamera.rsrd_half()
        self.grid = grid or GridSpec()

        try:
            self.appearance: AppearanceRange | None = appearance_range(appearance)
        except RoadbevError as exc:  # an unknown name
            raise DatasetError(str(exc)) from exc
        self.folder = _cache_folder(Path(cache_dir), self.camera, self.grid, self.appearance)
        self.render_missing(progress=progress)

    def path(self, seed: int) -> Path:
        return self.folder / f"{seed}.npz"

    def render_missing(self, *, progress: bool = False) -> int:
        """Render and cache every seed not on disk yet; returns how many were rendered."""
        missing = [s for s in self.seeds if not self.path(s).exists()]
        if not missing:
            return 0
        # Imported lazily: reading a cache needs no renderer.

        self.folder.mkdir(parents=True, exist_ok=True)
        bar = _progress(missing, "rendering scenes", progress)
        for seed in bar:
            sample = make_sample(seed, camera=self.camera, grid=self.grid, appearance=self.appearance)
            frame = sample.frame
            tmp = self.path(seed).with_suffix(".tmp.npz")
            np.savez_compressed(
                tmp,
                left=frame.left,
                right=frame.right if frame.right is not None else np.zeros((0,), np.uint8),
                attitude=np.array([frame.attitude.roll, frame.attitude.pitch]),
                truth=sample.truth.elevation.astype(np.float32),
            )
            tmp.replace(self.path(seed))  # atomic: a killed run never leaves half a file
        return len(missing)

    def __len__(self) -> int:
        return len(self.seeds)

    def __getitem__(self, index: int) -> tuple[Frame, np.ndarray]:
        seed = self.seeds[index]
        try:
            with np.load(self.path(seed)) as data:
                left, right = data["left"], data["right"]
                roll, pitch = (float(v) for v in data["attitude"])
                truth = data["truth"]
        except (OSError, KeyError, ValueError) as exc:
            raise DatasetError(f"cached scene {self.path(seed)} is unreadable ({exc}); delete it") from exc
        frame = Frame(left=left, right=right if right.size else None, camera=self.camera,
                      attitude=Attitude(roll, pitch), stamp_ns=seed)
        return frame, truth


class LabelledFrames:
    """Decoded frames with labels, held in memory (for example an evaluation bag's, read by
    :func:`roadbev_lab.evaluation.evalbag.bag_frames`: roadbev_core reads no bags itself).

    Raises:
        DatasetError: no frame has a label.
    """

    def __init__(
        self, grid: GridSpec, samples: Iterable[tuple[Frame, np.ndarray | None]], what: str = "frames"
    ) -> None:
        self.grid = grid
        self.samples = [(frame, truth) for frame, truth in samples if truth is not None]
        if not self.samples:
            raise DatasetError(f"{what}: no frame has ground truth")

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, index: int) -> tuple[Frame, np.ndarray]:
        return self.samples[index]


class ModelInputs(Dataset[dict[str, Any]]):
    """Tensors for a model from a frame source; prepared images are kept in memory if asked.

    Items are dicts: ``left``/``right`` uint8 [3, h, w] (right absent for mono), ``elevation``
    float32 [n_rows, n_cols] (NaN = no label), ``camera``, ``attitude``, and ``grey`` uint8
    [2, H, W] (the full-resolution grey frames) for models that read them (``needs_full_grey``).
    """

    def __init__(
        self, source: FrameSource, config: ModelConfig, grid: GridSpec, *, keep_in_memory: bool = True
    ) -> None:
        if source.grid.shape != grid.shape:
            raise DatasetError(f"data labels are on a {source.grid.shape} grid, the model's is {grid.shape}")
        self.source = source
        self.config = config
        self.keep = keep_in_memory
        self._memo: dict[int, dict[str, Any]] = {}

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, index: int) -> dict[str, Any]:
        if index in self._memo:
            return self._memo[index]
        frame, truth = self.source[index]
        item: dict[str, Any] = {
            "left": torch.from_numpy(prepare_image(frame.left, self.config)),
            "elevation": torch.from_numpy(np.asarray(truth, dtype=np.float32)),
            "camera": frame.camera,
            "attitude": frame.attitude,
        }
        if self.config.kind == "stereo":
            if frame.right is None:
                raise DatasetError("RoadBEV-stereo needs stereo frames; this source has no right images")
            item["right"] = torch.from_numpy(prepare_image(frame.right, self.config))
            if needs_full_grey(self.config):
                item["grey"] = torch.from_numpy(prepare_grey(frame.left, frame.right))
        if self.keep:
            self._memo[index] = item
        return item


def collate(items: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Stack tensors; keep cameras and attitudes as lists."""
    batch: dict[str, Any] = {"camera": [i["camera"] for i in items], "attitude": [i["attitude"] for i in items]}
    for key in ("left", "right", "grey", "elevation"):
        if key in items[0]:
            batch[key] = torch.stack([i[key] for i in items])
    return batch


def _progress(items: Sequence[Any], desc: str, enabled: bool) -> Iterable[Any]:
    if not enabled:
        return items

    return tqdm(items, desc=desc, unit="frame", disable=None)  # None: only on a terminal


def as_samples(source: FrameSource) -> Iterable[tuple[Frame, np.ndarray]]:
    """Iterate a source's ``(frame, truth)`` pairs (what ``evaluation.evaluate`` takes)."""
    for i in range(len(source)):
        yield source[i]


class ConcatSource:
    """Several frame sources on the same grid, one after another."""

    def __init__(self, sources: Sequence[FrameSource]) -> None:
        if not sources:
            raise DatasetError("no data sources given")
        shapes = {s.grid.shape for s in sources}
        if len(shapes) > 1:
            raise DatasetError(f"data sources disagree on the grid: {sorted(shapes)}")
        self.sources = list(sources)
        self.grid = sources[0].grid
        self._starts = np.cumsum([0, *(len(s) for s in sources)])

    def __len__(self) -> int:
        return int(self._starts[-1])

    def __getitem__(self, index: int) -> tuple[Frame, np.ndarray]:
        if not 0 <= index < len(self):
            raise IndexError(index)
        k = int(np.searchsorted(self._starts, index, side="right") - 1)
        return self.sources[k][index - int(self._starts[k])]
