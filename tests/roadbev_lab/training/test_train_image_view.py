"""The image-view baselines' training: labels from the elevation label, the networks learn, checkpoints load."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roadbev_core.checkpoint import load_baseline, training_envelope
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.models.adabins import AdaBinsConfig
from roadbev_core.models.gwcnet import GwcNetConfig
from roadbev_lab.training.datasets import SyntheticSet
from roadbev_lab.training.train import TrainConfig, TrainError
from roadbev_lab.training.train_image_view import (
    AdaBinsSample,
    adabins_sample,
    augment_adabins,
    gwcnet_sample,
    train_image_view,
    training_phases,
)

CAMERA = StereoCamera.rsrd_half().scaled(0.25)  # 240 x 132 renders in about a second
GRID = GridSpec(resolution=0.12)
SEEDS = (100_000, 100_001)


@pytest.fixture(scope="module")
def frames(tmp_path_factory: pytest.TempPathFactory) -> SyntheticSet:
    return SyntheticSet(tmp_path_factory.mktemp("synth"), SEEDS, camera=CAMERA, grid=GRID)


def test_gwcnet_labels_are_the_disparities_of_the_labelled_road(frames: SyntheticSet) -> None:
    frame, truth = frames[0]
    sample = gwcnet_sample(frame, truth, GRID, GwcNetConfig())
    assert sample.left.shape == sample.right.shape and sample.left.shape[:2] == sample.target.shape
    labelled = np.isfinite(sample.target)
    assert labelled.mean() > 0.2
    # the road's disparity falls from the bottom of the window to its top (farther road)
    rows = np.where(labelled.any(axis=1))[0]
    top, bottom = np.nanmean(sample.target[rows[0]]), np.nanmean(sample.target[rows[-1]])
    assert bottom > top >= 0


def test_adabins_labels_are_depths_at_the_output_pixels(frames: SyntheticSet) -> None:
    frame, truth = frames[0]
    config = AdaBinsConfig(input_width=240, input_height=128, patch_size=4)
    sample = adabins_sample(frame, truth, GRID, config)
    assert sample.image.shape == (3, 128, 240) and sample.target.shape == (64, 120)
    depths = sample.target[np.isfinite(sample.target)]
    assert depths.size > 100 and np.all((depths > GRID.x_min * 0.5) & (depths < GRID.x_max * 1.5))


def test_gwcnet_learns_and_its_checkpoint_loads(frames: SyntheticSet, tmp_path: Path) -> None:
    out = tmp_path / "gwcnet.pt"
    # disparities of the quarter-size rig lie within 16 pixels of the search's first one
    small = GwcNetConfig(max_disparity=16, features=16, groups=4, volume_channels=4)
    result = train_image_view("gwcnet", frames, TrainConfig(epochs=30, batch_size=2, lr=3e-3, seed=0), out,
                              model_config=small, crop=(112, 128), meta={"command": "test"})
    first, last = result["history"][0], result["history"][-1]
    assert last["loss"] < 0.7 * first["loss"], (first, last)
    model, payload = load_baseline(out, "gwcnet")
    assert model.config == small
    # a second phase from these weights keeps the first one's record
    again = train_image_view("gwcnet", frames, TrainConfig(epochs=1, batch_size=2, lr=1e-3, seed=1), tmp_path / "2.pt",
                             init=out, crop=(112, 128), meta={"command": "second"})
    phases = training_phases(load_baseline(again["checkpoint"], "gwcnet")[1]["meta"])
    assert [p["command"] for p in phases] == ["test", "second"] and len(phases[0]["history"]) == 30
    assert payload["meta"]["command"] == "test" and len(payload["meta"]["history"]) == 30
    assert training_envelope(payload).grid == GRID


def test_adabins_learns_and_its_checkpoint_loads(frames: SyntheticSet, tmp_path: Path) -> None:
    out = tmp_path / "adabins.pt"
    result = train_image_view("adabins", frames, TrainConfig(epochs=6, batch_size=2, lr=1e-3, seed=0), out)
    first, last = result["history"][0], result["history"][-1]
    assert last["loss"] < 0.8 * first["loss"], (first, last)
    _, payload = load_baseline(out, "adabins")
    assert training_envelope(payload).baseline_m == (0.0, 0.0)  # a monocular network


def test_adabins_augmentation_mirrors_image_and_label_together_and_scales_colours_mildly() -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(30, 220, size=(3, 8, 12), dtype=np.uint8)
    target = np.tile(np.arange(6, dtype=np.float32), (4, 1))  # [4, 6], rising to the right
    target[0, 0] = np.nan
    sample = AdaBinsSample(image, target)
    flips = recoloured = 0
    for _ in range(400):
        out = augment_adabins(sample, rng)
        assert out.image.dtype == np.uint8 and out.image.shape == image.shape and out.target.shape == target.shape
        flipped = bool(np.isnan(out.target[0, -1]))
        np.testing.assert_array_equal(out.target, target[:, ::-1] if flipped else target)
        base = image[:, :, ::-1] if flipped else image
        if not np.array_equal(out.image, base):
            recoloured += 1
            ratio = out.image.astype(np.float64).mean() / base.astype(np.float64).mean()
            assert 0.75 < ratio < 1.35
        flips += flipped
    assert 150 < flips < 250 and 150 < recoloured < 250  # each half of the time
    np.testing.assert_array_equal(sample.image, image)  # the cached sample is left as it was


def test_bad_settings_are_refused(frames: SyntheticSet, tmp_path: Path) -> None:
    with pytest.raises(TrainError, match="AdaBins' "):
        train_image_view("gwcnet", frames, TrainConfig(), tmp_path / "x.pt", augment=True)
    with pytest.raises(TrainError, match="unknown image-view baseline"):
        train_image_view("psmnet", frames, TrainConfig(), tmp_path / "x.pt")
    with pytest.raises(TrainError, match="multiples of 8"):
        train_image_view("gwcnet", frames, TrainConfig(), tmp_path / "x.pt", crop=(60, 128))
    with pytest.raises(TrainError, match="takes a GwcNetConfig"):
        train_image_view("gwcnet", frames, TrainConfig(), tmp_path / "x.pt", model_config=AdaBinsConfig())
    with pytest.raises(TrainError, match="fresh AdaBins-lite only"):
        train_image_view("gwcnet", frames, TrainConfig(), tmp_path / "x.pt", pretrained=tmp_path / "w.pth")
