"""baseline_training: a baseline checkpoint's phases become the record and the loss-curve figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from benchmarks.baseline_training import main, network_errors, summary
from roadbev_core.checkpoint import TrainingEnvelope, save_baseline
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.models.gwcnet import GwcNetConfig, GwcNetLite

CAMERA = StereoCamera.rsrd_half()


def _checkpoint(path: Path, phases: list[dict[str, object]]) -> Path:
    torch.manual_seed(0)
    envelope = TrainingEnvelope(GridSpec(), (CAMERA.fx, CAMERA.fx), CAMERA.width, (CAMERA.baseline, CAMERA.baseline))
    return save_baseline(path, "gwcnet", GwcNetLite(GwcNetConfig(features=16, groups=4)).eval(), envelope,
                         meta={**phases[-1], "phases": phases})


def _phase(command: str, epochs: int, seconds: float) -> dict[str, object]:
    history = [{"epoch": e + 1, "step": 10 * (e + 1), "loss": 1.0 / (e + 1), "abs_err": 0.5 / (e + 1)}
               for e in range(epochs)]
    return {"command": command, "frames": 20, "epochs": epochs, "lr": 1e-3, "batch_size": 2, "crop": [448, 384],
            "steps": 10 * epochs, "seconds": seconds, "history": history}


def test_the_record_sums_the_phases_and_the_figure_is_drawn(tmp_path: Path) -> None:
    path = _checkpoint(tmp_path / "gwc.pt", [_phase("first", 3, 120.0), _phase("second", 2, 60.0)])
    record = summary(path)
    assert record["kind"] == "gwcnet" and [p["command"] for p in record["phases"]] == ["first", "second"]
    assert record["steps"] == 50 and record["sample_passes"] == 100 and record["minutes"] == pytest.approx(3.0)
    assert main(["--checkpoints", str(path), "--out", str(tmp_path / "out"), "--held-out", "0"]) == 0
    data = json.loads((tmp_path / "out" / "baseline_training.json").read_text())
    assert data["baselines"][0]["phases"][1]["history"][-1]["loss"] == pytest.approx(0.5)
    assert (tmp_path / "out" / "baseline_training.png").stat().st_size > 0


def test_a_checkpoint_that_is_no_baseline_is_refused(tmp_path: Path) -> None:
    other = tmp_path / "other.pt"
    torch.save({"format": "roadbev-checkpoint/1"}, other)
    with pytest.raises(ValueError, match="not an image-view baseline"):
        summary(other)


class _ConstantDisparity(torch.nn.Module):
    """Answers the same disparity (from the search's first) at every pixel."""

    def __init__(self, value: float) -> None:
        super().__init__()
        self.value = value
        self.config = GwcNetConfig()

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, _, h, w = left.shape
        return torch.full((b, h, w), self.value), torch.ones(b, h, w)


def test_a_networks_own_error_is_scored_against_its_labels_in_its_unit() -> None:
    from roadbev_core.backends.gwcnet import search_window
    from roadbev_lab.synth import make_sample
    from roadbev_lab.training.train_image_view import gwcnet_sample

    grid = GridSpec()
    scene = make_sample(3, grid=grid)
    samples = [(scene.frame, scene.truth.elevation)]
    target = gwcnet_sample(scene.frame, scene.truth.elevation, grid, GwcNetConfig()).target
    labelled = target[np.isfinite(target)]
    offset = search_window(grid, scene.frame.camera, scene.frame.attitude).min_disparity
    errors = network_errors("gwcnet", _ConstantDisparity(20.0), samples, grid)
    assert errors["pixels"] == labelled.size > 1000
    assert errors["abs_err"] == pytest.approx(np.abs(20.0 - labelled).mean(), rel=1e-5)
    assert errors["relative_err"] == pytest.approx((np.abs(20.0 - labelled) / (labelled + offset)).mean(), rel=1e-5)
