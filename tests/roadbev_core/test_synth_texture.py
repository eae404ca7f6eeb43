"""Pavement tiles: the cameras' glint tiles share the asked share of their glints."""

from __future__ import annotations

import numpy as np
import pytest

from roadbev_core.synth import SynthError
from roadbev_core.synth.texture import make_glint_tile


def _glints(view: int, correlation: float, density: float = 0.002) -> np.ndarray:
    return make_glint_tile(5, view, density, 3.0, correlation, size=256).pyramid[0] > 1.5  # [256, 256] bool


def _overlap(correlation: float) -> float:
    """Share of the left camera's glint pixels that glint in the right camera too."""
    left, right = _glints(0, correlation), _glints(1, correlation)
    return float((left & right).sum() / left.sum())


def test_glint_tiles_share_the_correlated_part_between_the_cameras() -> None:
    np.testing.assert_array_equal(_glints(0, 1.0), _glints(1, 1.0))  # all shared: one tile
    chance = float(_glints(0, 0.0).mean())  # two independent layouts overlap by chance only
    assert _overlap(0.0) < 3 * chance + 0.02
    assert _overlap(0.5) == pytest.approx(0.5, abs=0.12)
    assert _overlap(0.0) < _overlap(0.5) < _overlap(0.9) < 1.0


def test_glint_tiles_are_additive_brightness_on_a_dark_ground() -> None:
    tile = make_glint_tile(5, 0, 0.002, 3.0, 0.5, size=256).pyramid[0]
    assert tile.min() == 0.0 and tile.max() == pytest.approx(3.0, rel=1e-5)
    # about density x facet area of the pavement glints (facets of ~1.4 mm across, 3 mm texels)
    assert 0.001 < float((tile > 0).mean()) < 0.05


@pytest.mark.parametrize(
    ("view", "density", "brightness", "correlation"),
    [(2, 0.002, 3.0, 0.5), (0, 0.0, 3.0, 0.5), (0, 0.002, -1.0, 0.5), (0, 0.002, 3.0, 1.5)],
)
def test_bad_glint_parameters_are_refused(view: int, density: float, brightness: float, correlation: float) -> None:
    with pytest.raises(SynthError):
        make_glint_tile(5, view, density, brightness, correlation, size=256)
