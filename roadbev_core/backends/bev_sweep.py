"""``bev_sweep``: training-free stereo in bird's-eye view (the paper's stereo mechanism, no learning).

For every voxel of the grid (and a few sub-samples per cell), the left and right grey images are
sampled bilinearly at the voxel's projections. At the true road height the two samples show the
same surface point, so their zero-normalised cross-correlation (ZNCC) over a small window *in the
road plane* (not fronto-parallel: the window lies on the road, which is what the BEV formulation
buys) peaks there. Per height, the ZNCC volume is box-filtered over the BEV plane, optionally with
shiftable windows (the best of the centred window and four shifted ones, so steps stay sharp).
The best height per cell is refined below the sweep step by a parabola through the peak and its
neighbours; the softmax over heights gives a per-cell 1-sigma uncertainty (its spread).

No guessing: a cell is NaN when its score curve is flat or ambiguous (low best score, a second
separate peak nearly as good, a spread above ``max_sigma``, a peak on the range boundary),
texture-less, outside either image, or hidden (its line of sight grazes nearer surface, e.g.
behind a speed bump, where the sweep would only find the occluder's edge).

Images are pre-filtered (a light Gaussian blur against the bilinear interpolation's pull toward
whole-pixel disparities, and a high-pass against shading). Pixel convention (docs/interface/frames-and-grid.md): pixel
column i is centred at u = i, so ``grid_sample`` runs with ``align_corners=True`` (normalised -1
and +1 are the centres of the first and last pixels).

Everything after the colour conversion is vectorized torch on the CPU. The projection exploits
the grid's separable structure (x per row, y per column, z per level): camera coordinates are
sums of broadcast terms, so no [Z, R, C, 3] point array is ever built.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from roadbev_core.backends.common import StageClock, grey_u8
from roadbev_core.box_filter import WindowSize, box_mean, window_shape
from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.geometry import Attitude
from roadbev_core.image_sampling import sample_coordinates
from roadbev_core.visibility import CLEARANCE, fill_holes

__all__ = ["DEFAULT_Z_STEP", "BevSweep", "SweepParams", "create_bev_sweep", "grey_image"]

_WORST = -2.0  # below any ZNCC: levels outside the image never win
_OCCLUSION_SAMPLES = 16  # points per line of sight in the occlusion test
_MIN_SIGMA = 0.001  # m: the smallest uncertainty reported
DEFAULT_Z_STEP = 0.02  # m: the sweep step when SweepParams.z_step is None (see there)


@dataclass(frozen=True)
class SweepParams:
    """Settings of the sweep (defaults chosen with ``benchmarks/tune_bev_sweep.py``; its figures
    are in ``docs/results/tuning.md``).

    The defaults were chosen on the tuning frames (seeds 200,000+, never the evaluation frames) of
    scene version 1 (``roadbev_lab.training.datasets.SCENE_VERSION``, the clean appearance) and
    not re-chosen for version 2's ``real-road`` range, where they answer fewer cells.

    Attributes:
        z_step: height step of the sweep (m); None = about ``DEFAULT_Z_STEP`` (2 cm), the grid's
            height range divided into a whole number of steps. The parabola through the peak
            refines below the step, so 2 cm steps are about as accurate as 1 cm ones and faster;
            coarser steps lose accuracy.
        subsamples: samples per cell (along x = rows, along y = columns) in the middle rows.
            Across the road a 3 cm cell spans 4-13 pixels, along it (foreshortened) 1-6, so the
            near rows have many more pixels to use than the far ones.
        far_subsamples, near_subsamples: the same for the ``far_fraction`` / ``near_fraction``
            zones: fewer samples far and more near beat one count everywhere (the near rows'
            count everywhere costs more time: far cells are narrower than a pixel along x).
        patch_cells: the ZNCC window in cells (odd; one side or (rows, columns)).
        aggregation_cells: the box filter of the ZNCC volume over the BEV plane per height, for
            the rows between the near and far zones: (rows, columns) in cells, odd (one number =
            a square; 1 = none). Taller than wide because the road is foreshortened: a cell spans
            4-13 pixels across the image but 1-6 along it, so a square window holds several times
            more independent pixels across than along and is needlessly wide; the tall windows
            give a lower error than squares at the same coverage.
        min_score: cells whose best aggregated ZNCC is below this are NaN (the strongest single
            discriminator of wrong cells). It trades coverage for error: with the default windows
            and ``max_disagreement``, 0.87 gave the coverage of ``bm`` on the version-1 tuning
            frames, so the two compared at equal coverage.
        min_margin: a cell is NaN when a second peak (more than ``peak_exclusion`` from
            the best) scores within this margin of the best (ambiguous, e.g. repetitive texture).
        peak_exclusion: half-width (m) around the best height ignored when looking for a second peak.
        min_texture: std (grey levels of the filtered image) of the left patch below which a
            cell is texture-less (NaN).
        temperature: softmax temperature on the aggregated ZNCC for the uncertainty. The errors
            are heavier-tailed than a Gaussian, so no temperature makes the spread an exact
            1-sigma; this one keeps it informative, where a larger one with the sweep step's
            quantisation added covers nearly every error but is too cautious to be useful.
        blur_sigma: Gaussian pre-smoothing of the images (pixels; 0 = none).
        highpass_sigma: the images minus their Gaussian blur of this sigma (pixels; 0 = none):
            removes shading and exposure gradients that correlate at every height.
        occlusion_clearance: a cell is NaN when a camera's line of sight to it passes nearer
            surface with less than this share of the clearance it would have over a flat road
            (hidden behind a bump, or seen at grazing incidence); 0 = no occlusion test.
        far_aggregation_cells: the box filter (rows, columns) for the farthest ``far_fraction``
            of the rows, where a height step moves the match least.
        far_fraction: share of the rows (from the far end) using ``far_aggregation_cells``.
        near_aggregation_cells, near_fraction: the same for the nearest share of the rows, where
            cells hold many pixels and a smaller window keeps detail.
        shiftable_windows: per cell, use the best of the centred aggregation window and four
            windows shifted by half its size (sharp steps and bump edges instead of smears).
        max_disagreement: cells whose estimate differs by more than this (m) from the estimate
            with a ``check_cells`` window are NaN (0 = no check): the large far and middle windows
            straddle a bump's edge or the hidden strip behind it, where a small window disagrees.
            A better discriminator of wrong cells than ``min_score``: with the check, a given
            error is reached at a higher coverage than by raising ``min_score`` alone.
        check_cells: that small aggregation window (rows, columns), odd.
        max_deviation: cells further than this (m) from the median of their confident
            neighbours (5 x 5 cells) are NaN: isolated wrong peaks (0 = no check).
        threads: torch intra-op threads while estimating (the previous setting is restored
            after). One thread: on a shared 2-core CPU a second thread mostly waits for the busy
            core, which makes two threads slower than one under load; 0 = leave torch's setting.
        max_sigma: cells whose softmax spread (1-sigma, m) exceeds this are NaN: a flat
            or multi-modal score curve.
    """

    z_step: float | None = None
    subsamples: tuple[int, int] = (1, 3)
    far_subsamples: tuple[int, int] = (1, 2)
    near_subsamples: tuple[int, int] = (2, 4)
    patch_cells: WindowSize = 3
    aggregation_cells: WindowSize = (21, 9)
    min_score: float = 0.87
    min_margin: float = 0.02
    peak_exclusion: float = 0.04
    min_texture: float = 0.5
    temperature: float = 0.005
    blur_sigma: float = 1.0
    highpass_sigma: float = 4.0
    occlusion_clearance: float = CLEARANCE
    far_aggregation_cells: WindowSize = (35, 15)
    far_fraction: float = 0.33
    near_aggregation_cells: WindowSize = (13, 5)
    near_fraction: float = 0.33
    shiftable_windows: bool = False
    max_disagreement: float = 0.02
    check_cells: WindowSize = (13, 5)
    max_deviation: float = 0.01
    max_sigma: float = 0.1
    threads: int = 1

    def __post_init__(self) -> None:
        if self.z_step is not None and not (isinstance(self.z_step, (int, float)) and self.z_step > 0):
            raise ConfigError(f"z_step must be a positive number of metres, got {self.z_step!r}")
        for name in ("subsamples", "far_subsamples", "near_subsamples"):
            value = getattr(self, name)
            if not (isinstance(value, tuple) and len(value) == 2 and all(_is_int(v) and v >= 1 for v in value)):
                raise ConfigError(f"{name} must be two positive integers (x, y), got {value!r}")
        windows = ("patch_cells", "aggregation_cells", "far_aggregation_cells", "near_aggregation_cells", "check_cells")
        for name in windows:
            try:
                window_shape(getattr(self, name))
            except ValueError as exc:
                raise ConfigError(f"{name}: {exc}") from None
        non_negative: tuple[str, ...] = (
            "peak_exclusion", "min_texture", "blur_sigma", "highpass_sigma", "occlusion_clearance",
        )
        non_negative += ("max_deviation", "max_disagreement", "far_fraction", "near_fraction")
        for name in (*non_negative, "min_score", "min_margin", "temperature", "max_sigma"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"{name} must be a finite number, got {value!r}")
            if name in non_negative and value < 0:
                raise ConfigError(f"{name} must be >= 0, got {value}")
        if self.temperature <= 0 or self.max_sigma <= 0:
            raise ConfigError("temperature and max_sigma must be positive")
        if not _is_int(self.threads) or self.threads < 0:
            raise ConfigError(f"threads must be a non-negative integer, got {self.threads!r}")
        if self.far_fraction + self.near_fraction > 1.0:
            raise ConfigError("far_fraction + near_fraction must not exceed 1 (the zones would overlap)")
        if not isinstance(self.shiftable_windows, bool):
            raise ConfigError(f"shiftable_windows must be true or false, got {self.shiftable_windows!r}")

    @classmethod
    def from_options(cls, options: dict[str, Any]) -> SweepParams:
        """Parameters from keyword options (lists become tuples); unknown names raise ConfigError."""
        known = {f.name for f in fields(cls)}
        unknown = set(options) - known
        if unknown:
            raise ConfigError(
                f"unknown bev_sweep option(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}"
            )
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in options.items()}
        return cls(**values)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def grey_image(image: np.ndarray, blur_sigma: float = 0.0, highpass_sigma: float = 0.0) -> np.ndarray:
    """[H, W] float32 grey levels of an RGB [H, W, 3] or grey [H, W] uint8 image, filtered.

    Args:
        image: the camera image.
        blur_sigma: Gaussian smoothing (pixels; 0 = none).
        highpass_sigma: subtract the Gaussian blur of this sigma (pixels; 0 = keep the mean level).
    """
    grey: np.ndarray = grey_u8(image).astype(np.float32)
    if blur_sigma > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), blur_sigma)
    if highpass_sigma > 0:
        grey = grey - cv2.GaussianBlur(grey, (0, 0), highpass_sigma)
    return grey


class _Samples(NamedTuple):
    """Road-frame sample positions of some rows: [rows*sx] x and [C*sy] y, with the counts per cell."""

    x: torch.Tensor
    y: torch.Tensor
    per_x: int
    per_y: int


class _Zone(NamedTuple):
    """Rows ``start:stop`` of the grid, sampled from row ``first`` (a margin for the ZNCC window)."""

    start: int
    stop: int
    first: int
    samples: _Samples


def _sample_positions(grid: GridSpec, per_x: int, per_y: int) -> _Samples:
    """Sample positions ``per_x`` x ``per_y`` per cell, centred in it (row 0 farthest, col 0 leftmost)."""
    x = grid.x_max - (np.arange(grid.n_rows * per_x) + 0.5) * (grid.resolution / per_x)
    y = grid.y_max - (np.arange(grid.n_cols * per_y) + 0.5) * (grid.resolution / per_y)
    return _Samples(torch.tensor(x, dtype=torch.float32), torch.tensor(y, dtype=torch.float32), per_x, per_y)


class _Decision(NamedTuple):
    """Per-cell outcome of one sweep: [R, C] tensors."""

    elevation: torch.Tensor  # sub-step height (m)
    sigma: torch.Tensor  # 1-sigma (m)
    best: torch.Tensor  # best score
    level: torch.Tensor  # level (index) of the best score
    second: torch.Tensor  # best score outside the exclusion zone
    interior: torch.Tensor  # bool: the peak is not on the first or last level


def _best_shifted_window(score: torch.Tensor, shift: tuple[int, int]) -> torch.Tensor:
    """Per cell, the score curve [K, R, C] of the best of five windows: centred or shifted.

    ``score`` holds box-aggregated scores; the window centred on a neighbour ``shift`` = (rows,
    columns) away still contains the cell. Near a step or a bump's edge the centred window
    straddles two surfaces and its peak is smeared between them; a window shifted onto one side
    has the higher peak, so picking the window with the best peak keeps discontinuities sharp
    (shiftable windows, as in classical stereo aggregation).
    """
    sr, sc = shift
    if sr < 1 and sc < 1:
        return score
    n_k, n_rows, n_cols = score.shape
    padded = F.pad(score, (sc, sc, sr, sr), value=_WORST)  # [K, R+2sr, C+2sc]
    candidates = torch.stack(
        (
            score,
            padded[:, :n_rows, sc : sc + n_cols],  # window centred `sr` rows nearer the top (farther)
            padded[:, 2 * sr :, sc : sc + n_cols],
            padded[:, sr : sr + n_rows, :n_cols],
            padded[:, sr : sr + n_rows, 2 * sc :],
        )
    )  # [5, K, R, C]
    best = candidates.max(dim=1).values  # [5, R, C]
    choice = best.argmax(dim=0)  # [R, C]
    return candidates.gather(0, choice[None, None].expand(1, n_k, n_rows, n_cols))[0]


def _outliers(surface: torch.Tensor, confident: torch.Tensor, tolerance: float) -> torch.Tensor:
    """[R, C] bool: confident cells further than ``tolerance`` from the 5 x 5 median around them.

    ``surface`` is the estimate with its holes filled from confident neighbours (see
    :meth:`BevSweep._fill_holes`), so the median is over confident evidence only; a wrong peak in
    a texture-poor patch stands out from the surface around it (the BEV analogue of a speckle
    filter). OpenCV's median (float32, 5 x 5) over the filled surface is used because a NaN-aware
    median over unfolded windows costs far more.
    """
    median = torch.from_numpy(cv2.medianBlur(np.ascontiguousarray(surface.numpy(), dtype=np.float32), 5))
    return confident & ((surface - median).abs() > tolerance)


class BevSweep:
    """The training-free BEV plane-sweep stereo backend (see the module docstring)."""

    name = "bev_sweep"
    needs_stereo = True

    def __init__(self, grid: GridSpec, params: SweepParams | None = None) -> None:
        # the pipeline flushes denormals in the thread that runs the backend; this covers
        # direct use in the constructing thread (tests, scripts)
        torch.set_flush_denormal(True)
        self.grid = grid
        self.params = params or SweepParams()
        p = self.params
        span = grid.z_max - grid.z_min
        step = p.z_step if p.z_step is not None else span / max(3, round(span / DEFAULT_Z_STEP))
        n_levels = int(round(span / step))
        if n_levels < 3 or abs(n_levels * step - (grid.z_max - grid.z_min)) > 1e-6:
            raise ConfigError(
                f"z_step {step} m must divide the grid's height range {grid.z_min}..{grid.z_max} m "
                "into at least 3 levels"
            )
        self.z_step = step
        self._zones = self._sampling_zones()
        self._cells = _sample_positions(grid, 1, 1)
        self._z = torch.tensor(grid.z_min + (np.arange(n_levels) + 0.5) * step, dtype=torch.float32)

    def _zone_rows(self) -> tuple[int, int]:
        """(first middle row, first near row): the far / middle / near zones' row boundaries."""
        n_rows, p = self.grid.n_rows, self.params
        return int(round(n_rows * p.far_fraction)), n_rows - int(round(n_rows * p.near_fraction))

    def _sampling_zones(self) -> list[_Zone]:
        """The far, middle and near row ranges (empty ones left out) with their sample positions.

        Each zone's samples reach half the ZNCC window's rows into its neighbours, so the ZNCC
        window of a boundary row is as complete as anywhere else; those margin rows are dropped.
        """
        p, n_rows = self.params, self.grid.n_rows
        mid_start, near_start = self._zone_rows()
        margin = window_shape(p.patch_cells)[0] // 2
        zones = []
        for start, stop, per in (
            (0, mid_start, p.far_subsamples),
            (mid_start, near_start, p.subsamples),
            (near_start, n_rows, p.near_subsamples),
        ):
            if stop <= start:
                continue
            lo, hi = max(0, start - margin), min(n_rows, stop + margin)
            full = _sample_positions(self.grid, *per)
            samples = _Samples(full.x[lo * per[0] : hi * per[0]], full.y, per[0], per[1])
            zones.append(_Zone(start, stop, lo, samples))
        return zones

    # --- geometry ------------------------------------------------------------------------------
    def _normalised_coordinates(
        self, samples: _Samples, heights: torch.Tensor, camera: StereoCamera, attitude: Attitude
    ) -> torch.Tensor:
        """Normalised ``grid_sample`` coordinates [2, K, Rs, Cs, 2] (left, right images).

        Args:
            samples: the sample rows' x and columns' y (road frame).
            heights: road-frame z of the samples, [K, 1, 1] (horizontal planes, the cheap case)
                or [K, Rs, Cs] (surfaces).
        """
        return sample_coordinates(samples.x, samples.y, heights, camera, attitude, self.grid.base_height).coords

    def _valid_levels(self, camera: StereoCamera, attitude: Attitude) -> torch.Tensor:
        """[Z, R, C] bool: the cell centre at that height projects inside both images."""
        cells = self._cells
        inside = sample_coordinates(cells.x, cells.y, self._z[:, None, None], camera, attitude,
                                    self.grid.base_height).inside(camera)  # [2, Z, R, C]
        return inside[0] & inside[1]

    # --- matching ------------------------------------------------------------------------------
    def _zncc(
        self, images: torch.Tensor, samples: _Samples, heights: torch.Tensor, frame: Frame, clock: StageClock
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """ZNCC [K, R, C] over the patch window and the left patch's std [K, R, C].

        Args:
            images: [2, 1, H, W] filtered (zero-mean) left and right images.
            samples: sample positions of this pass.
            heights: [K, 1, 1] or [K, R*sx, C*sy] road-frame heights of the samples.
        """
        coords = self._normalised_coordinates(samples, heights, frame.camera, frame.attitude)
        clock.lap("projection")
        n_k, n_rs, n_cs = coords.shape[1:4]
        values = F.grid_sample(
            images, coords.view(2, n_k * n_rs, n_cs, 2), mode="bilinear", padding_mode="border", align_corners=True
        ).view(2, n_k, n_rs, n_cs)
        clock.lap("sampling")
        sx, sy = samples.per_x, samples.per_y
        n_rows, n_cols = n_rs // sx, n_cs // sy
        left, right = values[0], values[1]

        def cell_sum(v: torch.Tensor) -> torch.Tensor:  # [K, R*sx, C*sy] -> [K, R, C]
            # Strided slices added up: much faster than a reduction over interleaved axes.
            total = v[:, 0::sx, 0::sy].clone() if sx * sy > 1 else v
            for i in range(sx):
                for j in range(sy):
                    if i or j:
                        total += v[:, i::sx, j::sy]
            return total

        moments = torch.stack(
            (cell_sum(left), cell_sum(right), cell_sum(left * left), cell_sum(right * right), cell_sum(left * right))
        )  # [5, K, R, C]: per-cell sums
        k = self.params.patch_cells
        # Box window over k x k cells at cell resolution = the mean over the window's samples.
        moments = box_mean(moments.view(5 * n_k, n_rows, n_cols), k).view(5, n_k, n_rows, n_cols) * (1.0 / (sx * sy))
        m_l, m_r, m_ll, m_rr, m_lr = moments.unbind(dim=0)
        var_l = (m_ll - m_l * m_l).clamp_min_(0.0)
        var_r = (m_rr - m_r * m_r).clamp_min_(0.0)
        zncc = (m_lr - m_l * m_r).mul_(torch.rsqrt(var_l * var_r + 1e-6))
        clock.lap("cost")
        return zncc, var_l.sqrt_()

    def _zncc_zones(
        self, images: torch.Tensor, heights: torch.Tensor, frame: Frame, clock: StageClock
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """ZNCC and left-patch std [K, R, C] of the whole grid, each zone at its sampling density.

        Args:
            images: [2, 1, H, W] filtered (zero-mean) left and right images.
            heights: [K, 1, 1] road-frame heights of the sweep planes.
        """
        scores, textures = [], []
        for zone in self._zones:
            zncc, texture = self._zncc(images, zone.samples, heights, frame, clock)  # [K, rows + margins, C]
            keep = slice(zone.start - zone.first, zone.stop - zone.first)
            scores.append(zncc[:, keep])
            textures.append(texture[:, keep])
        return torch.cat(scores, dim=1), torch.cat(textures, dim=1)

    def _decide(self, score: torch.Tensor, levels: torch.Tensor, step: float) -> _Decision:
        """Best level per cell of a score volume [K, R, C] over heights ``levels`` ([K, R, C] or [K, 1, 1]).

        The best level is refined by a parabola through it and its neighbours; the uncertainty is
        the spread of the softmax over the levels (at least 1 mm: the parabola refines below the
        step, so the step's quantisation is not a floor).
        """
        p = self.params
        n_k = score.shape[0]
        best, idx = score.max(dim=0)  # [R, C]
        s_lo = score.gather(0, (idx - 1).clamp_min(0)[None])[0]
        s_hi = score.gather(0, (idx + 1).clamp_max(n_k - 1)[None])[0]
        curvature = s_lo - 2.0 * best + s_hi
        offset = torch.where(curvature < -1e-9, 0.5 * (s_lo - s_hi) / curvature, torch.zeros_like(best))
        level_at_best = levels.expand(n_k, *best.shape).gather(0, idx[None])[0]
        elevation = level_at_best + offset.clamp(-0.5, 0.5) * step
        # The second peak: the best local maximum outside the exclusion zone (a broad main peak's
        # flanks are not a second peak; a separate maximum is).
        edge = torch.full_like(score[:1], _WORST)
        padded = torch.cat((edge, score, edge))  # [K+2, R, C]
        local_max = (score >= padded[:-2]) & (score >= padded[2:])
        far = (torch.arange(n_k)[:, None, None] - idx[None]).abs() * step > p.peak_exclusion
        second = torch.where(far & local_max, score, torch.full_like(score, _WORST)).max(dim=0).values
        prob = torch.softmax(score / p.temperature, dim=0)
        spread = (prob * (levels - elevation[None]).square()).sum(dim=0)
        sigma = spread.sqrt().clamp_min(_MIN_SIGMA)
        interior = (idx > 0) & (idx < n_k - 1)
        return _Decision(elevation, sigma, best, idx, second, interior)

    @staticmethod
    def _fill_holes(surface: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
        """[R, C] ``surface`` with the cells not ``known`` filled from known neighbours (0 m if none)."""
        return torch.from_numpy(fill_holes(surface.numpy(), known.numpy()))

    def _occluded(self, surface: torch.Tensor, baseline: float) -> torch.Tensor:
        """[R, C] bool: cells whose line of sight (left or right camera) grazes the nearer surface.

        The ray from a camera centre (``base_height`` above the road origin; the right camera
        ``baseline`` to the right) to a cell at its estimated height is sampled at fractions f of
        the way; at each sample the clearance above the (hole-filled) surface is compared with the
        clearance over a flat road, (H - e)(1 - f). Behind a bump or a kerb that ratio drops to
        about zero: the cell is hidden or seen at grazing incidence, and what the sweep found there
        is the occluder's edge, not the road.

        Args:
            surface: [R, C] elevation with no holes.
            baseline: stereo baseline (m).
        """
        grid, p = self.grid, self.params
        n_rows, n_cols = grid.shape
        height = grid.base_height
        x = self._cells.x[None, :, None]  # [1, R, 1]
        y = self._cells.y[None, None, :]  # [1, 1, C]
        e = surface[None]  # [1, R, C]
        # Samples only where the ray is over the grid (nothing is known nearer than x_min) and more
        # than 1.5 cells before its target: ~30 cm apart for the farthest cells, a bump's width.
        reach = (x - 1.5 * grid.resolution - grid.x_min).clamp_min(0.0)  # [1, R, 1]
        px = grid.x_min + torch.linspace(0.0, 1.0, _OCCLUSION_SAMPLES)[:, None, None] * reach  # [F, R, 1]
        fractions = px / x  # [F, R, 1]: share of the way from the camera to the cell
        tested = (reach > 0).expand(_OCCLUSION_SAMPLES, n_rows, 1)  # [F, R, 1]
        ray_z = height + fractions * (e - height)  # [F, R, C]: the same for both cameras
        flat = ((height - e) * (1.0 - fractions)).clamp_min_(1e-6)  # [F, R, C]
        # Normalised grid_sample coordinates of (px, py) on the [R, C] map (cell centres):
        # row from px (shared), column from py (per camera), written in place.
        coords = torch.empty(1, _OCCLUSION_SAMPLES * n_rows, n_cols, 2)
        row_norm = ((grid.x_max - px) / grid.resolution - 0.5) * (2.0 / max(n_rows - 1, 1)) - 1.0  # [F, R, 1]
        coords[0, :, :, 1] = row_norm.reshape(-1, 1)
        col_scale = 2.0 / (grid.resolution * max(n_cols - 1, 1))  # a one-cell axis: border padding
        hidden = torch.zeros(n_rows, n_cols, dtype=torch.bool)
        for origin_y in (0.0, -baseline):
            py = origin_y + fractions * (y - origin_y)  # [F, R, C]
            coords[0, :, :, 0] = ((grid.y_max - 0.5 * grid.resolution) - py).mul_(col_scale).sub_(1.0).view(-1, n_cols)
            ground = F.grid_sample(
                surface[None, None], coords, mode="bilinear", padding_mode="border", align_corners=True
            ).view(_OCCLUSION_SAMPLES, n_rows, n_cols)
            ratio = (ray_z - ground).div_(flat).masked_fill_(~tested, math.inf)
            hidden |= ratio.amin(dim=0) < p.occlusion_clearance
        return hidden

    # --- protocol ------------------------------------------------------------------------------
    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and uncertainty of ``self.grid`` for one stereo frame."""
        if frame.right is None:
            raise FrameError("bev_sweep needs a stereo frame (the right image is missing)")
        if frame.camera.baseline <= 0:
            raise FrameError("bev_sweep needs a stereo rig with a positive baseline")
        previous = torch.get_num_threads()
        if self.params.threads:
            torch.set_num_threads(self.params.threads)
        try:
            return self._estimate(frame, frame.right)
        finally:
            torch.set_num_threads(previous)

    def _estimate(self, frame: Frame, right: np.ndarray) -> Estimate:
        clock = StageClock()
        p = self.params
        greys = np.stack([grey_image(im, p.blur_sigma, p.highpass_sigma) for im in (frame.left, right)])
        greys -= greys.mean(axis=(1, 2), keepdims=True)  # zero-mean: precise float32 moments
        images = torch.from_numpy(greys)[:, None]  # [2, 1, H, W]
        clock.lap("preprocess")
        with torch.no_grad():
            valid = self._valid_levels(frame.camera, frame.attitude)  # [Z, R, C]
            planes = self._z[:, None, None]  # [Z, 1, 1]
            zncc, texture = self._zncc_zones(images, planes, frame, clock)
            aggregated = box_mean(zncc, p.aggregation_cells)
            mid_start, near_start = self._zone_rows()
            if p.far_aggregation_cells != p.aggregation_cells:
                # Far rows: 1 cm of elevation moves the match by ~0.15 px only; a larger window.
                aggregated[:, :mid_start] = box_mean(zncc, p.far_aggregation_cells)[:, :mid_start]
            if p.near_aggregation_cells != p.aggregation_cells:
                # Near rows: many pixels per cell, ~0.5 px per cm; a smaller window keeps detail.
                aggregated[:, near_start:] = box_mean(zncc, p.near_aggregation_cells)[:, near_start:]
            score = torch.where(valid, aggregated, torch.full_like(zncc, _WORST))
            if p.shiftable_windows:
                rows, cols = window_shape(p.aggregation_cells)
                score = _best_shifted_window(score, (rows // 2, cols // 2))
            clock.lap("aggregation")
            decision = self._decide(score, planes, self.z_step)
            confident = (
                (decision.best >= p.min_score)
                & (decision.best - decision.second >= p.min_margin)
                & decision.interior
                & (texture.gather(0, decision.level[None])[0] >= p.min_texture)
                & valid.all(dim=0)
                & (decision.sigma <= p.max_sigma)
            )
            elevation, sigma = decision.elevation, decision.sigma
            if p.max_disagreement > 0:
                small = torch.where(valid, box_mean(zncc, p.check_cells), torch.full_like(zncc, _WORST))
                check = self._decide(small, planes, self.z_step)
                disagreement = (check.elevation - elevation).abs()
                confident &= disagreement <= p.max_disagreement
                # The two windows disagree where the large one smears a bump's edge: part of the error.
                sigma = torch.hypot(sigma, disagreement)
            if p.max_deviation > 0:
                confident &= ~_outliers(self._fill_holes(elevation, confident), confident, p.max_deviation)
            if p.occlusion_clearance > 0:
                confident &= ~self._occluded(self._fill_holes(elevation, confident), frame.camera.baseline)
            nan = torch.full_like(elevation, float("nan"))
            elevation_np = torch.where(confident, elevation, nan).numpy().astype(np.float32)
            sigma_np = torch.where(confident, sigma, nan).numpy().astype(np.float32)
            clock.lap("post")
        return Estimate(elevation=elevation_np, uncertainty=sigma_np, timings_ms=clock.timings)

    def describe(self) -> dict[str, Any]:
        """Parameters as a JSON-able dict (for benchmark records)."""
        return {"backend": self.name, "z_step": self.z_step, **asdict(self.params)}


def create_bev_sweep(grid: GridSpec, **options: Any) -> BevSweep:
    """Backend factory: ``create("bev_sweep", grid, patch_cells=3, ...)`` (see :class:`SweepParams`)."""
    return BevSweep(grid, SweepParams.from_options(options))
