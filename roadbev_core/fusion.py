"""The road map that follows the wheels: per-frame estimates fused over time in ``odom``.

docs/concepts/fused_map.md explains it. Each frame's estimate (elevation and
1-sigma on the grid, in the road frame ``base_height`` below the camera) is placed in ``odom``
with the planar pose of ``base_link`` from the odometry and the camera's roll and pitch from the
IMU, aligned with what the map already holds, and fused cell by cell::

    estimate [R, C] ──► place_frame (odometry x, y, yaw; IMU roll, pitch; camera on base_link)
                     ──► sample at the map's cells (bilinear, holes stay holes)
                     ──► align: offset + slopes fitted on the overlap with the map (weighted,
                         gated, with priors), so body heave and base_height error do not smear
                     ──► gate each cell (Mahalanobis) ──► inverse-variance update

**The lattice.** Cells are fixed in ``odom`` (centre of cell (i, j) at ((i + 0.5) r, (j + 0.5) r),
r the grid's resolution): the window moves by whole cells, so a cell's value is never resampled
(elevation_mapping's rolling map). The map holds the *corridor* of the car: from ``behind_m``
behind the rear axle to the grid's far edge, as wide as the grid (in ``base_link``); a cell that
leaves it is forgotten, a cell no frame saw stays NaN.

**Vertical datum.** ``odom`` z is unobservable from planar odometry; the first frame's road plane
is put where the static ride height puts it (``base_link`` on the road), later frames are aligned
to the map where they overlap it (offset ``a`` at the camera and slopes ``b``, ``c`` along and
across the camera's heading, with Gaussian priors ``offset_prior_m`` and ``slope_prior_rad``
around the prediction), and without overlap they keep the prediction (the map's contact plane
under the car at static ride height, else the last frame's body height). The datum therefore
drifts: a backend whose heights lean with distance (a pitch bias, a scale error) hands each frame
a slightly different offset against the map, and these add up with the distance driven. Nothing
a consumer does with the map needs ``odom`` z itself: a controller, a planner, a person reads
heights against the road the car stands on (the preview against the contact plane, a hazard
against the road around it). So the published ``uncertainty`` is **anchored to the road under
the car**: a cell's height against the map's road under the car now, whose datums differ by the
drift over the distance driven between the two fusions. A cell fused (as the weighted mean of its
observations) at odometer reading ``s_cell`` carries ``datum_sigma_m + datum_drift * |s_now -
s_cell|`` in quadrature to its own sigma, the two calibrated per backend on tuning drives
(:func:`datum_calibration_for`). Cells leave the corridor behind the rear axle, so this stays
bounded however far the car drives. The gate, the alignment and the preview use the cells' own
sigma: the datum is common to the cells they compare, and the contact plane the preview is
relative to lies on the same datum. (:class:`FrameFusion` keeps the absolute datum's sigma, the
part that does grow with the distance driven, for diagnostics.)

**The far field** (``far_field.enabled``, :meth:`FusedMap.integrate_far`): the corridor reaches
the far-field grid's far edge, still at the grid's resolution; each map cell in a far-field cell
takes its height and sigma, once per frame, with the frame's datum and alignment. The grid's
observation supersedes the far field's: a cell the far field alone has seen starts again from
its first grid observation, or is forgotten when the grid looks at it and declines it (a cell
hidden behind a crest, one the matcher could not match: what the grid cannot tell there, the
coarser, farther look cannot either), and a cell the grid has seen takes no far-field observation. The far
field's errors are several times the grid's and correlated over whole coarse cells, so its weight
in a mean with grid observations would be small and its bias not; this way every cell the grid
has looked at holds what it would hold without the far field (and so does the alignment fitted
on those cells).

**Fusion.** A cell keeps the weighted mean of the observations it accepted, with weights
``w = 1 / (s^2 (x / x_near)^k)``: ``s`` the observation's sigma, ``x`` its distance ahead of the
camera, ``x_near`` the grid's near edge, ``k = range_exponent``. Nearer is better, and by more
than the calibrated sigma says: that sigma is fitted per cell on features of the estimate and
hardly grows with distance, while the error does (stereo height error grows with the square of
the distance, so its variance with the fourth power: k = 4). Errors of one backend on one road
are correlated from frame to frame, so the fused variance is not the independent one: with correlation ``rho``
it is ``(1 - rho) sum(w^2 s^2) / W^2 + rho (sum(w s) / W)^2`` (``W = sum w``; for N equal
observations ``s^2 (rho + (1 - rho) / N)``, the variance of a mean of equicorrelated errors), and
never less than the spread of the accepted observations around their mean. An observation farther than
``gate_sigma`` combined sigmas from the cell is rejected; ``reset_after`` rejections in a row
(the road really is different: the map was wrong) restart the cell from the new observation.

Pure numpy; shapes in the comments.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from roadbev_core.config import GridSpec, RoadbevConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, Attitude, rotation_from_rpy
from roadbev_core.tables import json_table
from roadbev_core.vehicle import planar_yaw

__all__ = [
    "DATUM_CALIBRATION_FILE",
    "FrameFusion",
    "FramePlacement",
    "FusedMap",
    "FusionError",
    "MapSettings",
    "MapWindow",
    "Prepared",
    "datum_calibration_for",
    "map_settings",
    "place_frame",
    "prepare_bilinear",
    "sample_bilinear",
    "sample_prepared",
]


class FusionError(RoadbevError, ValueError):
    """Map settings or inputs the fusion cannot use."""


# per backend: the map datum's 1-sigma when fixed and its growth per metre driven, fitted on
# tuning drives by ``python -m benchmarks.calibrate_datum`` (never on the benchmark drives)
DATUM_CALIBRATION_FILE = Path(__file__).resolve().parent / "data" / "datum_calibration.json"


def datum_calibration_for(backend: str, path: Path = DATUM_CALIBRATION_FILE) -> tuple[float, float] | None:
    """``(datum_sigma_m, datum_drift)`` fitted for ``backend`` (None when the table has none, or
    the file is missing or unreadable)."""
    try:
        entry = json_table(path)["backends"][backend]
        sigma, drift = float(entry["datum_sigma_m"]), float(entry["datum_drift"])
    except (ValueError, KeyError, TypeError):
        return None
    if not (math.isfinite(sigma) and math.isfinite(drift) and sigma >= 0 and drift >= 0):
        return None
    return sigma, drift


@dataclass(frozen=True)
class MapSettings:
    """How the map is kept (``map.*`` parameters; the corridor from the grid and the vehicle).

    Attributes:
        resolution: cell size (m): the grid's.
        behind_m: the map reaches this far behind the rear axle.
        ahead_m: the far edge in ``base_link`` x (camera x + the grid's ``x_max``; the far-field
            grid's with the far field on).
        y_min, y_max: the corridor's lateral extent in ``base_link`` (camera y + the grid's).
        base_height: the road frame lies this far below the camera.
        error_correlation: ``rho`` of the fused variance: how correlated one cell's errors are
            from frame to frame (0 = independent frames).
        gate_sigma: observations farther than this many combined sigmas are rejected.
        reset_after: this many rejections in a row restart a cell.
        align: fit the offset (and with ``align_slopes`` the slopes) of each frame on the overlap.
        offset_prior_m, slope_prior_rad: 1-sigma priors of the alignment around the prediction.
        min_overlap_cells: fewer overlapping cells than this: the prediction is kept.
        align_correlation: correlation of the cell errors of one frame in the alignment fit (the
            overlap's n cells are worth ``1 / (rho + (1 - rho) / n)`` independent ones).
        range_exponent: an observation at distance x ahead of the camera weighs
            ``(x_near / x)^range_exponent`` times what its sigma alone says (x_near: the grid's
            near edge).
        datum_sigma_m, datum_drift: 1-sigma of the map's vertical datum (``odom`` z, which
            nothing observes) where it is fixed, and its growth per metre driven (m/m): a cell
            fused ``d`` metres of driving away from where the car is now carries
            ``datum_sigma_m + datum_drift * d`` in the published uncertainty (module docstring).
    """

    resolution: float
    behind_m: float
    ahead_m: float
    y_min: float
    y_max: float
    base_height: float
    error_correlation: float = 1.0
    gate_sigma: float = 3.0
    reset_after: int = 3
    align: bool = True
    align_slopes: bool = True
    offset_prior_m: float = 0.05
    slope_prior_rad: float = math.radians(0.3)
    min_overlap_cells: int = 50
    range_exponent: float = 4.0
    align_correlation: float = 0.1
    datum_sigma_m: float = 0.0
    datum_drift: float = 0.0

    def __post_init__(self) -> None:
        if not (0.001 <= self.resolution <= 1.0):
            raise FusionError(f"map resolution must be in [0.001, 1] m, got {self.resolution}")
        if not (self.ahead_m > -self.behind_m and self.y_max > self.y_min):
            raise FusionError("the map corridor is empty")
        if not 0.0 <= self.error_correlation <= 1.0:
            raise FusionError(f"error_correlation must be in [0, 1], got {self.error_correlation}")
        if self.datum_sigma_m < 0 or self.datum_drift < 0:
            raise FusionError("datum_sigma_m and datum_drift must be >= 0")
        if self.gate_sigma <= 0 or self.reset_after < 1:
            raise FusionError("gate_sigma must be > 0 and reset_after >= 1")
        cells = (self.ahead_m + self.behind_m) * (self.y_max - self.y_min) / self.resolution ** 2
        if cells > 4_000_000:
            raise FusionError(f"the map corridor would hold {cells:,.0f} cells (limit 4,000,000): coarser cells")


def map_settings(config: RoadbevConfig, camera_position_m: Sequence[float] | np.ndarray | None = None) -> MapSettings:
    """The fused map's settings of ``config``: the ``map.*`` parameters, the corridor from the
    grid (to the far-field grid's far edge with ``far_field.enabled``) and the camera's position on
    ``base_link`` (``camera_position_m``, [3]: from ``/tf_static`` when known, else
    ``vehicle.camera_position_m``), and the backend's calibrated datum where ``map.datum_sigma_m``
    / ``map.datum_drift`` are -1.

    Raises:
        FusionError: settings the map cannot use.
    """
    cam = config.vehicle.camera_position_m if camera_position_m is None else tuple(camera_position_m)
    m, g = config.map, config.grid
    far_grid = config.far_grid  # with the far field on the corridor reaches its far edge (one resolution: the grid's)
    x_max = g.x_max if far_grid is None else far_grid.x_max
    calibrated = datum_calibration_for(config.backend.name) or (0.0, 0.0)
    datum_sigma = calibrated[0] if m.datum_sigma_m < 0 else m.datum_sigma_m
    datum_drift = calibrated[1] if m.datum_drift < 0 else m.datum_drift
    return MapSettings(
        resolution=g.resolution, behind_m=m.behind_m, ahead_m=float(cam[0]) + x_max,
        y_min=float(cam[1]) + g.y_min, y_max=float(cam[1]) + g.y_max, base_height=g.base_height,
        error_correlation=m.error_correlation, gate_sigma=m.gate_sigma, reset_after=m.reset_after,
        align=m.align, align_slopes=m.align_slopes, offset_prior_m=m.offset_prior_m,
        slope_prior_rad=math.radians(m.slope_prior_deg), min_overlap_cells=m.min_overlap_cells,
        range_exponent=m.range_exponent, align_correlation=m.align_correlation,
        datum_sigma_m=datum_sigma, datum_drift=datum_drift,
    )


class FramePlacement(NamedTuple):
    """Where one frame's road frame lies in ``odom`` (horizontally; z is the datum's business).

    Attributes:
        origin: [2] x, y of the camera (the road frame's origin) in ``odom``.
        heading: yaw of the road frame's x axis (the camera's heading) in ``odom``.
        camera_height_over_base: z of the camera above ``base_link``'s origin, vertical (m).
        R_odom_base: [3, 3] the body's attitude (yaw from odometry, tilt from the IMU).
        base: the planar pose it was placed with.
    """

    origin: np.ndarray
    heading: float
    camera_height_over_base: float
    R_odom_base: np.ndarray
    base: PlanarPose


def place_frame(base: PlanarPose, attitude: Attitude, camera_position: np.ndarray,
                R_base_optical: np.ndarray | None) -> FramePlacement:
    """Place a frame: ``base_link``'s planar pose, the camera's roll/pitch relative to gravity, and
    the camera on ``base_link`` (position [3] of the optical centre; R [3, 3] optical ->
    base_link, from ``/tf_static``).

    The body's tilt follows from the camera's (the camera is fixed to it); its yaw is the
    odometry's. Without the mounting rotation (no TF) the body is taken as level and the camera
    as looking along its x axis.
    """
    position = np.asarray(camera_position, np.float64)
    if R_base_optical is None:
        M = np.eye(3)
    else:
        R_base_cambody = np.asarray(R_base_optical, np.float64) @ R_BODY_FROM_OPTICAL.T  # camera body -> base
        R_tilt_cambody = rotation_from_rpy(attitude.roll, attitude.pitch)  # camera body -> level, yaw 0
        M = R_tilt_cambody @ R_base_cambody.T  # base_link -> level frame with the camera's heading
    yaw_of_m = float(planar_yaw(M))
    heading = base.yaw - yaw_of_m  # the camera's heading in odom
    c, s = math.cos(heading), math.sin(heading)
    R_odom_base = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ M
    offset = R_odom_base @ position  # [3] camera relative to base_link's origin, odom axes
    origin = np.array([base.x + offset[0], base.y + offset[1]])
    return FramePlacement(origin, heading, float(offset[2]), R_odom_base, base)


def sample_bilinear(values: np.ndarray, sigma: np.ndarray | None, rows: np.ndarray, cols: np.ndarray,
                    min_weight: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of a [R, C] array at fractional (row, col) [N] (cell centres at integers).

    Unknown (NaN) neighbours drop out and the weights of the known ones are renormalised; a
    sample whose known neighbours weigh less than ``min_weight`` is NaN (holes stay holes).

    Returns:
        [N] values and [N] sigmas (the same weights; NaN without ``sigma``).
    """
    # one NaN cell around the array: outside is a hole, and every sample has its neighbours inside
    padded = np.pad(values, 1, constant_values=np.nan)
    padded_sigma = None if sigma is None else np.pad(sigma, 1, constant_values=np.nan)
    return sample_prepared(prepare_bilinear(padded, padded_sigma), np.clip(rows + 1.0, 0.0, values.shape[0] + 1.0),
                           np.clip(cols + 1.0, 0.0, values.shape[1] + 1.0), min_weight, with_sigma=sigma is not None)


class Prepared(NamedTuple):
    """A [R, C] array (and its sigma) ready for :func:`sample_prepared`: flat, holes zeroed.

    Attributes:
        shape: (R, C).
        values: [R*C] the values, 0 in a hole.
        sigma: [R*C] the sigmas, 0 in a hole (all 0 without sigma).
        known: [R*C] 1.0 where the value (and the sigma) is finite, else 0.
    """

    shape: tuple[int, int]
    values: np.ndarray
    sigma: np.ndarray
    known: np.ndarray


def prepare_bilinear(values: np.ndarray, sigma: np.ndarray | None) -> Prepared:
    """Flatten ``values`` [R, C] (and ``sigma``) once for many :func:`sample_prepared` calls."""
    known = np.isfinite(values) if sigma is None else np.isfinite(values) & np.isfinite(sigma)
    sigma_flat = np.zeros(values.size) if sigma is None else np.where(known, sigma, 0.0).ravel()
    return Prepared((int(values.shape[0]), int(values.shape[1])), np.where(known, values, 0.0).ravel(), sigma_flat,
                    known.ravel().astype(np.float64))


def sample_prepared(prepared: Prepared, rows: np.ndarray, cols: np.ndarray, min_weight: float = 0.5,
                    with_sigma: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sample_bilinear` of a :class:`Prepared` array (sigma NaN unless ``with_sigma``)."""
    n_rows, n_cols = prepared.shape
    r0f, c0f = np.floor(rows), np.floor(cols)
    tr, tc = rows - r0f, cols - c0f
    r0, c0 = r0f.astype(np.intp), c0f.astype(np.intp)
    if rows.size and r0.min() >= 0 and r0.max() < n_rows - 1 and c0.min() >= 0 and c0.max() < n_cols - 1:
        # every sample has its four neighbours inside (the usual case): no clipping, no masks
        flat = r0 * n_cols + c0
        corners = (flat, flat + 1, flat + n_cols, flat + n_cols + 1)
        weights = ((1.0 - tr) * (1.0 - tc), (1.0 - tr) * tc, tr * (1.0 - tc), tr * tc)
    else:
        # per-axis weights of the two neighbours, 0 outside the array
        wr = (np.where((r0 >= 0) & (r0 < n_rows), 1.0 - tr, 0.0), np.where((r0 >= -1) & (r0 < n_rows - 1), tr, 0.0))
        wc = (np.where((c0 >= 0) & (c0 < n_cols), 1.0 - tc, 0.0), np.where((c0 >= -1) & (c0 < n_cols - 1), tc, 0.0))
        rr = (np.clip(r0, 0, n_rows - 1) * n_cols, np.clip(r0 + 1, 0, n_rows - 1) * n_cols)
        cc = (np.clip(c0, 0, n_cols - 1), np.clip(c0 + 1, 0, n_cols - 1))
        corners = (rr[0] + cc[0], rr[0] + cc[1], rr[1] + cc[0], rr[1] + cc[1])
        weights = (wr[0] * wc[0], wr[0] * wc[1], wr[1] * wc[0], wr[1] * wc[1])
    acc = np.zeros(rows.shape)
    acc_s = np.zeros(rows.shape)
    weight = np.zeros(rows.shape)
    for flat_k, w in zip(corners, weights, strict=True):
        wk = w * np.take(prepared.known, flat_k)  # [N] the weight of this neighbour where it is known
        acc += w * np.take(prepared.values, flat_k)  # values are 0 where unknown
        if with_sigma:
            acc_s += w * np.take(prepared.sigma, flat_k)
        weight += wk
    good = weight >= min_weight - 1e-12
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(good, acc / weight, np.nan)
        out_s = np.where(good, acc_s / weight, np.nan) if with_sigma else np.full(rows.shape, np.nan)
    return out, out_s


@dataclass(frozen=True)
class FrameFusion:
    """What fusing one frame did.

    Attributes:
        offset_m, slope_x, slope_y: the alignment (at the camera; along and across its heading).
        aligned: whether the alignment came from the overlap (else the prediction was kept).
        overlap_cells: cells the frame shared with the map.
        residual_rms_m: weighted RMS of the overlap residuals after alignment.
        accepted, rejected, restarted: cells updated, rejected by the gate, restarted.
        cost_ms: wall time.
        datum_sigma_m: the 1-sigma of the map's datum in ``odom`` z at this frame (grows with the
            distance driven; the published uncertainty carries the datum against the car instead).
        driven_m: the distance driven since the datum was fixed (the map's odometer).
        base_z_m: ``base_link``'s origin z in odom after the frame (the datum it put the map on).
    """

    offset_m: float
    slope_x: float
    slope_y: float
    aligned: bool
    overlap_cells: int
    residual_rms_m: float
    accepted: int
    rejected: int
    restarted: int
    cost_ms: float
    datum_sigma_m: float = 0.0
    driven_m: float = 0.0
    base_z_m: float = math.nan


class MapWindow(NamedTuple):
    """The map as published: grid_map order (row 0 at the largest x, column 0 at the largest y).

    Attributes:
        elevation: [n_rows, n_cols] float32 z in ``odom`` (m), NaN = never seen.
        uncertainty: [n_rows, n_cols] float32 1-sigma (m) of the cell's height against the road under
            the car: its own and its datum's against the car's (module docstring).
        observations: [n_rows, n_cols] float32 accepted observations.
        age: [n_rows, n_cols] float32 seconds since the cell's last update (NaN = never).
        resolution: cell size (m).
        centre: (x, y) of the window's centre in ``odom``.
        stamp_ns: the frame it was made after.
        datum_uncertainty: [n_rows, n_cols] float32, the part of ``uncertainty`` that nearby
            cells share (the 1-sigma of their datum against the car's, module docstring);
            None for a map without that layer. Compare cells with each other (a bump's height
            above the road around it, a slope) with :meth:`local_uncertainty`.
    """

    elevation: np.ndarray
    uncertainty: np.ndarray
    observations: np.ndarray
    age: np.ndarray
    resolution: float
    centre: tuple[float, float]
    stamp_ns: int
    datum_uncertainty: np.ndarray | None = None

    def layers(self) -> dict[str, np.ndarray]:
        """The map's layers (docs/interface/topics.md) by name (and ``datum_uncertainty`` when known)."""
        layers = {"elevation": self.elevation, "uncertainty": self.uncertainty, "observations": self.observations,
                  "age": self.age}
        if self.datum_uncertainty is not None:
            layers["datum_uncertainty"] = self.datum_uncertainty
        return layers

    def local_uncertainty(self) -> np.ndarray:
        """[n_rows, n_cols] float32 1-sigma of a cell against the cells around it: ``uncertainty``
        without the datum's part (all of ``uncertainty`` when the datum's is unknown)."""
        if self.datum_uncertainty is None:
            return self.uncertainty
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.maximum(self.uncertainty.astype(np.float64) ** 2
                                      - self.datum_uncertainty.astype(np.float64) ** 2, 0.0)).astype(np.float32)

    def cell_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """[n_rows] x and [n_cols] y of the cell centres in ``odom``."""
        n_rows, n_cols = self.elevation.shape
        r = self.resolution
        x = self.centre[0] + 0.5 * n_rows * r - (np.arange(n_rows) + 0.5) * r
        y = self.centre[1] + 0.5 * n_cols * r - (np.arange(n_cols) + 0.5) * r
        return x, y

    def crop(self, position: tuple[float, float], length: tuple[float, float]) -> MapWindow | None:
        """The cells whose centres lie in the ``length`` (x, y) rectangle centred on ``position``
        (``odom``), as a window of their own (grid_map's sub-map); None when none does.
        A zero or negative length means the whole window along that axis."""
        x, y = self.cell_centres()
        half_x = length[0] / 2 if length[0] > 0 else math.inf
        half_y = length[1] / 2 if length[1] > 0 else math.inf
        rows = np.flatnonzero(np.abs(x - position[0]) <= half_x + 1e-9)  # [k] contiguous: x falls with the row
        cols = np.flatnonzero(np.abs(y - position[1]) <= half_y + 1e-9)
        if rows.size == 0 or cols.size == 0:
            return None
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        cut = (slice(r0, r1), slice(c0, c1))
        centre = (float(x[r0:r1].mean()), float(y[c0:c1].mean()))
        datum = None if self.datum_uncertainty is None else self.datum_uncertainty[cut]
        return MapWindow(self.elevation[cut], self.uncertainty[cut], self.observations[cut], self.age[cut],
                         self.resolution, centre, self.stamp_ns, datum)


class _FrameAlignment(NamedTuple):
    """Where :meth:`FusedMap.integrate` put the last frame: its stamp and placement, the road
    plane's z in odom (``datum``), the alignment ``a + b u + c v`` with its covariance [3, 3], and
    the grid's near edge ``x_near`` of its weights."""

    stamp_ns: int
    placement: FramePlacement
    datum: float
    a: float
    b: float
    c: float
    cov: np.ndarray
    x_near: float


# the sums per cell: w, w z, w z^2, w sigma, w^2 sigma^2, w s (s: the map's odometer at the fusion)
_W, _S1, _S2, _WSIG, _W2VAR, _WODO = range(6)


class FusedMap:
    """The rolling map (see the module docstring). Not thread-safe: one caller (the pipeline).

    Args:
        settings: the map's settings.
    """

    MARGIN_M = 1.0  # the buffer reaches this far beyond the corridor on every side
    # ... and this much further ahead, so that it moves (a copy of every layer) about every LEAD_M
    # driven rather than every MARGIN_M, without widening it sideways
    LEAD_M = 4.0

    def __init__(self, settings: MapSettings) -> None:
        self.settings = settings
        self.reset()

    def reset(self) -> None:
        """Forget everything (a new drive, a clock that jumped back, ``~/clear_map``)."""
        self._i0 = 0  # lattice index of buffer row 0 (x)
        self._j0 = 0  # lattice index of buffer column 0 (y)
        self._sums = np.zeros((_WODO + 1, 0, 0))  # [6, n_i, n_j] see _W ... _WODO
        self._n = np.zeros((0, 0), np.int32)
        self._rejected = np.zeros((0, 0), np.int16)
        # the cell holds an observation of the grid (not only of the far field) since it (re)started:
        # the alignment fits each frame on those alone
        self._near_seen = np.zeros((0, 0), bool)
        self._t_last = np.zeros((0, 0), np.int64)
        # the fused mean and sigma of every cell as a bilinear table (0 and known = 0 where nothing
        # was accepted), kept up to date cell by cell as frames change them: heights() samples it
        self._table = prepare_bilinear(np.zeros((0, 0)), np.zeros((0, 0)))
        self._base_z: float | None = None  # base_link's origin z in odom, after the last frame
        self._driven = 0.0  # metres driven since the datum was fixed
        self._last_xy: tuple[float, float] | None = None
        self._last_frame: _FrameAlignment | None = None  # the datum and alignment integrate_far reuses
        self.frames = 0

    @property
    def empty(self) -> bool:
        return not bool(np.any(self._n > 0))

    # --- the lattice and the window ------------------------------------------------------------
    def _corridor_corners(self, base: PlanarPose) -> np.ndarray:
        """[4, 2] corners of the corridor in odom."""
        s = self.settings
        local = np.array([[-s.behind_m, s.y_min], [-s.behind_m, s.y_max], [s.ahead_m, s.y_min], [s.ahead_m, s.y_max]])
        c, sn = math.cos(base.yaw), math.sin(base.yaw)
        return np.stack([base.x + c * local[:, 0] - sn * local[:, 1], base.y + sn * local[:, 0] + c * local[:, 1]], 1)

    def _index_box(self, corners: np.ndarray, margin: float) -> tuple[int, int, int, int]:
        """Lattice index box (i_lo, i_hi, j_lo, j_hi), hi exclusive, around points [K, 2]."""
        r = self.settings.resolution
        lo = np.floor((corners.min(0) - margin) / r).astype(int)
        hi = np.ceil((corners.max(0) + margin) / r).astype(int)
        return int(lo[0]), int(hi[0]), int(lo[1]), int(hi[1])

    def _ensure(self, corners: np.ndarray, yaw: float) -> None:
        """Move/resize the buffer so it holds the box around ``corners`` (whole cells: no
        resampling), reaching :attr:`LEAD_M` further on the side the car heads to (``yaw``)."""
        n_i, n_j = self._n.shape
        i_lo, i_hi, j_lo, j_hi = self._index_box(corners, 0.0)
        if n_i and i_lo >= self._i0 and j_lo >= self._j0 and i_hi <= self._i0 + n_i and j_hi <= self._j0 + n_j:
            return
        i_lo, i_hi, j_lo, j_hi = self._index_box(corners, self.MARGIN_M)
        # the lead, split over the axes by the heading: the buffer moves about every LEAD_M driven
        along_i, along_j = math.cos(yaw), math.sin(yaw)
        lead_i, lead_j = (int(math.ceil(self.LEAD_M * abs(a) / self.settings.resolution)) for a in (along_i, along_j))
        i_lo, i_hi = (i_lo, i_hi + lead_i) if along_i >= 0 else (i_lo - lead_i, i_hi)
        j_lo, j_hi = (j_lo, j_hi + lead_j) if along_j >= 0 else (j_lo - lead_j, j_hi)
        shape = (i_hi - i_lo, j_hi - j_lo)
        # the overlap of the old and the new buffer, in lattice indices
        a_lo, a_hi = max(i_lo, self._i0), min(i_hi, self._i0 + n_i)
        b_lo, b_hi = max(j_lo, self._j0), min(j_hi, self._j0 + n_j)

        def moved(old: np.ndarray) -> np.ndarray:  # [..., n_i, n_j] -> [..., shape]
            new = np.zeros(old.shape[:-2] + shape, old.dtype)
            if a_hi > a_lo and b_hi > b_lo:
                new[..., a_lo - i_lo:a_hi - i_lo, b_lo - j_lo:b_hi - j_lo] = \
                    old[..., a_lo - self._i0:a_hi - self._i0, b_lo - self._j0:b_hi - self._j0]
            return new

        self._sums = moved(self._sums)
        self._n, self._rejected, self._t_last = moved(self._n), moved(self._rejected), moved(self._t_last)
        self._near_seen = moved(self._near_seen)
        self._table = Prepared(shape, *(moved(a.reshape(n_i, n_j)).ravel() for a in self._table[1:]))
        self._i0, self._j0 = i_lo, j_lo

    def _forget_outside(self, base: PlanarPose) -> None:
        """Clear every cell outside the corridor at ``base`` (behind the car, beside it)."""
        n_i, n_j = self._n.shape
        r = self.settings.resolution
        # the whole buffer's lattice, row and column coordinates broadcast (no [n_i * n_j] index arrays)
        x = (self._i0 + np.arange(n_i) + 0.5) * r  # [n_i]
        y = (self._j0 + np.arange(n_j) + 0.5) * r  # [n_j]
        self._clear(np.flatnonzero((self._n > 0) & ~self._inside_corridor(x[:, None], y[None, :], base)))

    def _clear(self, cells: np.ndarray) -> None:
        """Forget the cells at flat buffer indices [K]."""
        if cells.size:
            for row in self._sums.reshape(_WODO + 1, -1):
                row[cells] = 0.0
            self._n.ravel()[cells] = 0
            self._rejected.ravel()[cells] = 0
            self._near_seen.ravel()[cells] = False
            for a in self._table[1:]:
                a[cells] = 0.0

    # --- reading -------------------------------------------------------------------------------
    def _fused_at(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fused elevation and 1-sigma [K] of the cells at flat buffer indices [K] (NaN where
        nothing was accepted)."""
        table = self._table
        known = np.take(table.known, flat) > 0
        return np.where(known, np.take(table.values, flat), np.nan), np.where(known, np.take(table.sigma, flat), np.nan)

    def _refresh(self, flat: np.ndarray, sums: Sequence[np.ndarray]) -> None:
        """Recompute the mean and sigma of cells at flat buffer indices [K] that hold observations,
        from their sums ``sums`` (w, w z, w z^2, w sigma, w^2 sigma^2 [K] each, as just written)."""
        w, s1, s2, wsig, w2var = sums[:_WODO]
        rho = self.settings.error_correlation
        mean = s1 / w
        model = (1.0 - rho) * w2var / (w * w) + rho * (wsig / w) ** 2
        sigma = np.sqrt(np.maximum(model, np.maximum(s2 / w - mean * mean, 0.0)))  # never below the spread
        self._table.values[flat] = mean
        self._table.sigma[flat] = sigma
        self._table.known[flat] = 1.0

    def heights(self, x: np.ndarray, y: np.ndarray, min_weight: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear fused height and 1-sigma at odom points [...] (NaN where the map has none)."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        if not self._n.size:
            return np.full(x.shape, np.nan), np.full(x.shape, np.nan)
        r = self.settings.resolution
        rows = x / r - 0.5 - self._i0
        cols = y / r - 0.5 - self._j0
        z, s = sample_prepared(self._table, rows.ravel(), cols.ravel(), min_weight)
        return z.reshape(x.shape), s.reshape(x.shape)

    def window(self, base: PlanarPose, stamp_ns: int) -> MapWindow:
        """The corridor at ``base`` as published (grid_map order, axis-aligned in odom)."""
        r = self.settings.resolution
        i_lo, i_hi, j_lo, j_hi = self._index_box(self._corridor_corners(base), 0.0)
        shape = (i_hi - i_lo, j_hi - j_lo)
        layers = {name: np.full(shape, np.nan, np.float32) for name in ("elevation", "uncertainty", "age", "datum")}
        observations = np.zeros(shape, np.float32)
        n_i, n_j = self._n.shape
        a_lo, a_hi = max(i_lo, self._i0), min(i_hi, self._i0 + n_i)
        b_lo, b_hi = max(j_lo, self._j0), min(j_hi, self._j0 + n_j)
        if a_hi > a_lo and b_hi > b_lo:
            src = (slice(a_lo - self._i0, a_hi - self._i0), slice(b_lo - self._j0, b_hi - self._j0))
            dst = (slice(a_lo - i_lo, a_hi - i_lo), slice(b_lo - j_lo, b_hi - j_lo))
            known = self._n[src] > 0
            mean, sigma = (a.reshape(n_i, n_j)[src] for a in (self._table.values, self._table.sigma))
            layers["elevation"][dst] = np.where(known, mean, np.nan)
            # the published sigma is against the road under the car: the cell's own and its datum's
            # against the car's, which drifted over the distance driven between them (module docstring)
            w, w_odometer = self._sums[_W][src], self._sums[_WODO][src]
            s = self.settings
            with np.errstate(invalid="ignore", divide="ignore"):
                driven_apart = np.abs(self._driven - w_odometer / w)
                datum_sigma = np.where(known, s.datum_sigma_m + s.datum_drift * driven_apart, np.nan)
            layers["uncertainty"][dst] = np.sqrt(sigma ** 2 + datum_sigma ** 2)
            layers["datum"][dst] = datum_sigma
            layers["age"][dst] = np.where(known, (stamp_ns - self._t_last[src]) * 1e-9, np.nan)
            observations[dst] = self._n[src]
        flip = (slice(None, None, -1), slice(None, None, -1))  # index order (+x, +y) -> grid_map's
        centre = (0.5 * (i_lo + i_hi) * r, 0.5 * (j_lo + j_hi) * r)
        return MapWindow(layers["elevation"][flip], layers["uncertainty"][flip], observations[flip],
                         layers["age"][flip], r, centre, int(stamp_ns), layers["datum"][flip])

    @property
    def base_z(self) -> float | None:
        """``base_link``'s origin z in odom after the last frame (None before the first)."""
        return self._base_z

    # --- fusing a frame ------------------------------------------------------------------------
    def predicted_base_z(self, plane_at_base: float | None) -> float:
        """Where ``base_link``'s origin is expected (static ride height): on the map's contact
        plane when the map holds it, else where the last frame left it (0 before any frame:
        ``odom`` is ``base_link`` at the first stamp)."""
        if plane_at_base is not None and math.isfinite(plane_at_base):
            return float(plane_at_base)
        return 0.0 if self._base_z is None else self._base_z

    def integrate(self, elevation: np.ndarray, sigma: np.ndarray, grid: GridSpec, placement: FramePlacement,
                  stamp_ns: int, *, base_z_prediction: float) -> FrameFusion:
        """Fuse one frame's estimate.

        Args:
            elevation, sigma: [R, C] the estimate on ``grid`` (m; NaN = none).
            placement: where the frame's road frame lies (:func:`place_frame`).
            base_z_prediction: the predicted z of ``base_link``'s origin
                (:meth:`predicted_base_z`).

        Raises:
            FusionError: maps not on ``grid``.
        """
        t0 = time.perf_counter()
        s = self.settings
        if elevation.shape != grid.shape or sigma.shape != grid.shape:
            raise FusionError(f"estimate {elevation.shape} / {sigma.shape} is not on the grid {grid.shape}")
        base = placement.base
        self._ensure(np.concatenate([self._corridor_corners(base), self._frame_corners(grid, placement)]), base.yaw)
        self._forget_outside(base)
        if self.empty or self._last_xy is None:
            self._driven = 0.0  # this frame fixes the datum
        else:
            self._driven += math.hypot(base.x - self._last_xy[0], base.y - self._last_xy[1])
        self._last_xy = (base.x, base.y)
        datum_sigma = s.datum_sigma_m + s.datum_drift * self._driven
        datum = base_z_prediction + placement.camera_height_over_base - s.base_height  # road plane z in odom
        # the map cells under the frame, and the frame sampled there
        flat, u, v = self._cells_under(grid, placement)
        rows = (grid.x_max - u) / grid.resolution - 0.5
        cols = (grid.y_max - v) / grid.resolution - 0.5
        z, sz = sample_bilinear(np.asarray(elevation, np.float64), np.asarray(sigma, np.float64), rows, cols)
        ok = np.isfinite(z) & np.isfinite(sz) & (sz > 0)
        # a cell the grid looked at and declined (hidden, unmatched) holds no far-field value either
        # (module docstring, "The far field")
        declined = flat[~ok]
        self._clear(declined[(self._n.ravel()[declined] > 0) & ~self._near_seen.ravel()[declined]])
        flat, u, v, z, sz = flat[ok], u[ok], v[ok], z[ok] + datum, sz[ok]
        range_factor = np.maximum(u / grid.x_min, 1.0) ** s.range_exponent if grid.x_min > 0 else np.ones_like(u)
        m, ms = self._fused_at(flat)
        both = np.isfinite(m) & np.take(self._near_seen.ravel(), flat)  # aligned on the grid's cells only
        a, b, c, cov, rms, aligned = self._align(z[both], sz[both] * np.sqrt(range_factor[both]), u[both], v[both],
                                                 m[both], ms[both])
        z = z + (a + b * u + c * v)
        # the alignment's variance at (u, v): g^T cov g with g = (1, u, v)
        var = sz ** 2 + (cov[0, 0] + 2.0 * cov[0, 1] * u + 2.0 * cov[0, 2] * v + cov[1, 1] * u * u
                         + 2.0 * cov[1, 2] * u * v + cov[2, 2] * v * v)
        accepted, rejected, restarted = self._update(flat, m, ms, z, var, range_factor, stamp_ns, near=True)
        self._base_z = datum + a + s.base_height - placement.camera_height_over_base
        self._last_frame = _FrameAlignment(int(stamp_ns), placement, datum, float(a), float(b), float(c), cov,
                                           grid.x_min)
        self.frames += 1
        return FrameFusion(float(a), float(b), float(c), aligned, int(both.sum()), rms, accepted, rejected, restarted,
                           1e3 * (time.perf_counter() - t0), float(datum_sigma), float(self._driven),
                           float(self._base_z))

    def integrate_far(self, elevation: np.ndarray, sigma: np.ndarray, far_grid: GridSpec, placement: FramePlacement,
                      stamp_ns: int) -> tuple[int, int, int]:
        """Fuse the far-field estimate of the frame :meth:`integrate` just fused, on the map's cells.

        The map keeps one resolution (the grid's). A map cell whose centre lies in a far-field
        cell takes that cell's height and sigma as they are (no interpolation between coarse
        cells): it is one measurement of that cell, once per frame. The map cells of one
        far-field cell share its error (fully correlated), so nothing may count them as
        independent: the per-cell fusion never does (each cell gets one observation per frame),
        and whatever combines cells averages their sigmas (the preview's footprints,
        :func:`roadbev_core.map_preview.footprint_heights`) instead of dividing by the square root
        of their number. Inflating each cell's sigma by that root instead would publish every far
        cell as several times less certain than the far-field estimate is.

        The frame's datum and alignment are the grid's (:meth:`integrate`), fitted on the map cells
        a grid observation reached (a cell the far field alone has seen takes no part): the far
        field is never aligned on its own, and the alignment's slopes reach it with their variance
        (growing with the distance). Its weights keep the grid's near edge as ``x_near``, so a
        far-field observation weighs ``(x_near / x)^range_exponent`` of one of its sigma.

        Args:
            elevation, sigma: [R, C] the far-field estimate on ``far_grid`` (m; NaN = none).
            far_grid: the far-field grid.
            placement, stamp_ns: the frame's, as given to :meth:`integrate`.

        A map cell the grid has already seen takes no far-field observation (the module docstring,
        "The far field").

        Returns:
            Cells accepted, rejected by the gate and restarted.

        Raises:
            FusionError: maps not on ``far_grid``, or no :meth:`integrate` of this frame before.
        """
        last = self._last_frame
        if last is None or last.stamp_ns != int(stamp_ns) or last.placement is not placement:
            raise FusionError("integrate_far fuses the far field of the frame integrate just fused (same placement "
                              "and stamp)")
        if elevation.shape != far_grid.shape or sigma.shape != far_grid.shape:
            raise FusionError(f"far-field estimate {elevation.shape} / {sigma.shape} is not on the far-field grid "
                              f"{far_grid.shape}")
        s = self.settings
        # the buffer holds the corridor and the far field's footprint together (moved to hold the
        # footprint alone, it would drop the corridor behind it)
        self._ensure(np.concatenate([self._corridor_corners(placement.base), self._frame_corners(far_grid, placement)]),
                     placement.base.yaw)
        flat, u, v = self._cells_under(far_grid, placement)
        n_rows, n_cols = far_grid.shape
        # the far-field cell holding each map cell's centre (rows from the far edge, columns from the left)
        rows = np.clip(np.floor((far_grid.x_max - u) / far_grid.resolution), 0, n_rows - 1).astype(np.intp)
        cols = np.clip(np.floor((far_grid.y_max - v) / far_grid.resolution), 0, n_cols - 1).astype(np.intp)
        z = np.asarray(elevation, np.float64)[rows, cols]
        sz = np.asarray(sigma, np.float64)[rows, cols]
        ok = np.isfinite(z) & np.isfinite(sz) & (sz > 0)
        flat, u, v, z, sz = flat[ok], u[ok], v[ok], z[ok], sz[ok]
        range_factor = np.maximum(u / last.x_near, 1.0) ** s.range_exponent if last.x_near > 0 else np.ones_like(u)
        z = z + last.datum + last.a + last.b * u + last.c * v
        cov = last.cov
        var = sz ** 2 + (cov[0, 0] + 2.0 * cov[0, 1] * u + 2.0 * cov[0, 2] * v + cov[1, 1] * u * u
                         + 2.0 * cov[1, 2] * u * v + cov[2, 2] * v * v)
        m, ms = self._fused_at(flat)
        return self._update(flat, m, ms, z, var, range_factor, stamp_ns, near=False)

    @staticmethod
    def _frame_corners(grid: GridSpec, placement: FramePlacement) -> np.ndarray:
        local = np.array([[grid.x_min, grid.y_min], [grid.x_min, grid.y_max], [grid.x_max, grid.y_min],
                          [grid.x_max, grid.y_max]])
        c, s = math.cos(placement.heading), math.sin(placement.heading)
        ox, oy = placement.origin
        return np.stack([ox + c * local[:, 0] - s * local[:, 1], oy + s * local[:, 0] + c * local[:, 1]], 1)

    def _cells_under(self, grid: GridSpec, placement: FramePlacement
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flat buffer indices [N] of the cells under the frame, and their road-frame (u, v) [N]."""
        r = self.settings.resolution
        i_lo, i_hi, j_lo, j_hi = self._index_box(self._frame_corners(grid, placement), 0.0)
        i_lo, j_lo = max(i_lo, self._i0), max(j_lo, self._j0)
        i_hi, j_hi = min(i_hi, self._i0 + self._n.shape[0]), min(j_hi, self._j0 + self._n.shape[1])
        gi, gj = np.arange(i_lo, i_hi)[:, None], np.arange(j_lo, j_hi)[None, :]  # [h, 1], [1, w]: the box
        x, y = (gi + 0.5) * r, (gj + 0.5) * r
        c, s = math.cos(placement.heading), math.sin(placement.heading)
        dx, dy = x - placement.origin[0], y - placement.origin[1]
        u, v = c * dx + s * dy, -s * dx + c * dy  # [h, w]
        inside = (u >= grid.x_min) & (u <= grid.x_max) & (v >= grid.y_min) & (v <= grid.y_max)
        inside &= self._inside_corridor(x, y, placement.base)
        flat = (gi - self._i0) * self._n.shape[1] + (gj - self._j0)  # [h, w]
        return flat[inside], u[inside], v[inside]

    def _inside_corridor(self, x: np.ndarray, y: np.ndarray, base: PlanarPose) -> np.ndarray:
        s = self.settings
        c, sn = math.cos(base.yaw), math.sin(base.yaw)
        dx, dy = x - base.x, y - base.y
        along, across = c * dx + sn * dy, -sn * dx + c * dy
        return (along >= -s.behind_m) & (along <= s.ahead_m) & (across >= s.y_min) & (across <= s.y_max)

    def _align(self, z: np.ndarray, sz: np.ndarray, u: np.ndarray, v: np.ndarray, m: np.ndarray, ms: np.ndarray
               ) -> tuple[float, float, float, np.ndarray, float, bool]:
        """Offset and slopes taking the frame onto the map on their overlap [K].

        Returns:
            a, b, c, their covariance [3, 3] (inflated for errors correlated across cells), the
            weighted RMS residual, and whether the overlap decided them.
        """
        s = self.settings
        prior = np.diag([s.offset_prior_m ** -2, s.slope_prior_rad ** -2, s.slope_prior_rad ** -2])
        if not s.align_slopes:
            prior[1, 1] = prior[2, 2] = 1e12  # slopes pinned to the prediction
        if self.empty:  # the first frame (after a reset) defines the map's datum: nothing to align to
            return 0.0, 0.0, 0.0, np.zeros((3, 3)), math.nan, False
        if not s.align or z.size < s.min_overlap_cells:
            return 0.0, 0.0, 0.0, np.linalg.inv(prior), math.nan, False
        prior[0, 0] = 0.0  # with an overlap the offset is the data's alone (its prior is for frames without)
        var = sz ** 2 + ms ** 2
        # fitted about the overlap's weighted centre, so the offset prior does not leak into the slopes
        inverse_var = 1.0 / var
        total = inverse_var.sum()
        u0, v0 = float((u * inverse_var).sum() / total), float((v * inverse_var).sum() / total)
        g = np.stack([np.ones_like(u), u - u0, v - v0], 1)  # [K, 3]
        residual = m - z
        keep = np.ones(z.size, bool)
        x = np.zeros(3)
        # spatially correlated cell errors: n cells of one frame are worth 1 / (rho + (1 - rho) / n) of one
        rho = s.align_correlation
        for _ in range(3):  # refit without the cells the fit cannot explain (a bump moved, a bad cell)
            n = max(int(keep.sum()), 1)
            w = np.where(keep, inverse_var, 0.0) / (n * (rho + (1.0 - rho) / n))
            gw = (g * w[:, None]).T  # [3, K]
            x = np.linalg.solve(gw @ g + prior, gw @ residual)
            fit = residual - g @ x
            new_keep = np.abs(fit) <= s.gate_sigma * np.sqrt(var)
            if np.array_equal(new_keep, keep) or new_keep.sum() < s.min_overlap_cells:
                break
            keep = new_keep
        n = int(keep.sum())
        w = np.where(keep, inverse_var, 0.0) / (max(n, 1) * (rho + (1.0 - rho) / max(n, 1)))
        cov_c = np.linalg.inv((g * w[:, None]).T @ g + prior)
        fit = residual - g @ x
        rms = float(np.sqrt(np.sum(w * fit ** 2) / np.sum(w))) if n else math.nan  # weighted RMS (m)
        # back to the offset at the camera: a = a' - b u0 - c v0
        T = np.array([[1.0, -u0, -v0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        a, b, c = T @ x
        return float(a), float(b), float(c), T @ cov_c @ T.T, rms, True

    def _update(self, flat: np.ndarray, m: np.ndarray, ms: np.ndarray, z: np.ndarray, var: np.ndarray,
                range_factor: np.ndarray, stamp_ns: int, *, near: bool) -> tuple[int, int, int]:
        """Gate and fuse observations z [N] with variances var [N] and range factors [N] (the
        weight is ``1 / (var * range_factor)``), all made at the map's current odometer, into the
        cells at flat buffer indices [N] (distinct), whose fused mean and sigma are m, ms [N]
        (NaN: never seen); ``near``: observations of the grid (else of the far field)."""
        s = self.settings
        near_seen = self._near_seen.ravel()
        if not near:  # a cell the grid has seen takes no far-field observation (module docstring)
            keep = ~near_seen[flat]
            flat, m, ms, z, var, range_factor = flat[keep], m[keep], ms[keep], z[keep], var[keep], range_factor[keep]
        seen = np.isfinite(m)
        # a cell the far field alone has seen starts again from the grid's observation
        superseded = seen & ~near_seen[flat] if near else np.zeros(flat.shape, bool)
        with np.errstate(invalid="ignore"):
            far = seen & ~superseded & (np.abs(z - m) > s.gate_sigma * np.sqrt(var + ms ** 2))
        n, sums = self._n.ravel(), self._sums.reshape(_WODO + 1, -1)  # views
        rejected_cells = self._rejected.ravel()
        rejected = rejected_cells[flat].astype(np.int32) + far
        restart = (far & (rejected >= s.reset_after)) | superseded
        take = ~far | restart
        # restart: the cell starts again from this observation
        tf, tz, tv = flat[take], z[take], var[take]
        w = 1.0 / (tv * range_factor[take])  # nearer observations weigh more (see the module docstring)
        wz = w * tz
        restarted = restart[take]
        any_restart = bool(restarted.any())
        updated = []  # [6][K] the cells' new sums, written and then read by _refresh
        for row, add in zip(sums, (w, wz, wz * tz, w * np.sqrt(tv), w * w * tv, w * self._driven), strict=True):
            updated.append((np.where(restarted, 0.0, row[tf]) if any_restart else row[tf]) + add)
            row[tf] = updated[-1]
        if any_restart:
            n[flat[restart]] = 0
        n[tf] += 1
        near_seen[tf] = near | (near_seen[tf] & ~restarted)
        self._t_last.ravel()[tf] = stamp_ns
        rejected_cells[flat] = np.where(take, 0, np.minimum(rejected, 1000)).astype(np.int16)
        self._refresh(tf, updated)
        return int(take.sum()), int((far & ~restart).sum()), int((far & restart).sum())  # superseded: no restart
