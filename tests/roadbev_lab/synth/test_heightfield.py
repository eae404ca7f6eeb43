"""Height fields: ISO 8608 roughness spectrum and the signs/shapes of discrete features."""

from __future__ import annotations

import numpy as np
import pytest

from roadbev_lab.synth.heightfield import (
    FEATURE_NAMES,
    ISO8608_GD0,
    Crack,
    Kerb,
    Patch,
    Pothole,
    Rut,
    SpeedBump,
    Step,
    SurfaceCanvas,
    SynthError,
    profile_psd,
    roughness_field,
    sample_feature,
)

RES = 0.01


def _field(road_class: str, seed: int = 0, shape: tuple[int, int] = (2048, 256)) -> np.ndarray:
    return roughness_field(shape, RES, road_class, np.random.default_rng(seed))


def test_roughness_psd_follows_iso8608_slope_and_level() -> None:
    field = _field("C")
    n, g = profile_psd(field.T, RES)  # profiles along x, averaged over the columns
    band = (n >= 0.4) & (n <= 2.0)  # inside the ISO band, clear of both corners
    slope = np.polyfit(np.log(n[band]), np.log(g[band]), 1)[0]
    assert -2.4 < slope < -1.7
    # Level: Gd(n) = Gd(n0) (n / n0)^-2 within a factor of 1.6 (one class is a factor of 4).
    expected = ISO8608_GD0["C"] * (n[band] / 0.1) ** -2
    ratio = np.exp(np.mean(np.log(g[band] / expected)))
    assert 1 / 1.6 < ratio < 1.6
    # Beyond the ISO band the spectrum steepens (texture is the albedo's job, not the height's).
    short = (n >= 12.0) & (n <= 30.0)
    assert np.polyfit(np.log(n[short]), np.log(g[short]), 1)[0] < -3.2


def test_roughness_classes_are_ordered_by_a_factor_two_in_amplitude() -> None:
    rms = [float(_field(c, seed=3).std()) for c in "ABCDE"]
    ratios = np.array(rms[1:]) / np.array(rms[:-1])
    assert np.all(np.abs(ratios - 2.0) < 0.05)  # same seed: exact factor sqrt(4)
    assert rms[2] < 0.02  # class C over a <10 m wavelength band is millimetres, not decimetres


def test_roughness_is_deterministic_and_seed_dependent() -> None:
    a, b, c = _field("B", 7, (256, 128)), _field("B", 7, (256, 128)), _field("B", 8, (256, 128))
    assert a.dtype == np.float32 and a.shape == (256, 128)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_roughness_rejects_bad_input() -> None:
    with pytest.raises(SynthError, match="class"):
        roughness_field((64, 64), RES, "F", np.random.default_rng(0))
    with pytest.raises(SynthError, match="small"):
        roughness_field((4, 64), RES, "A", np.random.default_rng(0))


def _canvas() -> SurfaceCanvas:
    return SurfaceCanvas.empty(0.0, -2.0, 801, 401, RES)  # x 0..8 m, y -2..2 m


def _at(canvas: SurfaceCanvas, x: float, y: float) -> float:
    return float(canvas.displacement(np.array([x]), np.array([y]))[0])


def test_pothole_is_negative_with_sloped_edge_and_zero_outside() -> None:
    canvas = _canvas()
    Pothole(x=4.0, y=0.0, radius_x=0.3, radius_y=0.25, depth=0.06, edge_width=0.05, angle=0.3).apply(
        canvas, np.random.default_rng(0)
    )
    centre = _at(canvas, 4.0, 0.0)
    assert -0.075 < centre < -0.045
    assert _at(canvas, 4.0, 1.0) == 0.0 and _at(canvas, 5.0, 0.0) == 0.0
    assert canvas.heights.max() <= 1e-6  # a pothole only goes down
    # the wall is sloped, not a cliff: intermediate depths exist on a line through the rim
    line = canvas.displacement(np.linspace(3.5, 4.0, 200), np.zeros(200))
    assert np.any((line < -0.01) & (line > -0.04))
    assert canvas.albedo[400, 200] < 1.0  # darker floor


@pytest.mark.parametrize("profile", ["parabolic", "circular", "sinusoidal", "flat_top"])
def test_bump_profiles_peak_at_their_height_and_vanish_outside(profile: str) -> None:
    bump = SpeedBump(x=4.0, y=0.0, length=0.8, height=0.07, width=3.0, profile=profile, ramp=0.2)
    u = np.linspace(-0.6, 0.6, 1201)
    prof = bump.along(u)
    assert prof.max() == pytest.approx(0.07, abs=1e-4)
    assert np.all(prof[np.abs(u) >= 0.4] == 0.0)
    assert np.all(prof >= 0.0)
    if profile == "flat_top":
        assert np.all(np.abs(prof[np.abs(u) < 0.15] - 0.07) < 1e-9)  # plateau
    canvas = _canvas()
    bump.apply(canvas, np.random.default_rng(0))
    assert _at(canvas, 4.0, 0.0) == pytest.approx(0.07, abs=2e-3)
    assert _at(canvas, 4.0, 1.9) == 0.0  # beyond the tapered ends


def test_bump_rejects_unknown_profile() -> None:
    with pytest.raises(SynthError, match="profile"):
        SpeedBump(x=0, y=0, length=1, height=0.05, width=2, profile="square").along(np.zeros(3))


def test_ruts_crack_step_kerb_patch_signs() -> None:
    rng = np.random.default_rng(1)
    canvas = _canvas()
    Rut(x=4.0, y=0.0, length=6.0, depth=0.02, width=0.4).apply(canvas, rng)
    assert _at(canvas, 4.0, 0.8) < -0.01 and _at(canvas, 4.0, -0.8) < -0.01
    assert abs(_at(canvas, 4.0, 0.0)) < 0.004  # between the wheel tracks

    canvas = _canvas()
    Crack(x=4.0, y=0.0, length=1.0, heading=0.0, width=0.012, depth=0.008).apply(canvas, rng)
    assert -0.0085 < canvas.heights.min() < -0.004 and canvas.heights.max() == 0.0
    assert canvas.albedo.min() < 0.6  # dark line

    canvas = _canvas()
    Step(x=3.0, y=0.0, height=0.03, length=2.0, bevel=0.01, orientation="transverse").apply(canvas, rng)
    assert _at(canvas, 4.0, 1.0) == pytest.approx(0.03, abs=1e-4)
    assert _at(canvas, 2.9, 1.0) == 0.0 and _at(canvas, 5.2, 1.0) == 0.0
    canvas = _canvas()
    Step(x=4.0, y=0.2, height=-0.03, length=3.0, bevel=0.01, orientation="longitudinal").apply(canvas, rng)
    assert _at(canvas, 4.0, -0.5) == pytest.approx(-0.03, abs=1e-4)  # milled to the right of y
    assert _at(canvas, 4.0, 0.5) == 0.0

    canvas = _canvas()
    Kerb(x=0.0, y=1.0, height=0.12, side=1).apply(canvas, rng)
    assert _at(canvas, 4.0, 1.5) == pytest.approx(0.12, abs=1e-4) and _at(canvas, 4.0, 0.5) == 0.0
    canvas = _canvas()  # a kerb of finite length: raised over its length, the road again beyond its ramps
    Kerb(x=4.0, y=1.0, height=0.12, side=1, length=2.0, end_ramp=0.5).apply(canvas, rng)
    assert _at(canvas, 4.0, 1.5) == pytest.approx(0.12, abs=1e-4)
    assert _at(canvas, 4.9, 1.5) == pytest.approx(0.12, abs=1e-4)
    assert 0.0 < _at(canvas, 5.25, 1.5) < 0.12  # on the dropped end
    assert _at(canvas, 2.4, 1.5) == 0.0 and _at(canvas, 5.6, 1.5) == 0.0 and _at(canvas, 4.0, 0.5) == 0.0

    canvas = _canvas()
    Patch(x=4.0, y=0.0, size_x=1.0, size_y=0.8, height=0.01, angle=0.1, tone=0.7).apply(canvas, rng)
    assert _at(canvas, 4.0, 0.0) == pytest.approx(0.01, abs=1e-4) and _at(canvas, 5.0, 0.0) == 0.0


@pytest.mark.parametrize("name", FEATURE_NAMES)
def test_sampled_features_change_the_surface_with_the_right_sign(name: str) -> None:
    canvas = _canvas()
    feature = sample_feature(name, np.random.default_rng(5), 4.0, 0.0)
    assert feature.name == name
    feature.apply(canvas, np.random.default_rng(5))
    if name in ("pothole", "rut", "crack"):
        assert canvas.heights.min() < -0.003 and canvas.heights.max() <= 1e-6
    elif name in ("speed_bump", "hump", "kerb"):
        assert canvas.heights.max() > 0.03 and canvas.heights.min() >= -1e-6
    else:  # steps and patches go either way, but do change the surface
        assert np.abs(canvas.heights).max() > 0.003


def test_unknown_feature_is_rejected() -> None:
    with pytest.raises(SynthError, match="manhole"):
        sample_feature("manhole", np.random.default_rng(0), 0.0, 0.0)


def test_profile_psd_of_a_sine_peaks_at_its_frequency() -> None:
    x = np.arange(4096) * RES
    n, g = profile_psd(0.01 * np.sin(2 * np.pi * 2.0 * x), RES)
    assert n[np.argmax(g)] == pytest.approx(2.0, abs=0.05)
