"""The one source of truth for the BEV grid (:class:`GridSpec`).

Every part of the project (labels, backends, models, node, evaluation, synthetic data) reads the
grid from a :class:`GridSpec`; nothing else hard-codes a range or a resolution. Defaults follow
docs/interface/frames-and-grid.md ("The BEV grid": the paper's reference code).

Grid layout (the interface's, grid_map's own order): ``[row, col]`` with row 0 the farthest row and
col 0 the leftmost column (largest y). Row ``i`` is centred at ``x_max - (i + 0.5) * res``,
column ``j`` at ``y_max - (j + 0.5) * res``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from roadbev_core.errors import RoadbevError

__all__ = ["GRID_PRESETS", "ConfigError", "GridSpec", "grid_preset", "whole_cells_end"]

_EPS = 1e-6


class ConfigError(RoadbevError, ValueError):
    """A grid, rig or model configuration that cannot work, with the reason."""


# How far from a whole number (in cells) a range may be and still count as whole cells.
_WHOLE_TOLERANCE = 1e-4


def whole_cells_end(start: float, end: float, step: float) -> float:
    """``end``, or where it is not a whole number of ``step`` cells from ``start``, the first
    whole cell's edge beyond it (m): ``end`` itself whenever it fits, to the bit."""
    count = (end - start) / step
    if abs(count - round(count)) <= _WHOLE_TOLERANCE:
        return end
    return round(start + math.ceil(count) * step, 9)


def _whole_count(span: float, step: float, what: str) -> int:
    """Number of cells of size ``step`` in ``span``, which must be a whole number."""
    if not math.isfinite(span) or not math.isfinite(step):
        raise ConfigError(f"{what}: range and step must be finite (span={span}, step={step})")
    if step <= 0:
        raise ConfigError(f"{what}: resolution must be positive, got {step}")
    if span <= 0:
        raise ConfigError(f"{what}: empty or inverted range (span {span:.6g} m)")
    count = span / step
    if abs(count - round(count)) > _WHOLE_TOLERANCE:
        raise ConfigError(
            f"{what}: range of {span:.6g} m is not a whole number of {step:.6g} m cells "
            f"({count:.4f})"
        )
    return int(round(count))


@dataclass(frozen=True)
class GridSpec:
    """The BEV grid in the road frame (x forward, y left, z up; metres).

    Attributes:
        x_min, x_max: longitudinal extent (distance ahead of the camera).
        y_min, y_max: lateral extent (y left positive).
        resolution: horizontal cell size (square cells).
        z_min, z_max: vertical range of the voxels of interest (elevation range).
        z_resolution: vertical voxel size.
        class_resolution: elevation bin size for the classification output.
        base_height: height of the camera's optical centre above the road reference plane.
    """

    x_min: float = 2.16
    x_max: float = 7.08
    y_min: float = -0.92
    y_max: float = 1.00
    resolution: float = 0.03
    z_min: float = -0.20
    z_max: float = 0.20
    z_resolution: float = 0.01
    class_resolution: float = 0.005
    base_height: float = 1.10

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"GridSpec.{name} must be a finite number, got {value!r}")
        _whole_count(self.x_max - self.x_min, self.resolution, "longitudinal x")
        _whole_count(self.y_max - self.y_min, self.resolution, "lateral y")
        _whole_count(self.z_max - self.z_min, self.z_resolution, "vertical z")
        _whole_count(self.z_max - self.z_min, self.class_resolution, "elevation classes")
        if self.x_min <= 0:
            raise ConfigError(f"x_min must be ahead of the camera (> 0), got {self.x_min}")
        if self.base_height <= 0:
            raise ConfigError(f"base_height must be positive, got {self.base_height}")
        if self.z_max >= self.base_height:
            raise ConfigError(
                f"z_max ({self.z_max} m) must lie below the camera (base_height {self.base_height} m)"
            )

    # --- sizes -------------------------------------------------------------------------------
    @property
    def n_rows(self) -> int:
        """Rows along x (164 by default)."""
        return int(round((self.x_max - self.x_min) / self.resolution))

    @property
    def n_cols(self) -> int:
        """Columns along y (64 by default)."""
        return int(round((self.y_max - self.y_min) / self.resolution))

    @property
    def n_z(self) -> int:
        """Vertical voxels (40 by default)."""
        return int(round((self.z_max - self.z_min) / self.z_resolution))

    @property
    def n_classes(self) -> int:
        """Elevation classes (80 by default)."""
        return int(round((self.z_max - self.z_min) / self.class_resolution))

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_rows, n_cols)``."""
        return (self.n_rows, self.n_cols)

    @property
    def length_x(self) -> float:
        return self.n_rows * self.resolution

    @property
    def length_y(self) -> float:
        return self.n_cols * self.resolution

    @property
    def centre(self) -> tuple[float, float]:
        """Grid centre ``(x, y)`` in the road frame (GridMap ``info.pose``)."""
        return (0.5 * (self.x_min + self.x_max), 0.5 * (self.y_min + self.y_max))

    # --- coordinates ---------------------------------------------------------------------------
    def x_centres(self) -> np.ndarray:
        """[n_rows] x of each row's centre, far to near."""
        return self.x_max - (np.arange(self.n_rows) + 0.5) * self.resolution

    def y_centres(self) -> np.ndarray:
        """[n_cols] y of each column's centre, left to right."""
        return self.y_max - (np.arange(self.n_cols) + 0.5) * self.resolution

    def z_centres(self) -> np.ndarray:
        """[n_z] z of each voxel layer's centre, bottom to top."""
        return self.z_min + (np.arange(self.n_z) + 0.5) * self.z_resolution

    def class_centres(self) -> np.ndarray:
        """[n_classes] elevation of each class bin's centre (the soft-argmin values e_c)."""
        return self.z_min + (np.arange(self.n_classes) + 0.5) * self.class_resolution

    def cell_index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row, column and inside-mask of road-frame points.

        Args:
            x, y: [N] coordinates in the road frame.

        Returns:
            rows [N] int64, cols [N] int64, inside [N] bool (rows/cols are only valid where inside).
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        rows = np.floor((self.x_max - x) / self.resolution).astype(np.int64)
        cols = np.floor((self.y_max - y) / self.resolution).astype(np.int64)
        inside = (rows >= 0) & (rows < self.n_rows) & (cols >= 0) & (cols < self.n_cols)
        return rows, cols, inside

    def band_of_rows(self, n_bands: int = 15) -> np.ndarray:
        """[n_rows] distance band index of each row, 0 = nearest band (the paper's Fig. 9)."""
        near_first = np.arange(self.n_rows)[::-1]  # row index counted from the near end
        return (near_first * n_bands // self.n_rows).astype(np.int64)

    def scaled(self, factor: int) -> GridSpec:
        """A grid with cells ``factor`` times larger horizontally (same extent)."""
        if factor < 1:
            raise ConfigError(f"scale factor must be >= 1, got {factor}")
        return replace(self, resolution=self.resolution * factor)

    def with_overrides(self, **overrides: Any) -> GridSpec:
        """A copy with some fields replaced (validated)."""
        unknown = set(overrides) - set(self.__dataclass_fields__)
        if unknown:
            raise ConfigError(f"unknown grid parameter(s): {', '.join(sorted(unknown))}")
        return replace(self, **{k: float(v) for k, v in overrides.items()})

    def to_dict(self) -> dict[str, float]:
        return {name: float(getattr(self, name)) for name in self.__dataclass_fields__}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GridSpec:
        return cls().with_overrides(**data)


GRID_PRESETS: dict[str, GridSpec] = {
    # The paper's grid (164 x 64 cells of 3 cm, 40 voxels of 1 cm, 80 classes of 0.5 cm).
    "paper": GridSpec(),
    # Same window, 6 cm cells (82 x 32): the CPU models' internal grid before upsampling.
    "half": GridSpec(resolution=0.06),
}


def grid_preset(name: str) -> GridSpec:
    """A named grid preset (``paper``, ``half``)."""
    try:
        return GRID_PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown grid preset {name!r}; choose from {sorted(GRID_PRESETS)}") from None
