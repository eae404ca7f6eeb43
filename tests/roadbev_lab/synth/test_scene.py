"""Scenes: features placed along a drive's strip keep their shapes."""

from __future__ import annotations

import math

import numpy as np

from roadbev_lab.synth import RoadConfig, build_scene
from roadbev_lab.synth.heightfield import Kerb, SpeedBump
from roadbev_lab.synth.scene import DISPLACEMENT_LIMIT


def test_kerbs_along_a_drive_are_finite_and_leave_the_other_features_standing() -> None:
    # Kerbs every few metres of a 120 m strip: along the whole strip they would stack past the clip
    # and flatten the speed bumps and the roughness into a plateau.
    road = RoadConfig(road_class="B", features=("kerb", "speed_bump", "kerb", "speed_bump"), feature_spacing_m=3.0)
    scene = build_scene(road, 7, (-4.0, 120.0))
    kerbs = [f for f in scene.features if isinstance(f, Kerb)]
    bumps = [f for f in scene.features if isinstance(f, SpeedBump)]
    assert len(kerbs) >= 4 and len(bumps) >= 4
    assert all(k.length == road.feature_spacing_m for k in kerbs)
    heights = scene.canvas.heights
    assert np.mean(np.abs(heights) >= DISPLACEMENT_LIMIT - 1e-4) < 0.01
    clear = [b for b in bumps if all(abs(b.x - k.x) > k.length / 2 + k.end_ramp + 1.5 for k in kerbs)]
    assert len(clear) >= 4
    for bump in clear:  # each bump clear of a kerb stands above the road a metre before it
        crest = scene.canvas.displacement(np.array([bump.x]), np.array([bump.y]))[0]
        before = scene.canvas.displacement(np.array([bump.x - bump.length / 2 - 1.0]), np.array([bump.y]))[0]
        assert crest - before > 0.5 * bump.height
    kerb = kerbs[0]  # raised beside it, the road again past its dropped ends
    beside = kerb.y + 0.3 * kerb.side
    far = kerb.x + kerb.length / 2 + kerb.end_ramp + 0.2
    near = scene.canvas.displacement(np.array([kerb.x, far]), np.array([beside, beside]))
    assert near[0] - near[1] > 0.5 * kerb.height


def test_a_single_scene_kerb_runs_along_the_whole_strip() -> None:
    road = RoadConfig(road_class="A", features=("kerb",), roughness_scale=0.0)
    scene = build_scene(road, 3, (-4.0, 20.0), [("kerb", 5.0, 1.0)])
    (kerb,) = scene.features
    assert isinstance(kerb, Kerb) and math.isinf(kerb.length)
    side = kerb.y + 0.3 * kerb.side
    raised = scene.canvas.displacement(np.array([-3.0, 5.0, 19.0]), np.full(3, side))
    np.testing.assert_allclose(raised, kerb.height, atol=1e-4)


def test_a_lambertian_road_has_no_glints_and_a_glinting_one_a_tile_per_camera() -> None:
    assert build_scene(RoadConfig(), 3, (-4.0, 20.0)).glints is None
    scene = build_scene(RoadConfig(glint_density=0.004), 3, (-4.0, 20.0))
    assert scene.glints is not None
    shared, left, right = scene.glints
    assert shared.size == left.size == right.size == scene.tile.size and left.texel == scene.tile.texel
    assert not np.array_equal(left.pyramid[0], right.pyramid[0])
