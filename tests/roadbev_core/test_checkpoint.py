"""Checkpoints: weights_only round trip with config and grid; clear errors."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch

from roadbev_core.checkpoint import (
    CheckpointError,
    TrainingEnvelope,
    load_model,
    read_checkpoint,
    save_checkpoint,
    training_envelope,
)
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.models.presets import model_config
from roadbev_core.models.roadbev import RoadBEV


def test_round_trip_rebuilds_the_same_network(tmp_path: Path) -> None:
    torch.manual_seed(0)
    model = RoadBEV(model_config("tiny", "mono"), GridSpec())
    path = save_checkpoint(tmp_path / "m.pt", model, meta={"note": "x"})
    payload = torch.load(path, weights_only=True)  # no code runs while loading
    assert payload["model_config"]["kind"] == "mono" and payload["grid"]["resolution"] == 0.03
    loaded, _ = load_model(path)
    for key, value in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value), key
    half = save_checkpoint(tmp_path / "h.pt", model, half=True)
    assert half.stat().st_size < 0.6 * path.stat().st_size
    loaded_half, _ = load_model(half)
    assert next(loaded_half.parameters()).dtype == torch.float32
    # another base height (same shapes) works; another voxel count does not fit the mono head
    load_model(path, grid=GridSpec(base_height=1.3, z_min=-0.2, z_max=0.2))
    with pytest.raises(CheckpointError, match="does not fit"):
        load_model(path, grid=GridSpec(z_min=-0.16, z_max=0.16))


def test_missing_corrupt_or_foreign_files_raise_checkpoint_errors(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="does not exist"):
        read_checkpoint(tmp_path / "none.pt")
    (tmp_path / "junk.pt").write_bytes(b"\x00garbage")
    with pytest.raises(CheckpointError, match="corrupt"):
        read_checkpoint(tmp_path / "junk.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a RoadBEV checkpoint"):
        read_checkpoint(tmp_path / "other.pt")


def test_non_finite_weights_are_refused_at_load(tmp_path: Path) -> None:
    torch.manual_seed(0)
    model = RoadBEV(model_config("tiny", "mono"), GridSpec())
    name, weight = next((k, v) for k, v in model.state_dict().items() if v.is_floating_point() and v.numel() > 1)
    with torch.no_grad():
        weight.view(-1)[0] = float("nan")
    path = save_checkpoint(tmp_path / "nan.pt", model)
    with pytest.raises(CheckpointError, match=f"non-finite weights .* in {re.escape(name)}"):
        load_model(path)


def test_weights_scaled_beyond_any_trained_model_are_refused(tmp_path: Path) -> None:
    torch.manual_seed(0)
    model = RoadBEV(model_config("tiny", "mono"), GridSpec())
    with torch.no_grad():
        for value in model.state_dict().values():
            if value.is_floating_point():
                value.mul_(1e30)  # still finite in float32, but no trained model holds such weights
    path = save_checkpoint(tmp_path / "huge.pt", model)
    with pytest.raises(CheckpointError, match=r"implausible weights: \|.*\| up to .*e\+\d+"):
        load_model(path)


def test_training_envelope_names_what_is_out_of_range(tmp_path: Path) -> None:
    model = RoadBEV(model_config("tiny", "mono"), GridSpec())
    payload = read_checkpoint(save_checkpoint(tmp_path / "m.pt", model))
    envelope = training_envelope(payload)  # no envelope stored: the RSRD rig and the own grid
    rig = StereoCamera.rsrd_half()
    assert envelope.grid == GridSpec() and envelope.grid_problems(GridSpec()) == []
    assert envelope.rig_problems(rig, stereo=True) == []
    assert envelope.rig_problems(rig.scaled(0.5), stereo=True) == []  # same rig, smaller images
    far = GridSpec(x_min=6.5, x_max=18.5, y_min=-1.0, y_max=1.0, resolution=0.1, base_height=1.65)
    problems = " ".join(envelope.grid_problems(far))
    assert "x window" in problems and "cells of 0.1" in problems and "base_height 1.65" in problems
    wide = StereoCamera(fx=400.0, fy=400.0, cx=480.0, cy=264.0, baseline=0.54, width=960, height=528)
    assert len(envelope.rig_problems(wide, stereo=True)) == 2
    assert len(envelope.rig_problems(wide, stereo=False)) == 1  # mono ignores the baseline
    assert TrainingEnvelope.from_dict(envelope.to_dict()) == envelope
