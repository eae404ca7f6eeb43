"""Figures: voxel-column segments (paper Fig. 4), elevation maps, and the ``roadbev figures`` command."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude
from roadbev_lab.reports.figures import FigureError, elevation_figure, voxel_column_segments, voxel_columns_figure

GRID = GridSpec()
CAM = StereoCamera(fx=500.0, fy=500.0, cx=240.0, cy=130.0, baseline=0.12, width=480, height=264)


def _frame(attitude: Attitude) -> Frame:
    img = np.full((CAM.height, CAM.width, 3), 90, np.uint8)
    return Frame(left=img, right=img.copy(), camera=CAM, attitude=attitude)


def test_segments_of_a_level_camera_are_worked_out_by_hand() -> None:
    segments, dist = voxel_column_segments(_frame(Attitude(0.0, 0.0)), GRID, row_step=20, col_step=16)
    assert segments.shape == (len(GRID.x_centres()[::20]) * len(GRID.y_centres()[::16]), 2, 2)
    # level camera at base height h: a point at height z, distance x is on v = cy + fy (h - z) / x
    np.testing.assert_allclose(segments[:, 0, 1], CAM.cy + CAM.fy * (GRID.base_height - GRID.z_min) / dist)
    np.testing.assert_allclose(segments[:, 1, 1], CAM.cy + CAM.fy * (GRID.base_height - GRID.z_max) / dist)
    # columns are vertical for a level camera: same u at both ends, left of centre for y > 0
    np.testing.assert_allclose(segments[:, 0, 0], segments[:, 1, 0])
    y = np.repeat(GRID.y_centres()[::16][None, :], len(GRID.x_centres()[::20]), axis=0).ravel()
    np.testing.assert_allclose(segments[:, 0, 0], CAM.cx - CAM.fx * y / dist)


def test_segments_reject_a_bad_step() -> None:
    with pytest.raises(FigureError, match="step"):
        voxel_column_segments(_frame(Attitude()), GRID, row_step=0)


def test_voxel_columns_figure_draws_over_the_image(tmp_path: Path) -> None:
    path = voxel_columns_figure(_frame(Attitude.from_degrees(0.5, 19.0)), GRID, tmp_path / "sub" / "cols.png")
    img = cv2.imread(str(path))
    assert img is not None and img.shape[0] > CAM.height * 0.9 and img.shape[1] >= CAM.width * 0.9
    # the uniform grey image now carries coloured column segments
    saturation = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)[..., 1]
    assert (saturation > 120).mean() > 0.01


def test_elevation_figure_writes_a_png_and_checks_the_shape(tmp_path: Path) -> None:
    elev = np.full(GRID.shape, np.nan, np.float32)
    elev[40:80, 10:30] = -0.05
    elev[100:120] = 0.08
    path = elevation_figure(elev, GRID, tmp_path / "elev.png", title="test")
    img = cv2.imread(str(path))
    assert img is not None and img.shape[0] > img.shape[1]  # taller than wide, like the grid
    reds = (img[..., 2].astype(int) - img[..., 0] > 80).mean()
    blues = (img[..., 0].astype(int) - img[..., 2] > 80).mean()
    assert reds > 0.01 and blues > 0.005  # both signs are shown
    elevation_figure(np.full(GRID.shape, np.nan), GRID, tmp_path / "empty.png")  # no labels: still draws
    with pytest.raises(FigureError, match="grid"):
        elevation_figure(np.zeros((10, 10)), GRID, tmp_path / "bad.png")


def test_figures_command_writes_both_pngs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from roadbev_cli.cli import main

    out = tmp_path / "figs"
    assert main(["figures", "--out", str(out), "--seed", "2", "--features", "pothole"]) == 0
    for name in ("voxel_columns.png", "gt_elevation.png"):
        assert cv2.imread(str(out / name)) is not None
    assert "voxel_columns.png" in capsys.readouterr().out
    assert main(["figures", "--out", str(out), "--road-class", "Q"]) == 2
    assert "road_class" in capsys.readouterr().err


def _bins(scale: float, cells: int = 500) -> list[dict[str, float | int]]:
    return [{"sigma_lo_cm": s, "sigma_hi_cm": 2 * s, "cells": cells, "mean_sigma_cm": 1.5 * s,
             "q68_abs_err_cm": scale * 1.5 * s, "q95_abs_err_cm": scale * 3.0 * s} for s in (0.1, 0.3, 1.0)]


def test_reliability_figure_draws_a_curve_per_label_and_the_diagonal(tmp_path: Path, saved_figures: list[Any]) -> None:
    from matplotlib import image as mpimg

    from roadbev_lab.reports.figures import reliability_figure

    out = reliability_figure([("honest", _bins(1.0)), ("over-confident", _bins(3.0)),
                              ("sparse", _bins(1.0, cells=49))], tmp_path / "r.png", "t")
    assert mpimg.imread(out).shape[:2] == (600, 720)
    (ax,) = saved_figures[0].axes
    labels = [str(line.get_label()) for line in ax.get_lines()]
    # two lines per kept curve (68 % solid, 95 % / 2 dashed) and the diagonal; "sparse" left out
    assert labels.count("honest (68 %)") == 1 and labels.count("over-confident (68 %)") == 1
    assert "honest sigma" in labels and not any("sparse" in label for label in labels)
    over = next(line for line in ax.get_lines() if line.get_label() == "over-confident (68 %)")
    np.testing.assert_allclose(np.asarray(over.get_ydata(), float), 3.0 * np.asarray(over.get_xdata(), float))


def test_reliability_figure_refuses_curves_without_enough_cells(tmp_path: Path) -> None:
    from roadbev_lab.reports.figures import reliability_figure

    with pytest.raises(FigureError, match="50 cells"):
        reliability_figure([("a", _bins(1.0, cells=10)), ("b", [])], tmp_path / "r.png", "t")
    assert not (tmp_path / "r.png").exists()
