"""A synthetic road scene: configuration, surface rasters, markings, lighting and sky.

:func:`build_scene` turns a :class:`RoadConfig` and a seed into a :class:`Scene` over a strip of
the world frame (x along the road, y left, z up; the ego lane is centred on y = 0). The renderer
(:mod:`roadbev_lab.synth.render`) and the ground truth (:mod:`roadbev_lab.synth.drive`) both
read the surface from the scene, so they cannot disagree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import cast

import cv2
import numpy as np

from roadbev_lab.synth.heightfield import (
    FEATURE_NAMES,
    ISO8608_GD0,
    Feature,
    Kerb,
    SurfaceCanvas,
    SynthError,
    roughness_field,
    sample_feature,
)
from roadbev_lab.synth.texture import SURFACES, AlbedoTile, make_glint_tile, make_tile

__all__ = ["LaneMarking", "RoadConfig", "Scene", "build_scene"]

# Displacement is clipped to this band so that, with the limits on grade, cross-slope and the
# suspension, the surface in the grid stays inside the default +-0.20 m voxel range.
DISPLACEMENT_LIMIT = 0.16


@dataclass(frozen=True)
class RoadConfig:
    """What the synthetic road looks like.

    Attributes:
        road_class: ISO 8608 roughness class "A" (smooth) .. "E" (very poor).
        features: discrete features to place (names from ``FEATURE_NAMES``; repeat a name for
            more of it in one sample; drives repeat the list along the road).
        surface: "asphalt" or "concrete".
        cross_slope: lateral slope dz/dy of the road plane (0.02 = 2 % falling to the right).
        grade: longitudinal slope dz/dx (|grade| <= 0.012 keeps the far grid inside +-0.20 m).
        roughness_scale: multiplies the ISO 8608 amplitude (0 = smooth plane plus features).
        feature_spacing_m: mean distance between features along a drive.
        lane_markings, stains, shadows: appearance elements on/off.
        noise_sigma: sensor read noise (8-bit digital numbers, 1-sigma); shot noise is added on top.
        gain_mismatch: the right camera's gain differs from the left by up to this fraction.
        row_offset_px: the right image sits this many pixels lower than a perfect rectification
            puts it (sub-pixel, bilinear; a real calibration leaves a few tenths of a pixel of
            vertical disparity); 0, the default, renders a perfectly rectified pair.
        jpeg_quality: JPEG-compress both images at this quality (None = lossless).
        texture_scale: multiplies the pavement texture's contrast that each scene draws (1, the
            default: the drawn contrast).
        glint_density: specular glints of the pavement's aggregate per mm^2 (0, the default: a
            Lambertian pavement); see :func:`roadbev_lab.synth.texture.make_glint_tile`.
        glint_brightness: a glint's added albedo (the asphalt binder's is about 0.16).
        glint_lobe_deg: angular width of a glint's specular lobe (degrees): at a point whose
            rays from the two cameras are dtheta apart (baseline / range), a share
            exp(-(dtheta / lobe)^2) of the glints is in both images, the rest in one image only
            (texture the other camera cannot match).
        blur_sigma_px: optical blur (Gaussian sigma, pixels).
        vignetting: brightness lost in the image corners (both cameras).
        resolution: height-field cell size (m).
    """

    road_class: str = "C"
    features: tuple[str, ...] = ("pothole", "speed_bump", "crack", "patch")
    surface: str = "asphalt"
    cross_slope: float = 0.02
    grade: float = 0.0
    roughness_scale: float = 1.0
    feature_spacing_m: float = 6.0
    lane_markings: bool = True
    stains: bool = True
    shadows: bool = True
    noise_sigma: float = 1.5
    gain_mismatch: float = 0.04
    row_offset_px: float = 0.0
    jpeg_quality: int | None = None
    texture_scale: float = 1.0
    glint_density: float = 0.0
    glint_brightness: float = 3.0
    glint_lobe_deg: float = 3.4
    blur_sigma_px: float = 0.5
    vignetting: float = 0.12
    resolution: float = 0.01

    def __post_init__(self) -> None:
        if self.road_class not in ISO8608_GD0:
            raise SynthError(f"road_class must be one of A..E (ISO 8608), got {self.road_class!r}")
        unknown = [f for f in self.features if f not in FEATURE_NAMES]
        if unknown:
            raise SynthError(f"unknown road feature(s) {unknown}; choose from {', '.join(FEATURE_NAMES)}")
        if self.surface not in SURFACES:
            raise SynthError(f"surface must be one of {SURFACES}, got {self.surface!r}")
        if abs(self.cross_slope) > 0.04:
            raise SynthError(f"cross_slope {self.cross_slope} is beyond +-0.04 (4 %)")
        if abs(self.grade) > 0.012:
            raise SynthError(f"grade {self.grade} is beyond +-0.012: the far grid would leave +-0.20 m")
        if not 0.0 <= self.roughness_scale <= 3.0:
            raise SynthError(f"roughness_scale must be in [0, 3], got {self.roughness_scale}")
        if self.feature_spacing_m <= 0.5:
            raise SynthError(f"feature_spacing_m must be > 0.5 m, got {self.feature_spacing_m}")
        if self.noise_sigma < 0 or self.blur_sigma_px < 0:
            raise SynthError("noise_sigma and blur_sigma_px must be >= 0")
        if not 0.0 <= self.vignetting < 1.0:
            raise SynthError(f"vignetting must be in [0, 1), got {self.vignetting}")
        if not 0.0 <= self.gain_mismatch < 0.5:
            raise SynthError(f"gain_mismatch must be in [0, 0.5), got {self.gain_mismatch}")
        if not (math.isfinite(self.row_offset_px) and abs(self.row_offset_px) <= 2.0):
            raise SynthError(f"row_offset_px must be within +-2 px, got {self.row_offset_px}")
        if self.jpeg_quality is not None and not 1 <= int(self.jpeg_quality) <= 100:
            raise SynthError(f"jpeg_quality must be in 1..100 or None, got {self.jpeg_quality}")
        if not (math.isfinite(self.texture_scale) and 0.0 < self.texture_scale <= 10.0):
            raise SynthError(f"texture_scale must be in (0, 10], got {self.texture_scale}")
        if not (math.isfinite(self.glint_density) and 0.0 <= self.glint_density <= 0.1):
            raise SynthError(f"glint_density must be in [0, 0.1] per mm^2, got {self.glint_density}")
        if not (math.isfinite(self.glint_brightness) and 0.0 < self.glint_brightness <= 10.0):
            raise SynthError(f"glint_brightness must be in (0, 10], got {self.glint_brightness}")
        if not (math.isfinite(self.glint_lobe_deg) and 0.0 < self.glint_lobe_deg <= 90.0):
            raise SynthError(f"glint_lobe_deg must be in (0, 90], got {self.glint_lobe_deg}")
        if not 0.002 <= self.resolution <= 0.05:
            raise SynthError(f"height-field resolution must be in [0.002, 0.05] m, got {self.resolution}")


@dataclass(frozen=True)
class LaneMarking:
    """A painted line along the road at lateral position ``y`` (dashed when ``dash`` > 0)."""

    y: float
    width: float
    dash: float
    gap: float
    phase: float
    colour: tuple[float, float, float]


@dataclass
class Scene:
    """Everything the renderer and the ground truth need about one synthetic road.

    Attributes:
        config: the road configuration.
        canvas: displacement / albedo / light rasters over the strip.
        features: the placed features (world positions).
        tile, verge: albedo tiles of the pavement and of the verge beyond it.
        tile_angle, tile_offset: how the pavement tile is laid (quarter turns, metres offset).
        paved: (y_right, y_left) lateral extent of the pavement.
        markings: painted lines.
        sun: unit vector towards the sun (world), sun_strength, ambient: lighting.
        sky_horizon, sky_zenith, haze: RGB colours (linear, 0..1).
        treeline: [n] heights (radians) of the distant skyline over 360 deg of azimuth.
        displacement_range: (min, max) displacement over the rasters (m).
        texture_contrast: scales the pavement texture's contrast (aged, worn, fresh surfaces).
        tint: RGB tint of the pavement.
        glints: the glint tiles (None: no glints; ``config.glint_density``): the layout both
            cameras see, the left camera's own, the right camera's own.
        tile_variant: which random instance the pavement, verge and glint tiles are.
    """

    config: RoadConfig
    canvas: SurfaceCanvas
    features: list[Feature]
    tile: AlbedoTile
    verge: AlbedoTile
    tile_angle: float
    tile_offset: tuple[float, float]
    paved: tuple[float, float]
    markings: list[LaneMarking]
    sun: np.ndarray
    sun_strength: float
    ambient: float
    sky_horizon: np.ndarray
    sky_zenith: np.ndarray
    treeline: np.ndarray
    displacement_range: tuple[float, float] = field(default=(-0.16, 0.16))
    texture_contrast: float = 1.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    glints: tuple[AlbedoTile, AlbedoTile, AlbedoTile] | None = None
    tile_variant: int = 0

    def plane(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Height of the tilted road plane (m)."""
        return self.config.grade * np.asarray(x) + self.config.cross_slope * np.asarray(y)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface height at world points (plane + displacement, float64, bilinear)."""
        return cast("np.ndarray", self.plane(x, y) + self.canvas.displacement(x, y))


def _smooth_noise(shape: tuple[int, int], cells: float, rng: np.random.Generator) -> np.ndarray:
    small = (max(2, int(shape[0] / cells) + 2), max(2, int(shape[1] / cells) + 2))
    return cv2.resize(
        rng.standard_normal(small).astype(np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC
    )


def _add_stains(canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
    """Oil drip band in the lane centre, polished wheel tracks, a few dark stains, wear."""
    n_x, n_y = canvas.heights.shape
    r = canvas.resolution
    ys = canvas.y0 + np.arange(n_y) * r
    wear = 1.0 + 0.10 * _smooth_noise((n_x, n_y), 1.5 / r, rng)  # metre-scale tone variation
    drip = 1.0 - 0.10 * np.exp(-0.5 * (ys / 0.25) ** 2)  # oil drip band between the wheels
    tracks = 1.0 + 0.05 * (np.exp(-0.5 * ((ys - 0.8) / 0.2) ** 2) + np.exp(-0.5 * ((ys + 0.8) / 0.2) ** 2))
    canvas.albedo *= (wear * (drip * tracks)[None, :]).astype(np.float32)
    length = n_x * r
    for _ in range(int(rng.poisson(length / 6.0))):
        cx = canvas.x0 + rng.uniform(0, length)
        cy = rng.uniform(-2.0, 2.0)
        rad = rng.uniform(0.1, 0.6)
        win = canvas.window(cx - rad * 1.5, cx + rad * 1.5, cy - rad * 1.5, cy + rad * 1.5)
        if win is None:
            continue
        rows, cols, xs, ys_w = win
        blob = _smooth_noise((xs.shape[0], ys_w.shape[1]), 0.1 / r, rng) * 0.35
        dist = np.hypot(xs - cx, ys_w - cy) / rad + blob
        stain = np.clip(1.2 - dist, 0.0, 1.0)
        canvas.albedo[rows, cols] *= (1.0 - rng.uniform(0.2, 0.5) * stain).astype(np.float32)


def _add_slab_joints(canvas: SurfaceCanvas, rng: np.random.Generator) -> None:
    """Concrete pavement: sealed transverse joints every 4-6 m and a longitudinal joint at the
    lane edge, with a few millimetres of faulting (slabs settle unevenly)."""
    n_x, n_y = canvas.heights.shape
    r = canvas.resolution
    xs = canvas.x0 + np.arange(n_x) * r
    ys = canvas.y0 + np.arange(n_y) * r
    spacing = rng.uniform(4.0, 6.0)
    joint_x = np.arange(canvas.x0 + rng.uniform(0.0, spacing), xs[-1], spacing)
    fault = np.zeros(n_x, np.float32)
    dist = np.full(n_x, np.inf, np.float32)
    level = 0.0
    start = 0
    for jx in joint_x:  # each slab sits a little higher or lower than the previous one
        stop = int(np.searchsorted(xs, jx))
        fault[start:stop] = level
        level = float(np.clip(level + rng.normal(0.0, 0.002), -0.006, 0.006))
        start = stop
        dist = np.minimum(dist, np.abs(xs - jx).astype(np.float32))
    fault[start:] = level
    groove = np.clip(1.0 - dist / 0.006, 0.0, 1.0)[:, None]  # 12 mm wide, V-shaped
    lateral = np.abs(ys - rng.choice([-1.0, 1.0]) * rng.uniform(1.6, 1.9))
    long_groove = np.clip(1.0 - lateral / 0.006, 0.0, 1.0)[None, :]
    canvas.heights += fault[:, None] - 0.006 * np.maximum(groove, long_groove)
    canvas.albedo *= (1.0 - 0.55 * np.maximum(groove, long_groove)).astype(np.float32)


def _add_shadows(canvas: SurfaceCanvas, rng: np.random.Generator, sun: np.ndarray) -> None:
    """Cast shadows of roadside trees and poles (soft-edged), laid along the sun's azimuth."""
    n_x, n_y = canvas.heights.shape
    r = canvas.resolution
    ys = canvas.y0 + np.arange(n_y) * r
    light = np.ones((n_x, n_y), np.float32)
    # Tree canopies: thresholded smooth noise, present in some stretches only.
    canopy = _smooth_noise((n_x, n_y), 1.6 / r, rng) + 0.45 * _smooth_noise((n_x, n_y), 0.3 / r, rng)
    stretch = _smooth_noise((n_x, 1), 15.0 / r, rng)
    side = np.clip((ys[None, :] * np.sign(sun[1] + 1e-9) * -1.0 + 1.0) / 4.0, 0.0, 1.0)  # shade falls away from the sun
    density = np.clip(stretch, -1.0, 1.0) * 0.9 + side * 0.8 - 0.6
    trees = np.clip((canopy + density - 1.0) * 3.0, 0.0, 1.0)
    light *= (1.0 - 0.95 * trees).astype(np.float32)
    # Poles and sign posts: straight strips along the sun's azimuth.
    az = math.atan2(-sun[1], -sun[0])  # shadow direction on the ground
    for _ in range(int(rng.poisson(n_x * r / 15.0))):
        px, py = canvas.x0 + rng.uniform(0, n_x * r), float(rng.choice([-4.0, 4.0]))
        width = rng.uniform(0.06, 0.25)
        length = rng.uniform(5.0, 12.0)
        ex, ey = px + length * math.cos(az), py + length * math.sin(az)
        win = canvas.window(min(px, ex) - width, max(px, ex) + width, min(py, ey) - width, max(py, ey) + width)
        if win is None:
            continue
        rows, cols, wx, wy = win
        d_along = math.cos(az) * (wx - px) + math.sin(az) * (wy - py)
        d_across = -math.sin(az) * (wx - px) + math.cos(az) * (wy - py)
        strip = (np.abs(d_across) < width / 2) & (d_along > 0) & (d_along < length)
        light[rows, cols] *= np.where(strip, 0.05, 1.0).astype(np.float32)
    # Penumbra: a few centimetres of blur.
    canvas.light[:] = cv2.GaussianBlur(light, (0, 0), 0.02 / r)


def _markings(rng: np.random.Generator) -> tuple[list[LaneMarking], tuple[float, float]]:
    """Painted lines and the paved extent for an ego lane 3.0-3.75 m wide centred on y = 0."""
    lane = rng.uniform(3.0, 3.75)
    white = (0.75, 0.75, 0.72)
    yellow = (0.80, 0.62, 0.15)
    left_lanes = int(rng.integers(0, 3))
    marks = [LaneMarking(y=-lane / 2, width=rng.uniform(0.12, 0.2), dash=0.0, gap=0.0, phase=0.0, colour=white)]
    for k in range(1, left_lanes + 1):
        centre = k * lane - lane / 2
        kind = rng.random()
        if kind < 0.6:
            marks.append(
                LaneMarking(centre, 0.15, rng.uniform(2.0, 6.0), rng.uniform(4.0, 9.0), rng.uniform(0, 10), white)
            )
        else:
            marks.append(LaneMarking(centre - 0.1, 0.12, 0.0, 0.0, 0.0, yellow))
            marks.append(LaneMarking(centre + 0.1, 0.12, 0.0, 0.0, 0.0, yellow))
    marks.append(LaneMarking((left_lanes + 0.5) * lane, 0.15, 0.0, 0.0, 0.0, white))
    paved = (-lane / 2 - rng.uniform(0.3, 1.0), (left_lanes + 0.5) * lane + rng.uniform(0.3, 1.0))
    return marks, paved


def build_scene(
    config: RoadConfig,
    seed: int,
    x_range: tuple[float, float],
    feature_centres: list[tuple[str, float, float]] | None = None,
    *,
    half_width: float = 3.6,
) -> Scene:
    """Build a road scene over world x in ``x_range`` (1 cm rasters, ``2 * half_width`` wide).

    Args:
        config: road configuration.
        seed: random seed (the scene is a pure function of config, seed and ranges).
        x_range: (x_start, x_end) of the rasters (m); beyond them the road is the plain plane.
        feature_centres: (name, x, y) of features to place; None places ``config.features``
            along the strip at ``config.feature_spacing_m`` spacing near the ego lane (a drive:
            each kerb then runs over ``feature_spacing_m`` of it, not along the whole strip).
        half_width: lateral half-extent of the rasters around y = 0 (m).
    """
    x0, x1 = float(x_range[0]), float(x_range[1])
    if not x1 - x0 >= 1.0:
        raise SynthError(f"scene strip {x_range} is shorter than 1 m")
    if x1 - x0 > 700.0:
        raise SynthError(f"scene strip of {x1 - x0:.0f} m is longer than 700 m; split the drive")
    res = config.resolution
    n_x = int(math.ceil((x1 - x0) / res)) + 1
    n_y = int(math.ceil(2 * half_width / res)) + 1
    streams = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x5CE4E]).spawn(6)
    rng_rough, rng_feat, rng_look, rng_light, rng_lane, rng_place = (np.random.default_rng(s) for s in streams)

    canvas = SurfaceCanvas.empty(x0, -half_width, n_x, n_y, res)
    if config.roughness_scale > 0:
        canvas.heights += roughness_field((n_x, n_y), res, config.road_class, rng_rough, scale=config.roughness_scale)

    along_drive = feature_centres is None
    if feature_centres is None:
        feature_centres = []
        names = list(config.features)
        if names:
            x = x0 + rng_place.uniform(3.0, 3.0 + config.feature_spacing_m)
            k = 0
            while x < x1 - 2.0:
                name = names[k % len(names)]
                feature_centres.append((name, x, float(rng_place.normal(0.0, 0.5))))
                x += rng_place.uniform(0.5, 1.5) * config.feature_spacing_m
                k += 1
    features: list[Feature] = []
    for name, fx, fy in feature_centres:
        feat = sample_feature(name, rng_feat, fx, fy)
        if along_drive and isinstance(feat, Kerb):
            # A drive repeats its features every few metres: kerbs along the whole strip would
            # stack into a clipped plateau that flattens every other feature (and the roughness).
            feat = replace(feat, length=config.feature_spacing_m)
        feat.apply(canvas, rng_feat)
        features.append(feat)
    if config.surface == "concrete":
        _add_slab_joints(canvas, rng_feat)
    np.clip(canvas.heights, -DISPLACEMENT_LIMIT, DISPLACEMENT_LIMIT, out=canvas.heights)

    elevation = math.radians(rng_light.uniform(20.0, 65.0))
    azimuth = rng_light.uniform(-math.pi, math.pi)
    sun = np.array(
        [math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)]
    )
    overcast = rng_light.random() < 0.3
    sun_strength = rng_light.uniform(0.15, 0.35) if overcast else rng_light.uniform(0.8, 1.1)
    ambient = rng_light.uniform(0.7, 0.9) if overcast else rng_light.uniform(0.3, 0.45)
    if config.stains:
        _add_stains(canvas, rng_look)
    if config.shadows and not overcast:
        _add_shadows(canvas, rng_light, sun)
    markings, paved = _markings(rng_lane)
    for feat in features:  # no lane lines painted on the pavement beyond a (whole-strip) kerb
        if isinstance(feat, Kerb) and math.isinf(feat.length):  # a drive's short kerb leaves them
            markings = [m for m in markings if feat.side * (m.y - feat.y) < 0]
    if not config.lane_markings:
        markings = []
    variant = int(rng_look.integers(0, 3))
    horizon = np.array([0.78, 0.80, 0.82]) if overcast else np.array([0.70, 0.78, 0.88])
    zenith = np.array([0.62, 0.64, 0.68]) if overcast else np.array([0.30, 0.45, 0.75])
    tree_az = np.cumsum(rng_look.normal(0.0, 1.0, 720))
    tree_az = np.convolve(np.tile(tree_az - np.linspace(tree_az[0], tree_az[-1], 720), 3), np.ones(9) / 9, "same")[
        720:1440
    ]
    treeline = np.radians(np.clip(1.2 + 0.5 * tree_az / (np.abs(tree_az).max() + 1e-9) * 2.0, 0.1, 4.0))
    heights = canvas.heights
    # Pavements differ: fresh dark asphalt with little contrast, aged grey asphalt with bright
    # chips, brownish or bluish binders.
    contrast = float(rng_look.uniform(0.7, 1.35)) * config.texture_scale
    warm = float(rng_look.normal(0.0, 0.025))
    tint = (1.0 + warm, 1.0, 1.0 - warm)
    return Scene(
        config=config,
        canvas=canvas,
        features=features,
        tile=make_tile(config.surface, variant),
        verge=make_tile("verge", variant, 512, 0.006),
        # quarter turns only (the renderer's anisotropic filter works along the tile axes);
        # concrete keeps its transverse brushing across the road
        tile_angle=float(rng_look.integers(0, 4)) * math.pi / 2 if config.surface == "asphalt" else 0.0,
        tile_offset=(float(rng_look.uniform(0, 10)), float(rng_look.uniform(0, 10))),
        paved=paved,
        markings=markings,
        sun=sun,
        sun_strength=float(sun_strength),
        ambient=float(ambient),
        sky_horizon=horizon,
        sky_zenith=zenith,
        treeline=treeline,
        displacement_range=(min(float(heights.min()), 0.0) - 1e-3, max(float(heights.max()), 0.0) + 1e-3),
        texture_contrast=contrast,
        tint=tint,
        glints=glint_tiles(config, variant),
        tile_variant=variant,
    )


def glint_tiles(config: RoadConfig, variant: int) -> tuple[AlbedoTile, AlbedoTile, AlbedoTile] | None:
    """The shared, left and right glint layouts of a road (None without glints)."""
    if config.glint_density <= 0:
        return None
    shared, left, right = (
        make_glint_tile(variant, layout, config.glint_density, config.glint_brightness) for layout in (0, 1, 2)
    )
    return shared, left, right
