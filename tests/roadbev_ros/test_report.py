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

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude
from roadbev_ros.report import (
    FrameView,
    ReportData,
    ReportError,
    RunSummary,
    TimingTrace,
    TrackProfile,
    band_centres_m,
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


def test_frames_figure_keeps_the_bev_aspect(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each BEV map is 4.92 m x 1.92 m: its axes are about 2.56 times taller than wide."""
    from matplotlib.figure import Figure

    data = _data(1)
    captured: dict[str, Any] = {}
    original = Figure.savefig

    def grab(fig: Figure, *args: Any, **kwargs: Any) -> None:
        fig.canvas.draw()
        captured["boxes"] = [ax.get_window_extent() for ax in fig.axes if ax.images and ax.get_title() == "estimate"]
        original(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", grab)
    plot_frames(data.frames, GRID, tmp_path / "f.png")
    (box,) = captured["boxes"]
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
