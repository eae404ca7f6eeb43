"""Ray-casting renderer for synthetic stereo road images.

Each pixel (u, v) shoots a ray through its centre (docs/interface/frames-and-grid.md:
column i is centred at u = i), rotated into the road frame with :func:`roadbev_core.geometry.optical_from_road_rotation`
(the same rotation the projection code uses, so rendering and projection agree by
construction), and is intersected with the height field: the ray is sampled between the heights
of the highest and lowest displacement (a thin slab around the road plane), the first sample
below the surface brackets the first crossing (so bumps occlude what lies behind them), and
regula falsi refines it. Shading is Lambertian from the height-field normal with cast shadows
and ambient light; albedo comes from the pavement tile (trilinear mip filtering by the pixel's
footprint), feature rasters and painted markings; haze, sky and a distant tree line fill the
rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, cast

import cv2
import numpy as np

from roadbev_core.config import StereoCamera
from roadbev_core.geometry import Attitude, optical_from_road_rotation
from roadbev_lab.synth.heightfield import SynthError
from roadbev_lab.synth.scene import Scene
from roadbev_lab.synth.texture import build_pyramid, remap_points, sample_mip, sample_ripmap

__all__ = [
    "CameraPose",
    "RenderedView",
    "ViewCrop",
    "ego_shadow",
    "ray_directions",
    "render_stereo",
    "render_view",
    "sensor_image",
    "shift_rows",
    "view_crop",
]

MARCH_SAMPLES = 20  # slab samples per ray before refinement
REFINE_STEPS = 5  # regula falsi iterations at most
REFINE_TOL_M = 1e-4  # stop refining a ray this close to the surface (m; 0.1 mm)
LOOK_AHEAD_M = 32.0  # rasters are used this far ahead; beyond, the road is its plane
HAZE_DISTANCE_M = 400.0


@dataclass(frozen=True)
class CameraPose:
    """Where the left camera is in the world frame of a scene.

    Attributes:
        x, y, z: the left optical centre (m).
        attitude: roll/pitch of the camera body w.r.t. gravity.
        yaw: heading of the camera body w.r.t. the world x axis (rad).
    """

    x: float
    y: float
    z: float
    attitude: Attitude
    yaw: float = 0.0

    def road_origin(self, base_height: float) -> np.ndarray:
        """World position of the road-frame origin (``base_height`` below the camera)."""
        return np.array([self.x, self.y, self.z - base_height])

    def yaw_matrix(self) -> np.ndarray:
        """[3, 3] rotation from road-frame axes to world axes (about z)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def road_to_world(self, points_road: np.ndarray, base_height: float) -> np.ndarray:
        """Road-frame points [..., 3] -> world points [..., 3] (a turn about z, then a shift)."""
        p = np.asarray(points_road, np.float64)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        o = self.road_origin(base_height)
        # written out: numpy's [N, 3] @ [3, 3] is slow
        return np.stack(
            [c * p[..., 0] - s * p[..., 1] + o[0], s * p[..., 0] + c * p[..., 1] + o[1], p[..., 2] + o[2]], -1
        )

    def world_to_road(self, points_world: np.ndarray, base_height: float) -> np.ndarray:
        """World points [..., 3] -> road-frame points [..., 3]."""
        p = np.asarray(points_world, np.float64) - self.road_origin(base_height)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.stack([c * p[..., 0] + s * p[..., 1], -s * p[..., 0] + c * p[..., 1], p[..., 2]], -1)


class RenderedView(NamedTuple):
    """One rendered camera view.

    Attributes:
        radiance: [H, W, 3] float32 linear radiance (about 0..1.5).
        depth: [H, W] float32 optical-frame z of the surface seen (inf for sky).
    """

    radiance: np.ndarray
    depth: np.ndarray


def ray_directions(camera: StereoCamera, pose: CameraPose) -> np.ndarray:
    """[H*W, 3] float32 world-frame ray directions, scaled to unit optical z, row-major pixels."""
    u = (np.arange(camera.width) - camera.cx) / camera.fx  # pixel centres at integers (the interface's)
    v = (np.arange(camera.height) - camera.cy) / camera.fy
    # road = R^T optical (camera_to_road), then road axes -> world axes by yaw.
    M = optical_from_road_rotation(pose.attitude) @ pose.yaw_matrix().T  # optical row -> world row
    # d_opt @ M with d_opt = (u, v, 1), written out per row and column (separable, float32)
    cols = (u[:, None] * M[0]).astype(np.float32)  # [W, 3]
    rows = (v[:, None] * M[1] + M[2]).astype(np.float32)  # [H, 3]
    return cast("np.ndarray", (rows[:, None, :] + cols[None, :, :]).reshape(-1, 3))


class ViewCrop(NamedTuple):
    """The scene rasters one view needs, with their shading pyramid and displacement bounds."""

    heights: np.ndarray  # [n, m] float32 displacement rows along x
    shade: list[np.ndarray]  # pyramid of [n, m, 4] (dz/dx, dz/dy, albedo, light)
    bounds: list[tuple[float, float, np.ndarray, np.ndarray]]  # (cell m, radius m, max, min) fine first
    x0: float
    y0: float
    res: float


# Local displacement bounds at two scales: (coarse cell size, dilation in cells). A lookup at
# any point bounds the surface within (dilation * cell - 2 cm) of it.
BOUND_LEVELS = ((0.25, 2), (1.0, 2))
STEP_M = 0.02  # horizontal spacing of the slab samples (near the camera)
STEP_FOOTPRINTS = 0.5  # and at most half a pixel footprint further out


def _local_bounds(h: np.ndarray, res: float, cell_m: float, dilate: int) -> tuple[np.ndarray, np.ndarray]:
    """Max and min displacement over coarse cells of ``cell_m``, dilated by ``dilate`` cells.

    A point within ``dilate * cell_m - 2 cm`` of a lookup point lies in one of the dilated cells
    (the 2 cm cover the bilinear support of the fine raster), so the bounds hold for it.
    """
    k = max(int(round(cell_m / res)), 1)
    n, m = -(-h.shape[0] // k), -(-h.shape[1] // k)
    pad = np.pad(h, ((0, n * k - h.shape[0]), (0, m * k - h.shape[1])), mode="edge")
    blocks = pad.reshape(n, k, m, k)
    hi = np.maximum(blocks.max(axis=(1, 3)), 0.0)  # the plane outside the raster is 0
    lo = np.minimum(blocks.min(axis=(1, 3)), 0.0)
    kernel = np.ones((2 * dilate + 1, 2 * dilate + 1), np.uint8)
    return (
        cv2.dilate(hi, kernel, borderType=cv2.BORDER_REPLICATE),
        cv2.erode(lo, kernel, borderType=cv2.BORDER_REPLICATE),
    )


def _crop(scene: Scene, x_lo: float, x_hi: float) -> ViewCrop:
    """The rasters between world x_lo and x_hi, with a shading pyramid (gradients, albedo, light)."""
    c = scene.canvas
    i0 = max(int(math.floor((x_lo - c.x0) / c.resolution)), 0)
    i1 = min(int(math.ceil((x_hi - c.x0) / c.resolution)) + 1, c.heights.shape[0])
    if i1 - i0 < 4:
        # the camera looks beyond the rasters: a flat dummy raster keeps the code uniform
        i0 = 0
        h = np.zeros((4, 4), np.float32)
        shade = np.dstack([h, h, h + 1, h + 1])
        x0 = x_lo
    else:
        h = c.heights[i0:i1]
        shade = np.empty((*h.shape, 4), np.float32)
        shade[..., 0], shade[..., 1] = np.gradient(h, c.resolution)
        shade[..., 2] = c.albedo[i0:i1]
        shade[..., 3] = c.light[i0:i1]
        x0 = c.x0 + i0 * c.resolution
    bounds = []
    for cell_m, dilate in BOUND_LEVELS:
        hi, lo = _local_bounds(h, c.resolution, cell_m, dilate)
        bounds.append((cell_m, dilate * cell_m - 0.02, hi, lo))
    return ViewCrop(h, build_pyramid(shade, 7), bounds, x0, c.y0, c.resolution)


class _Rays(NamedTuple):
    """Rays in crop cell units: row(s) = row0 + s * drow, col(s) = col0 + s * dcol, and the
    height above the road plane f0 + s * df (metres)."""

    row0: float
    col0: float
    f0: float
    drow: np.ndarray
    dcol: np.ndarray
    df: np.ndarray

    def above(self, crop: ViewCrop, s: np.ndarray, sel: np.ndarray) -> np.ndarray:
        """Height of the ray above the surface at depth ``s`` (float32; > 0 above)."""
        row = np.clip(self.row0 + s * self.drow[sel], -2.0, crop.heights.shape[0] + 1.0)
        col = np.clip(self.col0 + s * self.dcol[sel], -2.0, crop.heights.shape[1] + 1.0)
        disp = remap_points(crop.heights, col, row, cv2.BORDER_CONSTANT, 0.0)
        return cast("np.ndarray", self.f0 + s * self.df[sel] - disp)


def _intersect(
    scene: Scene, crop: ViewCrop, origin: np.ndarray, dirs: np.ndarray, pixel_angle: float
) -> tuple[np.ndarray, np.ndarray]:
    """Depth (optical z) of the first surface crossing of each ray; inf for rays that miss.

    Each ray is sampled every ``STEP_M`` (horizontally; half a pixel footprint where that is
    longer) through the slab where it is between the highest and the lowest displacement near
    its plane hit (local bounds when the slab is short enough for them to hold, the scene's
    extremes otherwise); the first sample below the surface brackets the first crossing, regula
    falsi refines it.

    Args:
        origin: [3] world ray origin. dirs: [N, 3] world directions with unit optical z.
        pixel_angle: angle subtended by one pixel (rad, 1 / fx).

    Returns:
        depth [N] float64 and ground [N] bool.
    """
    f32 = np.float32
    g, cs = scene.config.grade, scene.config.cross_slope
    a = f32(origin[2] - g * origin[0] - cs * origin[1])  # height above the plane at s = 0
    b = dirs[:, 2] - f32(g) * dirs[:, 0] - f32(cs) * dirs[:, 1]  # its change per unit s
    ground = b < -1e-6
    depth = np.full(dirs.shape[0], np.inf, np.float32)
    idx = np.flatnonzero(ground)
    bb = b[idx]
    inv_res = f32(1.0 / crop.res)
    dr, dc = dirs[idx, 0] * inv_res, dirs[idx, 1] * inv_res  # cells per unit s
    s_plane = -a / bb
    row0, col0 = f32((origin[0] - crop.x0) / crop.res), f32((origin[1] - crop.y0) / crop.res)
    n_rows, n_cols = crop.heights.shape
    # Local bounds at the plane hit, the finest whose radius covers the ray's slab; the scene's
    # extremes where none does.
    horiz = np.sqrt(dr * dr + dc * dc) * f32(crop.res)  # metres per unit s
    g_lo, g_hi = scene.displacement_range
    d_hi = np.full(idx.size, g_hi + 1e-3, np.float32)
    d_lo = np.full(idx.size, g_lo - 1e-3, np.float32)
    todo = np.arange(idx.size)
    for cell_m, radius, b_hi, b_lo in crop.bounds:
        per_cell = f32(crop.res / cell_m)
        bi = np.clip(((row0 + s_plane[todo] * dr[todo]) * per_cell).astype(np.int32), 0, b_hi.shape[0] - 1)
        bj = np.clip(((col0 + s_plane[todo] * dc[todo]) * per_cell).astype(np.int32), 0, b_hi.shape[1] - 1)
        hi, lo = b_hi[bi, bj] + f32(1e-3), b_lo[bi, bj] - f32(1e-3)
        fits = np.maximum(hi, -lo) / -bb[todo] * horiz[todo] <= radius
        d_hi[todo[fits]], d_lo[todo[fits]] = hi[fits], lo[fits]
        todo = todo[~fits]
    s_top = np.maximum((d_hi - a) / bb, f32(1e-3))
    s_bot = (d_lo - a) / bb
    # Rays whose slab starts beyond the rasters see the plain plane.
    top_r = row0 + s_top * dr
    top_c = col0 + s_top * dc
    inside = (top_r >= 0) & (top_r <= n_rows - 1) & (top_c >= 0) & (top_c <= n_cols - 1)
    outside = ~inside
    depth[idx[outside]] = s_plane[outside]
    march = idx[inside]
    if march.size == 0:
        return depth.astype(np.float64), ground
    s0, s1 = s_top[inside], s_bot[inside]
    rays = _Rays(row0, col0, a, dr[inside], dc[inside], bb[inside])
    n = march.size
    # Sample spacing: STEP_M, or half the pixel's footprint along the road where that is longer
    # (nothing narrower than a pixel can hide a crossing the image would show).
    norm = np.sqrt(horiz * horiz + dirs[idx, 2] ** 2)
    foot = s_plane * norm * f32(pixel_angle) * norm / np.maximum(-bb, f32(1e-6))
    step = np.maximum(f32(STEP_M), f32(STEP_FOOTPRINTS) * foot)[inside]
    steps = np.clip(np.ceil((s1 - s0) * horiz[inside] / step), 1, 4 * MARCH_SAMPLES).astype(np.float32)
    lo_s, hi_s = s0.copy(), s1.copy()
    lo_f = rays.above(crop, s0, np.arange(n))
    hi_f = np.full(n, -1e-6, np.float32)
    at_top = lo_f <= 0  # already below the surface at the slab top (a steep wall)
    hi_s[at_top], hi_f[at_top], lo_f[at_top] = s0[at_top], lo_f[at_top], 1e-6
    open_ = np.flatnonzero(~at_top)
    k = 0
    while open_.size:
        k += 1
        t = np.minimum(f32(k) / steps[open_], f32(1.0))
        s = s0[open_] + (s1[open_] - s0[open_]) * t
        val = rays.above(crop, s, open_)
        below = (val <= 0) | (t >= 1.0)
        done = open_[below]
        hi_s[done], hi_f[done] = s[below], np.minimum(val[below], f32(-1e-6))
        still = open_[~below]
        lo_s[still], lo_f[still] = s[~below], val[~below]
        open_ = still
    # Regula falsi on [lo, hi] (Illinois variant keeps both ends moving), until the ray is
    # within REFINE_TOL_M of the surface.
    active = np.arange(n)
    side = np.zeros(n, np.int8)
    for _ in range(REFINE_STEPS):
        ls, hs, lf, hf = lo_s[active], hi_s[active], lo_f[active], hi_f[active]
        s = ls + (hs - ls) * lf / (lf - hf)
        val = rays.above(crop, s, active)
        up = val > 0
        sd = side[active]
        lf = np.where(~up & (sd == -1), lf * f32(0.5), np.where(up, val, lf))
        hf = np.where(up & (sd == 1), hf * f32(0.5), np.where(up, hf, np.minimum(val, f32(-1e-9))))
        lo_s[active], lo_f[active] = np.where(up, s, ls), lf
        hi_s[active], hi_f[active] = np.where(up, hs, s), hf
        side[active] = np.where(up, 1, -1)
        active = active[np.abs(val) > REFINE_TOL_M]
        if active.size == 0:
            break
    depth[march] = lo_s + (hi_s - lo_s) * lo_f / (lo_f - hi_f)
    return depth.astype(np.float64), ground


def _marking_coverage(
    scene: Scene, x: np.ndarray, y: np.ndarray, foot_lat: np.ndarray, foot_long: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Anti-aliased coverage [N] of painted lines and their RGB [N, 3]."""
    cover = np.zeros(x.shape[0], np.float32)
    colour = np.zeros((x.shape[0], 3), np.float32)
    for m in scene.markings:
        near = np.flatnonzero(np.abs(y - m.y) < m.width / 2 + foot_lat)
        if near.size == 0:
            continue
        fl = np.maximum(foot_lat[near], 1e-4)
        across = np.clip((m.width / 2 - np.abs(y[near] - m.y)) / fl + 0.5, 0.0, 1.0)
        if m.dash > 0:
            pos = np.mod(x[near] - m.phase, m.dash + m.gap)
            along = np.clip(np.minimum(pos, m.dash - pos) / np.maximum(foot_long[near], 1e-4) + 0.5, 0.0, 1.0)
            across = across * along
        colour[near] += across[:, None] * np.asarray(m.colour, np.float32)
        cover[near] = np.maximum(cover[near], across)
    return cover, colour / np.maximum(cover, 1e-6)[:, None]


# The ego vehicle as boxes in the camera's yaw-aligned level frame (m): x from the rear to the
# front, y across, z relative to the camera (which sits on the roof): body, then cabin.
EGO_BOXES = (
    ((-3.4, 1.0), (-0.92, 0.92), (-0.8, -0.35)),
    ((-2.7, 0.3), (-0.75, 0.75), (-0.35, 0.06)),
)
PENUMBRA_M = 0.03


def ego_shadow(scene: Scene, pose: CameraPose, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """[N] float32 share of sunlight the ego vehicle lets through at world points (1 = none blocked).

    The ray from each point towards the sun is tested against :data:`EGO_BOXES` (slab method);
    the length of its chord through a box, over ``PENUMBRA_M``, softens the edge like the sun's
    disc.
    """
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    qx, qy, qz = x - np.float32(pose.x), y - np.float32(pose.y), z - np.float32(pose.z)
    local = ((c * qx + s * qy), (-s * qx + c * qy), qz)
    sun = scene.sun
    direction = (c * sun[0] + s * sun[1], -s * sun[0] + c * sun[1], sun[2])
    through = np.ones(x.shape[0], np.float32)
    for box in EGO_BOXES:
        t_near = np.zeros(x.shape[0], np.float32)
        t_far = np.full(x.shape[0], np.inf, np.float32)
        for (lo, hi), q, dq in zip(box, local, direction, strict=True):
            if abs(dq) < 1e-9:
                t_far = np.where((q >= lo) & (q <= hi), t_far, -np.inf).astype(np.float32)
                continue
            t1, t2 = (lo - q) / np.float32(dq), (hi - q) / np.float32(dq)
            t_near = np.maximum(t_near, np.minimum(t1, t2))
            t_far = np.minimum(t_far, np.maximum(t1, t2))
        chord = np.maximum(t_far - t_near, 0.0)
        through *= 1.0 - np.clip(chord / PENUMBRA_M, 0.0, 1.0)
    return through.astype(np.float32)


def _glints(
    scene: Scene, camera: StereoCamera, rng_m: np.ndarray, ty: np.ndarray, tx: np.ndarray,
    lod_row: np.ndarray, lod_col: np.ndarray, right: bool,
) -> np.ndarray:
    """[N] glint albedo one camera sees at N ground points (tile coordinates and footprints as the
    pavement's; ``scene.glints`` set).

    The shared layout and this camera's own are blended as sqrt(rho) * shared + sqrt(1 - rho) *
    own, rho = exp(-(dtheta / lobe)^2) with dtheta = baseline / range the angle between the two
    cameras' rays: the two images' glints then correlate by rho with the same variance in both,
    and each point gets the same rho from either camera.
    """
    if scene.glints is None:
        return np.zeros(rng_m.shape, np.float32)
    shared, left, right_own = scene.glints
    shared_rip, own_rip = shared.rip, (right_own if right else left).rip
    if shared_rip is None or own_rip is None or any(
        t.size != scene.tile.size or t.texel != scene.tile.texel for t in scene.glints
    ):
        raise SynthError("glint tiles must be rip-mapped and laid like the pavement tile")
    lobe = np.float32(math.radians(scene.config.glint_lobe_deg))
    rho = np.exp(-np.square(np.float32(camera.baseline) / np.maximum(rng_m, np.float32(0.1)) / lobe))
    from_shared = sample_ripmap(shared_rip, ty, tx, lod_row, lod_col)
    from_own = sample_ripmap(own_rip, ty, tx, lod_row, lod_col)
    return cast("np.ndarray", np.sqrt(rho) * from_shared + np.sqrt(1.0 - rho) * from_own)


def _shade_ground(
    scene: Scene,
    crop: ViewCrop,
    camera: StereoCamera,
    pose: CameraPose,
    origin: np.ndarray,
    dirs: np.ndarray,
    depth: np.ndarray,
    right: bool = False,
) -> np.ndarray:
    """[N, 3] float32 radiance of ground hits (dirs [N, 3], depth [N] optical z) seen by the left
    (or ``right``) camera."""
    cfg = scene.config
    d = dirs.astype(np.float32)
    s = depth.astype(np.float32)
    px = np.float32(origin[0]) + s * d[:, 0]  # float32 keeps sub-mm precision within ~100 m
    py = np.float32(origin[1]) + s * d[:, 1]
    norm = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 2] ** 2)
    rng_m = s * norm  # range to the hit (m)
    sin_elev = np.clip(-(d[:, 2] - np.float32(cfg.grade) * d[:, 0]) / norm, 0.01, 1.0)
    foot_lat = rng_m / np.float32(camera.fx)  # pixel footprint across the ray (m)
    foot_long = foot_lat / sin_elev  # and along it
    log_foot = np.log2(np.sqrt(foot_lat * foot_long))

    row = (px - np.float32(crop.x0)) / np.float32(crop.res)
    col = (py - np.float32(crop.y0)) / np.float32(crop.res)
    shade = sample_mip(crop.shade, col, row, log_foot - np.float32(math.log2(crop.res)), wrap=False)
    outside = (row < 0) | (row > crop.heights.shape[0] - 1) | (col < 0) | (col > crop.heights.shape[1] - 1)
    shade[outside] = (0.0, 0.0, 1.0, 1.0)
    gx = shade[:, 0] + np.float32(cfg.grade)
    gy = shade[:, 1] + np.float32(cfg.cross_slope)
    inv = 1.0 / np.sqrt(gx * gx + gy * gy + 1.0)
    sun = scene.sun.astype(np.float32)
    n_dot_l = (sun[2] - gx * sun[0] - gy * sun[1]) * inv
    direct = shade[:, 3]
    if scene.config.shadows and scene.sun_strength > 0.5:  # the ego vehicle's own shadow
        pz = np.float32(origin[2]) + s * d[:, 2]
        direct = direct * ego_shadow(scene, pose, px, py, pz)
    light = scene.ambient * (0.75 + 0.25 * inv) + scene.sun_strength * np.maximum(n_dot_l, 0.0) * direct

    # Pavement tile, laid in one of 8 orientations (quarter turns and a flip) with an offset;
    # anisotropic (rip-map) filtering: the footprint is long along the ray's horizontal
    # direction and short across it, so lateral detail survives at a distance as in a camera.
    tile = scene.tile
    texel = np.float32(tile.texel)
    qx, qy = np.float32(scene.tile_offset[0]) + px, np.float32(scene.tile_offset[1]) + py
    turn = int(round(scene.tile_angle / (math.pi / 2))) % 4
    swap = turn % 2 == 1
    tx = (qy if swap else qx) * (np.float32(-1.0) if turn in (1, 2) else np.float32(1.0)) / texel
    ty = (qx if swap else qy) * (np.float32(-1.0) if turn in (2, 3) else np.float32(1.0)) / texel
    # The footprint on the actual surface (a bump's face seen head-on is far less foreshortened
    # than the road plane), then its horizontal extent along the ray's azimuth.
    horiz = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-6)
    cos_az, sin_az = d[:, 0] / horiz, d[:, 1] / horiz
    cos_inc = np.clip((d[:, 2] - gx * d[:, 0] - gy * d[:, 1]) * inv / -norm, 0.01, 1.0)
    slope_along = gx * cos_az + gy * sin_az
    foot_along = foot_lat / cos_inc / np.sqrt(1.0 + slope_along * slope_along)
    sin2 = sin_az * sin_az
    foot_x = np.sqrt(foot_along**2 * (1.0 - sin2) + foot_lat**2 * sin2)  # footprint along world x
    foot_y = np.sqrt(foot_along**2 * sin2 + foot_lat**2 * (1.0 - sin2))
    foot_row, foot_col = (foot_y, foot_x) if swap else (foot_x, foot_y)
    tile_lod = log_foot - np.float32(math.log2(tile.texel))
    if tile.rip is not None:
        albedo = sample_ripmap(tile.rip, ty, tx, np.log2(foot_row / texel), np.log2(foot_col / texel))
    else:
        albedo = sample_mip(list(tile.pyramid), ty, tx, tile_lod, wrap=True)
    # Steep walls (pothole sides, kerb faces): tri-planar mapping, so the texture is not
    # stretched down the wall as a plain (x, y) lookup would.
    steep = np.flatnonzero(shade[:, 0] ** 2 + shade[:, 1] ** 2 > 0.16)
    if steep.size:
        pz = (np.float32(origin[2]) + s[steep] * d[steep, 2]) / np.float32(tile.texel)
        wx, wy = np.abs(gx[steep]) ** 2, np.abs(gy[steep]) ** 2
        wz = np.ones_like(wx)
        total = wx + wy + wz
        on_x = sample_mip(list(tile.pyramid), ty[steep], pz + np.float32(7.0), tile_lod[steep], wrap=True)
        on_y = sample_mip(list(tile.pyramid), pz + np.float32(3.0), tx[steep], tile_lod[steep], wrap=True)
        albedo[steep] = (albedo[steep] * wz + on_x * wx + on_y * wy) / total
    lo, hi = scene.paved
    paved = np.clip(np.minimum(py - lo, hi - py) / np.maximum(foot_lat, 1e-3) + 0.5, 0.0, 1.0)
    if scene.texture_contrast != 1.0:
        mean = np.float32(tile.pyramid[-1].mean())
        albedo = np.maximum(mean + (albedo - mean) * np.float32(scene.texture_contrast), np.float32(0.01))
    if scene.glints is not None:
        lods = np.log2(foot_row / texel), np.log2(foot_col / texel)
        albedo = albedo + _glints(scene, camera, rng_m, ty, tx, *lods, right)
    base_tint = (1.0, 1.0, 1.03) if cfg.surface == "asphalt" else (1.0, 0.99, 0.95)
    tint = np.array(base_tint, np.float32) * np.array(scene.tint, np.float32)
    rgb = (albedo * paved)[:, None] * tint
    off = np.flatnonzero(paved < 1.0)
    if off.size:
        verge = scene.verge
        v = sample_mip(
            list(verge.pyramid),
            py[off] / np.float32(verge.texel),
            px[off] / np.float32(verge.texel),
            log_foot[off] - np.float32(math.log2(verge.texel)),
            wrap=True,
        )
        rgb[off] += (v * (1 - paved[off]))[:, None] * np.array([0.75, 0.95, 0.45], np.float32)
    if scene.markings:
        cover, paint = _marking_coverage(scene, px, py, foot_lat, foot_long)
        on = np.flatnonzero(cover > 0)
        wear = np.clip(0.55 + 1.5 * albedo[on], 0.0, 1.0)[:, None]  # aggregate shows through worn paint
        c = (cover[on] * paved[on])[:, None]
        rgb[on] = rgb[on] * (1 - c) + paint[on] * wear * c
    rgb *= (shade[:, 2] * light)[:, None]
    haze = (1.0 - np.exp(-rng_m / np.float32(HAZE_DISTANCE_M)))[:, None]
    return cast("np.ndarray", rgb * (1 - haze) + scene.sky_horizon.astype(np.float32) * haze)


def _shade_sky(scene: Scene, dirs: np.ndarray) -> np.ndarray:
    """[N, 3] float32 sky radiance with a distant tree line (dirs [N, 3] world)."""
    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    elev = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
    az = np.arctan2(d[:, 1], d[:, 0])
    n_tl = scene.treeline.size
    tl = scene.treeline[np.floor((az + math.pi) / (2 * math.pi) * n_tl).astype(np.int64) % n_tl]
    t = np.clip(elev / 0.5, 0.0, 1.0)[:, None]
    col = scene.sky_horizon * (1 - t) + scene.sky_zenith * t
    # foliage: a fixed random pattern over (azimuth, elevation), hazy with distance
    leaves = _FOLIAGE[(np.floor(az * 900.0).astype(np.int64) % 251), (np.floor(elev * 900.0).astype(np.int64) % 251)]
    trees = np.array([0.10, 0.13, 0.08]) * (0.6 + 0.8 * leaves)[:, None]
    trees = 0.6 * trees + 0.4 * scene.sky_horizon
    return cast("np.ndarray", np.where((elev < tl)[:, None], trees, col).astype(np.float32))


_FOLIAGE = cv2.GaussianBlur(np.random.default_rng(7).random((251, 251)).astype(np.float32), (0, 0), 1.0)


def view_crop(scene: Scene, pose: CameraPose) -> ViewCrop:
    """The scene rasters a view from ``pose`` needs (share it between the left and right views)."""
    return _crop(scene, pose.x - 1.0, pose.x + LOOK_AHEAD_M)


def render_view(
    scene: Scene, camera: StereoCamera, pose: CameraPose, *, right: bool = False, crop: ViewCrop | None = None
) -> RenderedView:
    """Render the left (or right) view of ``scene`` from the stereo rig at ``pose``.

    Args:
        scene: the road scene.
        camera: the rectified rig (the right camera is ``baseline`` along the left's optical +x).
        pose: the left camera's pose.
        right: render the right camera.
        crop: rasters from :func:`view_crop` (made here when None).
    """
    if right and camera.baseline <= 0:
        raise SynthError("rendering a right view needs a stereo baseline > 0")
    dirs = ray_directions(camera, pose)  # [N, 3]
    origin = np.array([pose.x, pose.y, pose.z], np.float64)
    if right:
        R = optical_from_road_rotation(pose.attitude)
        origin = origin + pose.yaw_matrix() @ (np.array([camera.baseline, 0.0, 0.0]) @ R)
    crop = crop if crop is not None else view_crop(scene, pose)
    depth, ground = _intersect(scene, crop, origin, dirs, 1.0 / camera.fx)
    ground &= depth < 1e5  # beyond that, the horizon
    n = dirs.shape[0]
    radiance = np.empty((n, 3), np.float32)
    hit = np.flatnonzero(ground)
    radiance[hit] = _shade_ground(scene, crop, camera, pose, origin, dirs[hit], depth[hit], right)
    sky = np.flatnonzero(~ground)
    if sky.size:
        radiance[sky] = _shade_sky(scene, dirs[sky])
    depth_img = np.where(ground, depth, np.inf).astype(np.float32)
    return RenderedView(
        radiance.reshape(camera.height, camera.width, 3), depth_img.reshape(camera.height, camera.width)
    )


def render_stereo(scene: Scene, camera: StereoCamera, pose: CameraPose) -> tuple[RenderedView, RenderedView | None]:
    """The left and (with a baseline) right views at ``pose``, sharing one raster crop."""
    crop = view_crop(scene, pose)
    left = render_view(scene, camera, pose, crop=crop)
    right = render_view(scene, camera, pose, right=True, crop=crop) if camera.baseline > 0 else None
    return left, right


def shift_rows(image: np.ndarray, rows: float) -> np.ndarray:
    """``image`` ([H, W] or [H, W, C]) moved down by ``rows`` pixels, sub-pixel (bilinear; the edge
    row repeated where it comes in): a stereo pair's rectification residual, which real
    calibrations leave at a few tenths of a pixel of vertical disparity."""
    h, w = image.shape[:2]
    shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, rows]], np.float32)
    return cv2.warpAffine(image, shift, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def sensor_image(
    radiance: np.ndarray,
    *,
    exposure: float,
    gain: float | tuple[float, float, float],
    noise_sigma: float,
    blur_sigma_px: float,
    rng: np.random.Generator,
    jpeg_quality: int | None = None,
    vignetting: float = 0.0,
) -> np.ndarray:
    """Camera response: optical blur, vignetting, exposure and gain, gamma, shot and read noise,
    8-bit, JPEG.

    Args:
        radiance: [H, W, 3] float32 linear radiance.
        exposure, gain: linear scale of the radiance before encoding (gain per channel or one).
        vignetting: brightness lost in the image corners (0.15 = 15 %), falling off as r^2.
        noise_sigma: read noise (digital numbers, 1-sigma); shot noise scales with sqrt(signal).
        blur_sigma_px: Gaussian optical blur (pixels).
        rng: noise source.
        jpeg_quality: JPEG round trip at this quality (None: none).

    Returns:
        [H, W, 3] uint8 RGB.
    """
    img = radiance
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    scale = exposure * np.asarray(gain, np.float32).reshape(-1)[None, None, :]
    if vignetting > 0:
        h, w = img.shape[:2]
        yy = (np.arange(h, dtype=np.float32) - (h - 1) / 2) / (h / 2)
        xx = (np.arange(w, dtype=np.float32) - (w - 1) / 2) / (w / 2)
        r2 = (yy[:, None] ** 2 + xx[None, :] ** 2) / 2.0  # 1 in the corners
        scale = scale * (1.0 - vignetting * r2)[:, :, None]
    lin = np.clip(img * scale, 0.0, 1.0)
    dn = 255.0 * lin ** (1 / 2.2)
    if noise_sigma > 0:
        # read noise plus shot noise (variance grows with the signal): sigma^2 (1 + dn / 255)
        sigma = np.float32(noise_sigma) * np.sqrt(np.float32(1.0) + np.maximum(dn, 0.0) * np.float32(1 / 255))
        dn = dn + rng.standard_normal(dn.shape, dtype=np.float32) * sigma
    out = np.clip(np.rint(dn), 0, 255).astype(np.uint8)
    if jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise SynthError("JPEG encoding failed")
        decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        if decoded is None:
            raise SynthError("JPEG decoding failed")
        out = decoded[:, :, ::-1].copy()
    return cast("np.ndarray", out)
