"""How hard the synthetic road is for a stereo matcher: named ranges of pavement and camera
appearance, from weak to strong texture.

Without a range (the ``clean`` appearance, scene version 1's generator) ``random_road`` and
``build_scene`` give a Lambertian pavement of one middling texture strength, seen by a clean
camera. Real road is a range: on the three KITTI
frames (``benchmarks.bench_texture``; figures in the README, "Real against synthetic road
texture") one dark asphalt has far less gradient energy than the synthetic road, two grainy ones
several times more, and on all three the cameras share much less of the texture (the 9 x 9 ZNCC
of the two images' fine band at the true disparity): sensor noise, a rectification residual and
glints one camera sees alone. An :class:`AppearanceRange` spans that: each scene draws a
strength in [0, 1] and gets the :class:`Appearance` between the range's weak and strong ends.

Since scene version 2 the random scenes and drives draw their appearance from
:data:`DEFAULT_APPEARANCE` (``real-road``), and the roads the demo and the benchmarks build by
hand take the range's middle (:data:`REAL_ROAD_MIDDLE`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from roadbev_lab.synth.heightfield import SynthError
from roadbev_lab.synth.scene import RoadConfig

__all__ = [
    "APPEARANCE_NAMES",
    "APPEARANCE_RANGES",
    "CLEAN",
    "DEFAULT_APPEARANCE",
    "REAL_ROAD",
    "REAL_ROAD_MIDDLE",
    "Appearance",
    "AppearanceRange",
    "appearance_range",
]


@dataclass(frozen=True)
class Appearance:
    """One setting of the pavement and camera (the :class:`RoadConfig` fields of the same names).

    Attributes:
        texture_scale: multiplies the pavement texture's drawn contrast.
        noise_sigma: sensor read noise (DN).
        row_offset_px: rectification residual (px, the right image lower).
        glint_density, glint_brightness, glint_lobe_deg: specular glints of the aggregate.
    """

    texture_scale: float
    noise_sigma: float
    row_offset_px: float
    glint_density: float
    glint_brightness: float
    glint_lobe_deg: float

    def apply(self, road: RoadConfig) -> RoadConfig:
        """``road`` with this appearance (validated by :class:`RoadConfig`)."""
        return replace(road, **asdict(self))


@dataclass(frozen=True)
class AppearanceRange:
    """Appearances from ``weak`` (strength 0) to ``strong`` (strength 1).

    The texture scale is interpolated geometrically (it spans more than a decade); the read noise
    and the glint density, what the two cameras do not share, with the square of the strength
    (a linear blend gives the middle of the real-road range less shared texture, by the
    inter-view ZNCC of ``benchmarks.bench_texture``, than either of its real ends has); the rest
    linearly.
    """

    name: str
    weak: Appearance
    strong: Appearance

    def at(self, strength: float) -> Appearance:
        """The appearance at ``strength`` in [0, 1]."""
        if not (math.isfinite(strength) and 0.0 <= strength <= 1.0):
            raise SynthError(f"appearance strength must be in [0, 1], got {strength}")
        w, s = self.weak, self.strong

        def lerp(a: float, b: float, t: float = strength) -> float:
            return a + (b - a) * t

        return Appearance(
            texture_scale=w.texture_scale * (s.texture_scale / w.texture_scale) ** strength,
            noise_sigma=lerp(w.noise_sigma, s.noise_sigma, strength**2),
            row_offset_px=lerp(w.row_offset_px, s.row_offset_px),
            glint_density=lerp(w.glint_density, s.glint_density, strength**2),
            glint_brightness=lerp(w.glint_brightness, s.glint_brightness),
            glint_lobe_deg=lerp(w.glint_lobe_deg, s.glint_lobe_deg),
        )

    def draw(self, rng: np.random.Generator) -> Appearance:
        """A random appearance of the range (strength uniform in [0, 1])."""
        return self.at(float(rng.uniform(0.0, 1.0)))


# Ends measured against the KITTI frames with their rig and window (benchmarks.bench_texture,
# docs/results/robustness.md, "Real against synthetic road texture"): the weak end against the dark asphalt of
# KITTI 2012 000070, the strong end against the grainy asphalt of KITTI 2015 000046 and the
# object frame (gradient energy, inter-view ZNCC, StereoBM's coverage); the rectification
# residuals are where bench_kitti's row-offset sweep puts each real frame's best coverage
# (about 0 for the 2012 frame, 0.1-0.25 px for the other two). Generator statistics were
# matched; no backend was tuned.
REAL_ROAD = AppearanceRange(
    "real-road",
    weak=Appearance(texture_scale=0.3, noise_sigma=2.0, row_offset_px=0.05, glint_density=0.0,
                    glint_brightness=3.0, glint_lobe_deg=4.5),
    strong=Appearance(texture_scale=4.5, noise_sigma=5.0, row_offset_px=0.15, glint_density=0.01,
                      glint_brightness=3.0, glint_lobe_deg=4.5),
)
APPEARANCE_RANGES: dict[str, AppearanceRange] = {REAL_ROAD.name: REAL_ROAD}
DEFAULT_APPEARANCE = REAL_ROAD.name  # what random scenes and drives draw from (scene version 2)
CLEAN = "clean"  # no range: the generator's own draws, Lambertian (scene version 1's default)
APPEARANCE_NAMES: tuple[str, ...] = (*APPEARANCE_RANGES, CLEAN)
# The appearance of roads built by hand (the demo's, the ride's, the hazards' drives): the
# middle of the default range, a texture of about the generator's own strength that the two
# cameras share less of.
REAL_ROAD_MIDDLE = REAL_ROAD.at(0.5)


def appearance_range(name: str | None) -> AppearanceRange | None:
    """The named range: None is :data:`DEFAULT_APPEARANCE`; :data:`CLEAN` is no range (None).

    Raises:
        SynthError: an unknown name.
    """
    if name is None:
        name = DEFAULT_APPEARANCE
    if name == CLEAN:
        return None
    if name not in APPEARANCE_RANGES:
        raise SynthError(f"unknown appearance {name!r}; choose from {', '.join(APPEARANCE_NAMES)}")
    return APPEARANCE_RANGES[name]
