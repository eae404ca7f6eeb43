"""The report's figures and page from synthetic arrays (no ROS, no bag)."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib import image as mpimg
from matplotlib.patches import Rectangle

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude
from roadbev_lab.reports.report import (
    FrameView,
    ReportData,
    ReportError,
    RunSummary,
    TimingTrace,
    TrackProfile,
    band_centres_m,
    mask_runs,
    plot_frames,
    plot_preview,
    roi_outline_px,
    write_report,
)

GRID = GridSpec()
CAMERA = StereoCamera.rsrd_half().scaled(0.25)
ATTITUDE = Attitude.from_degrees(0.3, 18.5)


def _frame(index: int, rng: np.random.Generator) -> FrameView:
    yy, xx = np.meshgrid(GRID.y_centres(), GRID.x_centres())
    truth = (-0.04 * np.exp(-((xx - 4.0) ** 2 + (yy - 0.4) ** 2) / 0.05)).astype(np.float32)
    estimate = truth + rng.normal(0.0, 0.003, truth.shape).astype(np.float32)
    estimate[-2:] = np.nan
    distance = GRID.x_centres()[::-1].copy()
    col = int(np.argmin(np.abs(GRID.y_centres() - 0.8)))
    sigma = np.full(distance.size, 0.003)
    est_track = TrackProfile("left", 0.8, distance, estimate[::-1, col].astype(np.float64), sigma)
    gt_track = TrackProfile("left", 0.8, distance, truth[::-1, col].astype(np.float64))
    left = rng.integers(0, 255, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8)
    return FrameView(index, index * 200_000_000, left, CAMERA, ATTITUDE, truth, estimate, (est_track,), (gt_track,))


def _data(frames: int = 2) -> ReportData:
    rng = np.random.default_rng(0)
    metrics = {"frames": 2, "cells": 100, "abs_err_cm": 0.25, "rmse_cm": 0.3, "gt_0p5cm_pct": 5.0,
               "coverage_pct": 98.8, "fps": 9.5, "band_abs_err_cm": [0.1 + 0.01 * i for i in range(15)]}
    runs = [RunSummary("bev_sweep · ROS 2", "bev_sweep", "online", metrics),
            RunSummary("bev_sweep · offline", "bev_sweep", "offline", {**metrics, "rmse_cm": float("nan")})]
    t = np.arange(5) * 0.2
    return ReportData("test report", GRID, runs, [_frame(i, rng) for i in range(frames)],
                      TimingTrace(t, np.full(5, 40.0), t + 0.04), ["a note"], {"bag": "x.mcap"}, {"bag": 1.0})


def test_write_report_writes_every_figure_page_and_json(tmp_path: Path) -> None:
    files = write_report(_data(), tmp_path)
    for name in ("frames.png", "surface.png", "preview.png", "band_error.png", "timing.png"):
        img = mpimg.imread(files[name])
        assert img.shape[0] > 200 and img.shape[1] > 300
        assert float(img[..., :3].std()) > 0.05  # not a blank canvas
    page = (tmp_path / "index.html").read_text()
    # images are referenced relatively (the folder opens offline anywhere)
    assert sorted(re.findall(r'<img src="([^"]+)"', page)) == sorted(
        ["frames.png", "surface.png", "preview.png", "band_error.png", "timing.png"])
    assert "http" not in page
    assert "0.250" in page and "98.8" in page
    payload = json.loads((tmp_path / "report.json").read_text())
    assert payload["runs"][0]["metrics"]["abs_err_cm"] == 0.25
    assert payload["runs"][1]["metrics"]["rmse_cm"] is None  # NaN -> null, standard JSON
    assert payload["frames_shown"] == [0, 1]


def test_preview_figure_draws_a_frame_that_lacks_a_track_another_frame_has(tmp_path: Path) -> None:
    """Frame 1 has a right track, frame 0 has not: frame 0's right panel stays empty (no crash)."""
    rng = np.random.default_rng(3)
    first, second = _frame(0, rng), _frame(1, rng)
    right = TrackProfile("right", -0.8, second.tracks[0].distance_m, second.tracks[0].elevation_m)
    second = replace(second, tracks=(*second.tracks, right))
    out = plot_preview([first, second], tmp_path / "preview.png")
    assert mpimg.imread(out).shape[0] > 200


def test_frames_figure_keeps_the_bev_aspect(tmp_path: Path, saved_figures: list[Any]) -> None:
    """Each BEV map is 4.92 m x 1.92 m: its axes are about 2.56 times taller than wide."""
    plot_frames(_data(1).frames, GRID, tmp_path / "f.png")
    (box,) = [ax.get_window_extent() for ax in saved_figures[0].axes if ax.images and ax.get_title() == "estimate"]
    assert box.height / box.width == pytest.approx(GRID.length_x / GRID.length_y, rel=0.03)


def test_roi_outline_lies_inside_the_image_for_the_rsrd_rig() -> None:
    camera = StereoCamera.rsrd_half()
    uv = roi_outline_px(GRID, camera, Attitude.from_degrees(0.0, 18.5))
    assert np.isfinite(uv).all()
    assert uv[:, 0].min() > 0 and uv[:, 0].max() < camera.width
    assert uv[:, 1].min() > 0 and uv[:, 1].max() < camera.height
    # the near edge (x_min) is lower in the image than the far edge
    n = (len(uv) - 1) // 4
    assert uv[0, 1] > uv[n, 1]


def test_band_centres_are_15_increasing_distances_inside_the_grid() -> None:
    centres = band_centres_m(GRID)
    assert centres.shape == (15,)
    assert np.all(np.diff(centres) > 0)
    assert GRID.x_min < centres[0] < centres[-1] < GRID.x_max


def test_report_refuses_no_frames(tmp_path: Path) -> None:
    data = _data(1)
    data.frames = []
    with pytest.raises(ReportError):
        write_report(data, tmp_path)


def test_mask_runs_are_the_rows_runs_of_set_cells() -> None:
    mask = np.zeros((3, 6), bool)
    mask[0, 1:3] = True
    mask[0, 4] = True
    mask[2, :] = True
    assert mask_runs(mask) == [(0, 1, 3), (0, 4, 5), (2, 0, 6)]
    assert mask_runs(np.zeros((2, 2), bool)) == []


def test_frames_figure_hatches_hidden_cells_shows_sigma_and_dots_confidently_wrong_cells(
    tmp_path: Path, saved_figures: list[Any],
) -> None:
    frame = _data(1).frames[0]
    assert frame.truth is not None
    estimate = frame.truth.copy()
    estimate[10, 5:9] += 0.05  # 5 cm off at sigma 3 mm: confidently wrong
    estimate[20, 5] += 0.005  # 5 mm off: beyond 3 sigma but under 1 cm, not counted
    sigma = np.full(GRID.shape, 0.003, np.float32)
    hidden = np.zeros(GRID.shape, bool)
    hidden[30:34, 10:20] = True  # 4 runs of 10 cells
    hidden[40, 0] = True
    plot_frames([replace(frame, estimate=estimate, sigma=sigma, hidden=hidden)], GRID, tmp_path / "f.png")
    (fig,) = saved_figures
    titles = [ax.get_title() for ax in fig.axes]
    assert "ground truth\n41 cells hidden" in titles and "1-sigma" in titles
    assert "residual GT - est.\n4 confidently wrong" in titles
    hatched = [c for ax in fig.axes for c in ax.collections if c.get_gid() == "hidden"]
    assert len(hatched) == 4  # GT, estimate, residual, sigma
    for collection in hatched:
        assert collection.get_hatch() == "////"
        assert len(collection.get_paths()) == 5
        # the boxes (data coordinates: y, x in metres) cover exactly the 41 hidden cells
        area = sum(float(np.prod(np.ptp(p.vertices, axis=0))) for p in collection.get_paths())
        assert area == pytest.approx(41 * GRID.resolution**2, rel=1e-6)
        lowest = min(float(p.vertices[:, 1].min()) for p in collection.get_paths())
        assert lowest == pytest.approx(GRID.x_max - 41 * GRID.resolution)  # row 40's near edge
    (dots,) = [c for ax in fig.axes for c in ax.collections if c.get_gid() == "confidently_wrong"]
    offsets = np.asarray(dots.get_offsets())
    assert offsets.shape == (4, 2)
    np.testing.assert_allclose(offsets[:, 1], GRID.x_centres()[10])  # row 10's distance
    np.testing.assert_allclose(sorted(offsets[:, 0]), sorted(GRID.y_centres()[5:9]))


def test_frames_figure_without_sigma_or_visibility_keeps_three_maps(tmp_path: Path, saved_figures: list[Any]) -> None:
    plot_frames(_data(1).frames, GRID, tmp_path / "f.png")
    (fig,) = saved_figures
    assert [ax.get_title() for ax in fig.axes if ax.images][1:] == ["ground truth", "estimate", "residual GT - est."]
    assert not [c for ax in fig.axes for c in ax.collections if c.get_gid() in ("hidden", "confidently_wrong")]


def test_frames_figure_refuses_a_sigma_off_the_grid(tmp_path: Path) -> None:
    frame = replace(_data(1).frames[0], sigma=np.zeros((3, 3), np.float32))
    with pytest.raises(ReportError, match="sigma"):
        plot_frames([frame], GRID, tmp_path / "f.png")


def _curve(scale: float) -> list[dict[str, Any]]:
    return [{"sigma_lo_cm": lo, "sigma_hi_cm": hi, "cells": cells, "mean_sigma_cm": 0.5 * (lo + hi),
             "q68_abs_err_cm": scale * 0.5 * (lo + hi), "q95_abs_err_cm": scale * (lo + hi)}
            for lo, hi, cells in ((0.1, 0.2, 400), (0.2, 0.3, 900), (0.5, 0.75, 60), (1.0, 1.5, 10))]


def test_the_report_draws_the_reliability_plot_and_the_sigma_columns(tmp_path: Path) -> None:
    data = _data(1)
    sigma_keys = {"within_2sigma_pct": 95.25, "confident_wrong_pct": 0.125, "mean_sigma_cm": 0.4321}
    data.runs = [replace(r, metrics={**r.metrics, **sigma_keys, "reliability": _curve(1.0 + k)})
                 for k, r in enumerate(data.runs)]
    files = write_report(data, tmp_path)
    assert "reliability.png" in files
    img = mpimg.imread(files["reliability.png"])
    assert float(img[..., :3].std()) > 0.05
    page = (tmp_path / "index.html").read_text()
    assert 'src="reliability.png"' in page
    assert "within 2σ (%)" in page and "confidently wrong (%)" in page and "mean σ (cm)" in page
    assert "95.2" in page and "0.12" in page and "0.432" in page
    assert "reliability.png" in json.loads((tmp_path / "report.json").read_text())["figures"]


def test_the_report_leaves_the_reliability_plot_out_without_a_curve_and_says_why_when_too_few_cells(
    tmp_path: Path,
) -> None:
    files = write_report(_data(1), tmp_path / "none")
    assert "reliability.png" not in files  # the runs report no sigma
    assert "within 2σ" in (tmp_path / "none" / "index.html").read_text()  # the column, empty ("–")
    data = _data(1)
    sparse = [dict(b, cells=10) for b in _curve(1.0)]
    data.runs = [replace(r, metrics={**r.metrics, "reliability": sparse}) for r in data.runs]
    files = write_report(data, tmp_path / "sparse")
    assert "reliability.png" not in files
    assert "No reliability plot: no reliability curve has a sigma bin with 50 cells or more." in (
        tmp_path / "sparse" / "index.html").read_text()


def test_preview_figure_shades_the_hidden_stretches_of_a_track(tmp_path: Path, saved_figures: list[Any]) -> None:
    frame = _data(1).frames[0]
    (gt,) = frame.truth_tracks
    hidden = np.zeros(gt.distance_m.size, bool)
    hidden[10:20] = True
    hidden[40:42] = True
    plot_preview([replace(frame, truth_tracks=(replace(gt, hidden=hidden),))], tmp_path / "p.png")
    (ax,) = saved_figures[0].axes
    spans = [p for p in ax.patches if p.get_gid() == "hidden" and isinstance(p, Rectangle)]
    assert len(spans) == 2
    xs = sorted((s.get_x(), s.get_x() + s.get_width()) for s in spans)
    step = float(abs(gt.distance_m[1] - gt.distance_m[0]))
    d = np.sort(gt.distance_m[hidden])
    assert xs[0] == pytest.approx((d[0] - step / 2, d[9] + step / 2))
    assert xs[1] == pytest.approx((d[10] - step / 2, d[11] + step / 2))
    legend = ax.get_legend()
    assert legend is not None and "hidden from the cameras (GT)" in [t.get_text() for t in legend.get_texts()]


def test_preview_figure_without_hidden_samples_has_no_span(tmp_path: Path, saved_figures: list[Any]) -> None:
    plot_preview(_data(1).frames, tmp_path / "p.png")
    (ax,) = saved_figures[0].axes
    assert not [p for p in ax.patches if p.get_gid() == "hidden"]
    legend = ax.get_legend()
    assert legend is not None and "hidden from the cameras (GT)" not in [t.get_text() for t in legend.get_texts()]
