"""Pavement tiles: glint layouts are independent draws, additive and checked."""

from __future__ import annotations

import numpy as np
import pytest

from roadbev_lab.synth import SynthError
from roadbev_lab.synth.texture import make_glint_tile


def _glints(layout: int, variant: int = 5) -> np.ndarray:
    return make_glint_tile(variant, layout, 0.002, 3.0, size=256).pyramid[0] > 1.5  # [256, 256] bool


def test_glint_layouts_are_reproducible_and_independent_of_each_other() -> None:
    np.testing.assert_array_equal(_glints(1), _glints(1))
    chance = float(_glints(1).mean())
    for a, b in ((0, 1), (1, 2), (0, 2)):
        both = float((_glints(a) & _glints(b)).sum() / _glints(a).sum())
        assert both < 3 * chance + 0.02  # they overlap by chance only
    assert not np.array_equal(_glints(1, variant=5), _glints(1, variant=6))


def test_glint_tiles_are_additive_brightness_on_a_dark_ground() -> None:
    tile = make_glint_tile(5, 0, 0.002, 3.0, size=256).pyramid[0]
    assert tile.min() == 0.0 and tile.max() == pytest.approx(3.0, rel=1e-5)
    # about density x facet area of the pavement glints (facets of ~1.4 mm across, 3 mm texels)
    assert 0.001 < float((tile > 0).mean()) < 0.05


@pytest.mark.parametrize(
    ("layout", "density", "brightness", "size"),
    [(3, 0.002, 3.0, 256), (0, 0.0, 3.0, 256), (0, 0.002, -1.0, 256), (0, 0.002, 3.0, 300)],
)
def test_bad_glint_parameters_are_refused(layout: int, density: float, brightness: float, size: int) -> None:
    with pytest.raises(SynthError):
        make_glint_tile(5, layout, density, brightness, size=size)
