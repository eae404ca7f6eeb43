"""The learned backends behind the registry: estimates on the grid, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from roadbev_core.backends import BackendError, create
from roadbev_core.backends.learned import OutOfDistributionError
from roadbev_core.checkpoint import save_checkpoint
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Frame, FrameError
from roadbev_core.geometry import Attitude
from roadbev_core.models.presets import model_config
from roadbev_core.models.roadbev import RoadBEV

CAMERA = StereoCamera.rsrd_half().scaled(0.25)


def _frame(stereo: bool = True) -> Frame:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8)
    return Frame(img, img.copy() if stereo else None, CAMERA, Attitude.from_degrees(0.5, 18.5))


@pytest.mark.parametrize("kind", ["stereo", "mono"])
def test_backend_estimates_the_requested_grid(kind: str, tmp_path: Path) -> None:
    torch.manual_seed(0)
    path = save_checkpoint(tmp_path / f"{kind}.pt", RoadBEV(model_config("tiny", kind), GridSpec()))
    grid = GridSpec(x_max=6.18)  # another window: 134 rows
    backend = create(kind, grid, checkpoint=str(path))
    assert backend.name == kind and backend.needs_stereo == (kind == "stereo")
    est = backend.estimate(_frame())
    assert est.elevation.shape == grid.shape == est.uncertainty.shape
    seen = np.isfinite(est.elevation)
    assert seen.mean() > 0.9 and np.array_equal(seen, np.isfinite(est.uncertainty))
    assert np.all(np.abs(est.elevation[seen]) <= 0.2) and np.all(est.uncertainty[seen] >= 0)
    assert {"preprocess", "network", "post"} <= set(est.timings_ms)


def test_missing_corrupt_or_mismatched_checkpoints_are_backend_errors(tmp_path: Path) -> None:
    with pytest.raises(BackendError, match="not found"):
        create("stereo", checkpoint=str(tmp_path / "none.pt"))
    (tmp_path / "bad.pt").write_bytes(b"PK\x03\x04 truncated zip")
    with pytest.raises(BackendError, match="corrupt"):
        create("mono", checkpoint=str(tmp_path / "bad.pt"))
    path = save_checkpoint(tmp_path / "mono.pt", RoadBEV(model_config("tiny", "mono"), GridSpec()))
    with pytest.raises(BackendError, match="RoadBEV-mono"):
        create("stereo", checkpoint=str(path))
    with pytest.raises(BackendError):
        create("mono", checkpoint=str(path), colour="blue")
    stereo = save_checkpoint(tmp_path / "stereo.pt", RoadBEV(model_config("tiny", "stereo"), GridSpec()))
    with pytest.raises(FrameError, match="right image"):
        create("stereo", checkpoint=str(stereo)).estimate(_frame(stereo=False))


@pytest.mark.parametrize(("kind", "bound_cm", "share_of_flat"), [("stereo", 1.0, 0.2), ("mono", 5.0, 0.75)])
def test_shipped_checkpoints_measure_the_road(kind: str, bound_cm: float, share_of_flat: float) -> None:
    """The shipped `lite` models on two test scenes: far better than predicting a flat road.

    Predicting 0 everywhere scores 6.1 cm on these two scenes (4.3 cm on the whole test set); a
    broken input path (wrong images, a photometric channel read at the wrong scale) loses the
    stereo model's centimetre accuracy and brings mono near the flat road's error.
    """
    from roadbev_lab.evaluation.frames import evaluate
    from roadbev_lab.synth import make_sample
    from roadbev_lab.training.datasets import TEST_SEED_START

    torch.set_flush_denormal(True)
    samples = [make_sample(TEST_SEED_START + i) for i in range(2)]
    metrics = evaluate(create(kind, GridSpec()), samples).metrics
    # every cell the cameras see gets an answer; cells hidden behind a crest are NaN (visibility)
    assert metrics["coverage_pct"] > 97.0
    raw = evaluate(create(kind, GridSpec(), raw=True), samples).metrics
    assert raw["coverage_pct"] > 99.0
    assert metrics["abs_err_cm"] < bound_cm, metrics["abs_err_cm"]
    flat_cm = 100.0 * float(np.mean(np.concatenate([np.abs(s.truth.elevation[np.isfinite(s.truth.elevation)])
                                                    for s in samples])))
    assert metrics["abs_err_cm"] < share_of_flat * flat_cm, (metrics["abs_err_cm"], flat_cm)


def test_a_grid_or_rig_beyond_the_training_is_refused_or_flagged(tmp_path: Path) -> None:
    torch.manual_seed(0)
    path = save_checkpoint(tmp_path / "mono.pt", RoadBEV(model_config("tiny", "mono"), GridSpec()))
    far = GridSpec(x_min=6.5, x_max=18.5, y_min=-0.92, y_max=1.0, resolution=0.06, base_height=1.65)
    with pytest.raises(BackendError, match=r"outside what mono\.pt was trained for.*x window.*base_height"):
        create("mono", far, checkpoint=str(path))
    with pytest.raises(BackendError, match="out_of_distribution must be one of"):
        create("mono", checkpoint=str(path), out_of_distribution="ignore")
    flagged = create("mono", far, checkpoint=str(path), out_of_distribution="flag").estimate(_frame(stereo=False))
    seen = np.isfinite(flagged.elevation)
    assert flagged.out_of_distribution and seen.any()
    assert np.allclose(flagged.uncertainty[seen], far.z_max - far.z_min)  # not calibrated away
    # a rig far from the training one is refused per frame, on the default grid
    backend = create("mono", checkpoint=str(path))
    wide = StereoCamera(fx=60.0, fy=60.0, cx=119.5, cy=65.5, baseline=0.0, width=240, height=132)
    img = np.zeros((132, 240, 3), np.uint8)
    with pytest.raises(OutOfDistributionError, match="focal length"):
        backend.estimate(Frame(img, None, wide, Attitude.from_degrees(0.5, 18.5)))
    assert not backend.estimate(_frame(stereo=False)).out_of_distribution
