"""Data sources: the synthetic scene cache, model inputs and batches."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

import roadbev_lab.synth as synth
import roadbev_lab.training.datasets as datasets
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.models.presets import model_config
from roadbev_lab.training.datasets import ConcatSource, DatasetError, ModelInputs, SyntheticSet, collate

CAMERA = StereoCamera.rsrd_half().scaled(0.25)
GRID = GridSpec(resolution=0.12)


def test_scenes_are_rendered_once_and_read_back_identically(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    first = SyntheticSet(tmp_path, [100_010], camera=CAMERA, grid=GRID)
    frame, truth = first[0]
    reference = synth.make_sample(100_010, camera=CAMERA, grid=GRID)
    assert frame.right is not None and reference.frame.right is not None
    assert np.array_equal(frame.left, reference.frame.left) and np.array_equal(frame.right, reference.frame.right)
    assert frame.attitude == reference.frame.attitude and frame.camera == CAMERA
    np.testing.assert_array_equal(truth, reference.truth.elevation)

    def no_render(*args: object, **kwargs: object) -> None:
        raise AssertionError("a cached scene was rendered again")

    monkeypatch.setattr(datasets, "make_sample", no_render)
    again = SyntheticSet(tmp_path, [100_010], camera=CAMERA, grid=GRID)
    assert again.render_missing() == 0
    assert np.array_equal(again[0][0].left, frame.left)
    # another rig gets its own cache folder instead of stale scenes
    with pytest.raises(AssertionError, match="rendered again"):
        SyntheticSet(tmp_path, [100_010], camera=CAMERA.scaled(0.5), grid=GRID)


def test_model_inputs_resize_and_batch(tmp_path: Path) -> None:
    source = SyntheticSet(tmp_path, [100_011], camera=CAMERA, grid=GRID)
    config = model_config("tiny", "stereo")
    items = ModelInputs(ConcatSource([source, source]), config, GRID)
    assert len(items) == 2
    item = items[1]
    assert item["left"].shape == item["right"].shape == (3, 128, 224) and item["left"].dtype == torch.uint8
    assert item["grey"].shape == (2, CAMERA.height, CAMERA.width)  # the photometric channel's full-size frames
    batch = collate([items[0], items[1]])
    assert batch["left"].shape == (2, 3, 128, 224) and batch["elevation"].shape == (2, *GRID.shape)
    assert batch["grey"].shape == (2, 2, CAMERA.height, CAMERA.width) and batch["grey"].dtype == torch.uint8
    assert batch["attitude"] == [source[0][0].attitude] * 2
    with pytest.raises(DatasetError, match="grid"):
        ModelInputs(source, config, GridSpec())
    (source.path(100_011)).write_bytes(b"broken")
    with pytest.raises(DatasetError, match="unreadable"):
        source[0]
    with pytest.raises(DatasetError, match="seed"):
        SyntheticSet(tmp_path, [])


def test_scenes_of_another_generator_version_are_not_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    SyntheticSet(tmp_path, [100_012], camera=CAMERA, grid=GRID)

    def no_render(*args: object, **kwargs: object) -> None:
        raise AssertionError("rendered again")

    monkeypatch.setattr(datasets, "make_sample", no_render)
    assert SyntheticSet(tmp_path, [100_012], camera=CAMERA, grid=GRID).render_missing() == 0
    monkeypatch.setattr(datasets, "SCENE_VERSION", datasets.SCENE_VERSION + 1)
    with pytest.raises(AssertionError, match="rendered again"):
        SyntheticSet(tmp_path, [100_012], camera=CAMERA, grid=GRID)


def test_scenes_of_an_appearance_range_have_their_own_cache_and_its_looks(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    plain = SyntheticSet(tmp_path, [100_013], camera=CAMERA, grid=GRID, appearance="clean")
    looked = SyntheticSet(tmp_path, [100_013], camera=CAMERA, grid=GRID, appearance="real-road")
    assert looked.folder != plain.folder
    reference = synth.make_sample(100_013, camera=CAMERA, grid=GRID, appearance=synth.REAL_ROAD)
    np.testing.assert_array_equal(looked[0][0].left, reference.frame.left)
    assert not np.array_equal(looked[0][0].left, plain[0][0].left)
    np.testing.assert_array_equal(looked[0][1], plain[0][1])  # the same road under other looks
    assert SyntheticSet(tmp_path, [100_013], camera=CAMERA, grid=GRID).folder == looked.folder  # the default
    changed = dataclasses.replace(synth.REAL_ROAD, weak=dataclasses.replace(synth.REAL_ROAD.weak, noise_sigma=1.0))
    monkeypatch.setitem(synth.APPEARANCE_RANGES, "real-road", changed)  # the range re-measured
    assert SyntheticSet(tmp_path, [100_013], camera=CAMERA, grid=GRID, appearance="real-road").folder != looked.folder
    with pytest.raises(DatasetError, match="unknown appearance"):
        SyntheticSet(tmp_path, [100_013], camera=CAMERA, grid=GRID, appearance="sunny")
