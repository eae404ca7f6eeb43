"""``bev_sweep``: training-free stereo in bird's-eye view (the paper's stereo mechanism, no learning).

For every voxel of the grid (and a few sub-samples per cell), the left and right grey images are
sampled bilinearly at the voxel's projections. At the true road height the two samples show the
same surface point, so their zero-normalised cross-correlation (ZNCC) over a small window *in the
road plane* (not fronto-parallel: the window follows the road, which is what the BEV formulation
buys) peaks there. The ZNCC volume is aggregated over the BEV plane per height (box filter), the
height with the best score is refined below the sweep step (a parabola through the peak and its
two neighbours), and a softmax over heights gives a per-cell 1-sigma uncertainty (the spread of
the distribution). Cells whose score curve has no clear, unique peak (texture-less, occluded, out
of the image, or a peak on the range boundary) are NaN: no guess.

Pixel convention (contract): pixel column i is centred at u = i, so ``grid_sample`` runs with
``align_corners=True`` (normalised -1 and +1 are the centres of the first and last pixels).

Everything after the colour conversion is vectorized torch on the CPU. The projection exploits
the grid's separable structure (x per row, y per column, z per level): camera coordinates are
sums of broadcast terms, so no [Z, R, C, 3] point array is ever built.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, fields
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from roadbev_core.backends import register
from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.geometry import Attitude, optical_from_road_rotation

__all__ = ["BevSweep", "SweepParams", "grey_image"]

torch.set_flush_denormal(True)


@dataclass(frozen=True)
class SweepParams:
    """Tuning of the sweep (defaults chosen by measurement, see ``benchmarks/sweep_params.py``).

    Attributes:
        z_step: height step of the sweep (m); None = the grid's voxel size. The answer is refined
            below this step, so it sets robustness more than resolution.
        subsamples_x, subsamples_y: samples per cell along x (rows) and y (columns), so a ZNCC
            window sees the texture inside a cell and not only at its centre. Across the road a
            3 cm cell spans 4-13 pixels, along it (foreshortened) 1-6, hence more along y.
        patch_cells: side of the ZNCC window, in cells (odd).
        aggregation_cells: side of the box filter over the BEV plane applied to the ZNCC volume
            per height, in cells (odd; 1 = none).
        min_score: a cell whose best aggregated ZNCC is below this is NaN (no reliable match).
        min_margin: a cell is NaN when a second peak (more than ``peak_exclusion`` steps from the
            best) scores within this margin of the best (ambiguous, e.g. repetitive texture).
        peak_exclusion: half-width (steps) around the best height excluded when looking for a
            second peak.
        min_texture: grey-level standard deviation (0..255) of the left patch below which a cell
            is texture-less (NaN).
        temperature: softmax temperature on the ZNCC scores for the uncertainty (smaller = the
            distribution follows the peak more tightly).
        blur_sigma: Gaussian pre-smoothing of the images (pixels; 0 = none); it reduces the bias
            of bilinear sampling toward whole-pixel disparities.
    """

    z_step: float | None = None
    subsamples_x: int = 1
    subsamples_y: int = 2
    patch_cells: int = 3
    aggregation_cells: int = 3
    min_score: float = 0.5
    min_margin: float = 0.02
    peak_exclusion: int = 3
    min_texture: float = 1.0
    temperature: float = 0.02
    blur_sigma: float = 0.0

    def __post_init__(self) -> None:
        if self.z_step is not None and not (math.isfinite(self.z_step) and self.z_step > 0):
            raise ConfigError(f"z_step must be a positive number of metres, got {self.z_step}")
        for name in ("subsamples_x", "subsamples_y", "patch_cells", "aggregation_cells", "peak_exclusion"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
        for name in ("patch_cells", "aggregation_cells"):
            if getattr(self, name) % 2 == 0:
                raise ConfigError(f"{name} must be odd (a centred window), got {getattr(self, name)}")
        for name in ("min_score", "min_margin", "min_texture", "temperature", "blur_sigma"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"{name} must be a finite number, got {value!r}")
        if self.temperature <= 0:
            raise ConfigError(f"temperature must be positive, got {self.temperature}")
        if self.blur_sigma < 0 or self.min_texture < 0:
            raise ConfigError("blur_sigma and min_texture must be >= 0")

    @classmethod
    def from_options(cls, options: dict[str, Any]) -> SweepParams:
        """Parameters from keyword options; unknown names raise :class:`ConfigError`."""
        known = {f.name for f in fields(cls)}
        unknown = set(options) - known
        if unknown:
            raise ConfigError(
                f"unknown bev_sweep option(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}"
            )
        return cls(**options)


def grey_image(image: np.ndarray, blur_sigma: float = 0.0) -> np.ndarray:
    """[H, W] float32 grey levels (0..255) of an RGB [H, W, 3] or grey [H, W] uint8 image."""
    if image.ndim == 3:
        grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    else:
        grey = image
    grey = grey.astype(np.float32, copy=False)
    if blur_sigma > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), blur_sigma)
    return grey


class _Clock:
    """Wall time per stage, in milliseconds."""

    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.timings[stage] = self.timings.get(stage, 0.0) + 1000.0 * (now - self._last)
        self._last = now


class BevSweep:
    """The training-free BEV plane-sweep stereo backend (see the module docstring)."""

    name = "bev_sweep"
    needs_stereo = True

    def __init__(self, grid: GridSpec, params: SweepParams | None = None) -> None:
        self.grid = grid
        self.params = params or SweepParams()
        p = self.params
        step = p.z_step if p.z_step is not None else grid.z_resolution
        n_levels = int(round((grid.z_max - grid.z_min) / step))
        if n_levels < 3 or abs(n_levels * step - (grid.z_max - grid.z_min)) > 1e-6:
            raise ConfigError(
                f"z_step {step} m must divide the grid's height range {grid.z_min}..{grid.z_max} m "
                "into at least 3 levels"
            )
        self.z_step = step
        sx, sy = p.subsamples_x, p.subsamples_y
        # Sample positions: sx x sy per cell, centred in the cell (row 0 farthest, col 0 leftmost).
        self._x = torch.tensor(
            grid.x_max - (np.arange(grid.n_rows * sx) + 0.5) * (grid.resolution / sx), dtype=torch.float32
        )
        self._y = torch.tensor(
            grid.y_max - (np.arange(grid.n_cols * sy) + 0.5) * (grid.resolution / sy), dtype=torch.float32
        )
        self._x_cell = torch.tensor(grid.x_centres(), dtype=torch.float32)
        self._y_cell = torch.tensor(grid.y_centres(), dtype=torch.float32)
        self._z = torch.tensor(grid.z_min + (np.arange(n_levels) + 0.5) * step, dtype=torch.float32)

    # --- stages --------------------------------------------------------------------------------
    def _normalised_coordinates(
        self, x: torch.Tensor, y: torch.Tensor, camera: StereoCamera, attitude: Attitude
    ) -> torch.Tensor:
        """Normalised ``grid_sample`` coordinates [2, Z, len(x), len(y), 2] (left, right images).

        Args:
            x: [Rs] road-frame x of the sample rows; y: [Cs] y of the sample columns.
        """
        R = torch.tensor(optical_from_road_rotation(attitude), dtype=torch.float32)  # road -> optical
        xs = x[None, :, None]  # [1, Rs, 1]
        ys = y[None, None, :]  # [1, 1, Cs]
        dz = (self._z - self.grid.base_height)[:, None, None]  # [Z, 1, 1]
        w, h = camera.width, camera.height
        # u_norm = 2 u / (W - 1) - 1 with u = fx X / Z + cx (align_corners=True: centres at -1, +1).
        ax, bx = 2.0 * camera.fx / (w - 1), 2.0 * camera.cx / (w - 1) - 1.0
        ay, by = 2.0 * camera.fy / (h - 1), 2.0 * camera.cy / (h - 1) - 1.0
        # Camera coordinates are sums of separable terms [Z, Rs, 1] + [1, 1, Cs], pre-scaled so that
        # one multiply by 1/depth gives the normalised coordinate (no [Z, R, C, 3] array is built).
        inv_depth = ((R[2, 0] * xs + R[2, 2] * dz) + R[2, 1] * ys).reciprocal_()  # [Z, Rs, Cs]
        coords = torch.empty(2, *inv_depth.shape, 2)
        u_left, v_norm = coords[0, ..., 0], coords[0, ..., 1]
        torch.mul((ax * R[0, 0]) * xs + (ax * R[0, 2]) * dz, inv_depth, out=u_left)
        u_left.add_(inv_depth * ((ax * R[0, 1]) * ys)).add_(bx)
        torch.mul((ay * R[1, 0]) * xs + (ay * R[1, 2]) * dz, inv_depth, out=v_norm)
        v_norm.add_(inv_depth * ((ay * R[1, 1]) * ys)).add_(by)
        # Right camera: its centre is `baseline` along the left's +x, so x' = x - B.
        torch.add(u_left, inv_depth, alpha=-ax * camera.baseline, out=coords[1, ..., 0])
        coords[1, ..., 1] = v_norm
        return coords

    def _valid_levels(self, camera: StereoCamera, attitude: Attitude) -> torch.Tensor:
        """[Z, R, C] bool: the cell centre at that height projects inside both images.

        The window never reaches behind the camera (x_min > 0 and z_max < base_height), so only
        the image bounds are checked, with half a pixel of slack as ``geometry.project_voxels``.
        """
        coords = self._normalised_coordinates(self._x_cell, self._y_cell, camera, attitude)
        lim = torch.tensor([1.0 + 1.0 / (camera.width - 1), 1.0 + 1.0 / (camera.height - 1)])
        return (coords.abs() <= lim).all(dim=-1).all(dim=0)

    def _zncc(self, samples: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """ZNCC [Z, R, C] of left vs right samples over the patch, and the left patch std [Z, R, C].

        Args:
            samples: [2, Z, R*sx, C*sy] left and right grey samples (images centred on zero mean,
                so the moments keep float32 precision).
        """
        p = self.params
        sx, sy = p.subsamples_x, p.subsamples_y
        n_z = samples.shape[1]
        n_rows, n_cols = self.grid.shape
        left, right = samples[0], samples[1]

        def cell_sum(values: torch.Tensor) -> torch.Tensor:  # [Z, R*sx, C*sy] -> [Z, R, C]
            if sx == sy == 1:
                return values
            return values.view(n_z, n_rows, sx, n_cols, sy).sum(dim=(2, 4))

        moments = torch.stack(
            (
                cell_sum(left),
                cell_sum(right),
                cell_sum(left * left),
                cell_sum(right * right),
                cell_sum(left * right),
            )
        )  # [5, Z, R, C] sums over each cell's samples
        k = p.patch_cells
        # Box window over k x k cells at cell resolution (the mean over the window's samples).
        moments = F.avg_pool2d(
            moments.view(5 * n_z, 1, n_rows, n_cols),
            kernel_size=k,
            stride=1,
            padding=k // 2,
            count_include_pad=False,
        ).view(5, n_z, n_rows, n_cols) * (1.0 / (sx * sy))
        m_l, m_r, m_ll, m_rr, m_lr = moments.unbind(dim=0)
        var_l = (m_ll - m_l * m_l).clamp_min_(0.0)
        var_r = (m_rr - m_r * m_r).clamp_min_(0.0)
        zncc = (m_lr - m_l * m_r).mul_(torch.rsqrt(var_l * var_r + 1e-6))
        return zncc, var_l.sqrt_()

    def _aggregate(self, zncc: torch.Tensor) -> torch.Tensor:
        """Box filter [Z, R, C] over the BEV plane per height."""
        a = self.params.aggregation_cells
        if a == 1:
            return zncc
        return F.avg_pool2d(zncc[:, None], kernel_size=a, stride=1, padding=a // 2, count_include_pad=False)[:, 0]

    def _decide(
        self, score: torch.Tensor, texture: torch.Tensor, valid: torch.Tensor
    ) -> tuple[np.ndarray, np.ndarray]:
        """Elevation and uncertainty [R, C] from the aggregated score volume [Z, R, C]."""
        p = self.params
        n_z = score.shape[0]
        score = torch.where(valid, score, torch.full_like(score, -2.0))  # invalid levels never win
        best, idx = score.max(dim=0)  # [R, C]
        lo = (idx - 1).clamp_min(0)
        hi = (idx + 1).clamp_max(n_z - 1)
        s_lo = score.gather(0, lo[None])[0]
        s_hi = score.gather(0, hi[None])[0]
        # Parabola through the peak and its neighbours: offset in steps, within (-0.5, 0.5).
        curvature = s_lo - 2.0 * best + s_hi
        offset = torch.where(curvature < -1e-9, 0.5 * (s_lo - s_hi) / curvature, torch.zeros_like(best))
        offset = offset.clamp(-0.5, 0.5)
        elevation = self._z[idx] + offset * self.z_step
        # A second peak outside the exclusion zone around the best.
        levels = torch.arange(n_z)[:, None, None]
        far = (levels - idx[None]).abs() > p.peak_exclusion
        second = torch.where(far, score, torch.full_like(score, -2.0)).max(dim=0).values
        # Uncertainty: spread of the softmax over heights around the estimate.
        prob = torch.softmax(score / p.temperature, dim=0)
        spread = (prob * (self._z[:, None, None] - elevation[None]).square()).sum(dim=0).sqrt()
        # Sub-step floor: a distribution that collapses on one level still has the step's error.
        sigma = torch.sqrt(spread.square() + (self.z_step / math.sqrt(12.0)) ** 2)
        texture_at_best = texture.gather(0, idx[None])[0]
        column_inside = valid.all(dim=0)
        confident = (
            (best >= p.min_score)
            & (best - second >= p.min_margin)
            & (idx > 0)
            & (idx < n_z - 1)
            & (texture_at_best >= p.min_texture)
            & column_inside
        )
        nan = torch.full_like(elevation, float("nan"))
        elevation = torch.where(confident, elevation, nan)
        sigma = torch.where(confident, sigma, nan)
        return elevation.numpy().astype(np.float32), sigma.numpy().astype(np.float32)

    # --- protocol ------------------------------------------------------------------------------
    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and uncertainty of ``self.grid`` for one stereo frame."""
        if frame.right is None:
            raise FrameError("bev_sweep needs a stereo frame (the right image is missing)")
        if frame.camera.baseline <= 0:
            raise FrameError("bev_sweep needs a stereo rig with a positive baseline")
        clock = _Clock()
        p = self.params
        greys = np.stack((grey_image(frame.left, p.blur_sigma), grey_image(frame.right, p.blur_sigma)))
        greys -= greys.mean(axis=(1, 2), keepdims=True)  # zero-mean: precise float32 moments
        images = torch.from_numpy(greys)[:, None]  # [2, 1, H, W]
        clock.lap("preprocess")
        with torch.no_grad():
            coords = self._normalised_coordinates(self._x, self._y, frame.camera, frame.attitude)
            valid = self._valid_levels(frame.camera, frame.attitude)  # [Z, R, C]
            clock.lap("projection")
            n_z, n_rs, n_cs = coords.shape[1:4]
            samples = F.grid_sample(
                images, coords.view(2, n_z * n_rs, n_cs, 2), mode="bilinear", padding_mode="border", align_corners=True
            ).view(2, n_z, n_rs, n_cs)
            clock.lap("sampling")
            zncc, texture = self._zncc(samples)
            clock.lap("cost")
            score = self._aggregate(zncc)
            clock.lap("aggregation")
            elevation, sigma = self._decide(score, texture, valid)
            clock.lap("post")
        return Estimate(elevation=elevation, uncertainty=sigma, timings_ms=clock.timings)

    def describe(self) -> dict[str, Any]:
        """Parameters as a JSON-able dict (for benchmark records)."""
        return {"backend": self.name, "z_step": self.z_step, **asdict(self.params)}


@register("bev_sweep")
def create_bev_sweep(grid: GridSpec, **options: Any) -> BevSweep:
    """Registry factory: ``create("bev_sweep", grid, patch_cells=3, ...)`` (see :class:`SweepParams`)."""
    return BevSweep(grid, SweepParams.from_options(options))
