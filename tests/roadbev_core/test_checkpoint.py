"""Checkpoints: weights_only round trip with config and grid; clear errors."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from roadbev_core.checkpoint import CheckpointError, load_model, read_checkpoint, save_checkpoint
from roadbev_core.config import GridSpec
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
