"""The error budget's machinery: candidates from node results, the node's schedule, estimates
shared by the rows, truth put into one stage, stored drive frames."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from benchmarks.preview_budget import (
    FAR_STAGES,
    LABEL_STAGES,
    STAGES,
    CachedEstimates,
    Candidate,
    DriveFrames,
    PacedEstimates,
    budgeted,
    candidate_previews,
    candidates_from_node,
    far_label_grid,
    label_features,
    node_rows,
    node_schedule,
    parse_candidate,
    parse_charges,
    short_band,
    stages_of,
    with_true_plane,
)
from roadbev_core.config import FarFieldConfig, GridSpec, RoadbevConfig
from roadbev_core.frame import Estimate
from roadbev_lab.evaluation.arrival import REFERENCE_CONTACT_PLANE, ArrivalSettings, Trajectory
from roadbev_lab.ride import RideSettings, perfect_map_previews
from roadbev_lab.synth import DriveConfig, RidingConfig, RidingDrive, RoadConfig

MS = 1_000_000


def test_the_node_fuses_the_newest_waiting_frame_and_its_previews_come_later() -> None:
    stamps = [k * 100 * MS for k in range(6)]  # a 10 Hz camera
    assert node_schedule(stamps, 0.08, 0.1) == [(k, stamps[k] + 100 * MS, False) for k in range(6)]  # keeps up
    # 250 ms a frame: frame 0; frame 1 waiting is replaced by frame 2, which starts when the node
    # is free at 250 ms; then frames 3 and 4 are replaced by frame 5, arriving as the node is free
    slow = node_schedule(stamps, 0.25, 0.1)
    assert [i for i, _, _ in slow] == [0, 2, 5]
    assert slow[1] == (2, 250 * MS + 100 * MS, False)  # waited 50 ms for the node, then the latency
    assert slow[2] == (5, 500 * MS + 100 * MS, False)


def test_a_paced_node_hands_the_frames_to_the_pace_backend_once_the_chosen_one_is_too_slow() -> None:
    stamps = [k * 100 * MS for k in range(8)]  # a 10 Hz camera
    # the chosen backend takes 150 ms a frame: frame 0 measures it (frame 1 waits 50 ms, frame 2
    # 10 ms), then the pace backend (60 ms a frame, 70 ms latency) answers every frame on arrival
    schedule = node_schedule(stamps, 0.15, 0.16, pace=(0.07, 0.06), pace_load=0.9)
    assert schedule[0] == (0, 160 * MS, False)
    assert schedule[1] == (1, 150 * MS + 70 * MS, True)
    assert schedule[2] == (2, 210 * MS + 70 * MS, True)
    assert schedule[3:] == [(k, stamps[k] + 70 * MS, True) for k in range(3, 8)]
    # allowed two periods a frame, the chosen backend answers (and falls behind)
    assert not any(paced for _, _, paced in node_schedule(stamps, 0.15, 0.16, pace=(0.07, 0.06), pace_load=2.0))
    # a fast one is never paced
    assert not any(paced for _, _, paced in node_schedule(stamps, 0.05, 0.06, pace=(0.07, 0.06), pace_load=0.9))


def test_at_speed_the_pace_backend_answers_frames_the_chosen_one_keeps_up_with() -> None:
    stamps = [k * 200 * MS for k in range(6)]  # a 5 Hz camera; the chosen backend's 125 ms a frame fit it
    kept_up = node_schedule(stamps, 0.125, 0.13, pace=(0.08, 0.07), pace_load=0.9, pace_lead_m=0.5,
                            speed_mps=10.0)  # 10 m/s x 125 ms: 1.25 m against a free pace backend
    # frame 1 measures the pace backend (55 ms less a frame: 0.55 m), which then keeps answering
    assert [paced for _, _, paced in kept_up] == [False] + [True] * 5
    assert kept_up[1] == (1, stamps[1] + 80 * MS, True)
    slow_pace = node_schedule(stamps, 0.125, 0.13, pace=(0.11, 0.10), pace_load=0.9, pace_lead_m=0.5,
                              speed_mps=10.0)  # 25 ms less a frame: 0.25 m, the chosen backend takes over again
    assert [paced for _, _, paced in slow_pace] == [False, True, False, False, False, False]
    for off in ({"pace_lead_m": 0.0, "speed_mps": 30.0}, {"pace_lead_m": 0.5, "speed_mps": None}):
        assert not any(paced for _, _, paced in node_schedule(stamps, 0.125, 0.13, pace=(0.08, 0.07),
                                                               pace_load=0.9, **off))


def test_a_paced_candidate_takes_its_pace_backends_row_and_never_a_paced_row() -> None:
    chosen = {"backend": "ensemble", "mode": "5hz", "latency_ms": {"p50": 180.0},
              "latency_on_arrival_ms": {"p50": 125.0}, "inference_p50_ms": 100.0, "overhead_mean_ms": 25.0}
    paced = {**chosen, "latency_on_arrival_ms": {"p50": 80.0}, "paced_frames": 58}
    bm = {"backend": "bm", "mode": "5hz", "latency_ms": {"p50": 88.0}, "inference_p50_ms": 60.0,
          "overhead_mean_ms": 20.0}
    rows = node_rows([{"rows": [paced, chosen, bm], "node_params": {"far_field.enabled": True}}])
    unpaced, c = candidates_from_node(["far=ensemble:far_field.enabled=true",
                                       "far_paced=ensemble:far_field.enabled=true,pace_backend=bm"], rows)
    assert unpaced.pace is None and unpaced.pace_backend == ""
    assert unpaced.latency_s == pytest.approx(0.125)  # the paced row is skipped
    assert c.pace_backend == "bm" and c.pace == pytest.approx((0.088, 0.080))
    assert (c.latency_s, c.period_s) == pytest.approx((0.125, 0.125)) and c.pace_load == pytest.approx(0.9)
    pace = c.pace_candidate()
    assert (pace.backend, dict(pace.params), pace.pace) == ("bm", {"far_field.enabled": True}, None)
    # the pipeline of a candidate never paces itself: the node model does
    assert c.config(GridSpec()).backend.pace_backend == ""
    with pytest.raises(ValueError, match=r"its pace_backend.*no bench_node row with backend bm"):
        candidates_from_node(["far_paced=ensemble:far_field.enabled=true,pace_backend=bm"],
                             node_rows([{"rows": [chosen], "node_params": {"far_field.enabled": True}}]))
    # a pace backend given with options takes the row measured with them, and runs with them
    warped = {**bm, "backend": "bm:plane_parallax_px=16", "latency_ms": {"p50": 92.0}}
    rows = node_rows([{"rows": [chosen, bm, warped], "node_params": {"far_field.enabled": True}}])
    (w,) = candidates_from_node(["w=ensemble:far_field.enabled=true,pace_backend=bm:plane_parallax_px=16"], rows)
    assert w.pace_backend == "bm:plane_parallax_px=16" and w.pace == pytest.approx((0.092, 0.080))
    pace = w.pace_candidate()
    assert (pace.backend, dict(pace.params)) == ("bm", {"far_field.enabled": True, "bm.plane_parallax_px": 16})


def test_candidates_take_their_latency_and_period_from_the_node_row() -> None:
    assert parse_candidate("bev_sweep") == ("bev_sweep", "bev_sweep", {})
    name, backend, params = parse_candidate("fast=stereo:stereo.runtime=openvino,stereo.threads=2")
    assert (name, backend, params) == ("fast", "stereo", {"stereo.runtime": "openvino", "stereo.threads": 2})
    with pytest.raises(ValueError):
        parse_candidate("x=stereo:runtime")
    rows = [{"backend": "stereo:runtime=openvino", "mode": "max", "latency_ms": {"p50": 80.0},
             "inference_p50_ms": 60.0, "overhead_mean_ms": 5.0},
            {"backend": "stereo:runtime=openvino", "mode": "5hz", "latency_ms": {"p50": 110.0},
             "inference_p50_ms": 90.0, "overhead_mean_ms": 5.0},
            {"backend": "stereo", "mode": "5hz", "latency_ms": {"p50": 300.0}, "inference_p50_ms": 280.0,
             "overhead_mean_ms": 5.0}]
    rows = node_rows([{"rows": rows, "node_params": {"far_field.enabled": True}}])
    (c,) = candidates_from_node(["int8=stereo:stereo.runtime=openvino"], rows)
    assert (c.name, c.backend) == ("int8", "stereo")
    assert c.latency_s == pytest.approx(0.11) and c.period_s == pytest.approx(0.095)
    assert candidates_from_node(["stereo"], rows)[0].latency_s == pytest.approx(0.3)
    with pytest.raises(ValueError, match="no bench_node row"):
        candidates_from_node(["bm"], rows)


def test_a_candidate_without_far_field_enabled_takes_the_row_of_its_default() -> None:
    """A candidate that leaves far_field.enabled out costs what the default costs; a result that
    does not name it (written before bench_node named it in every result) ran it off."""
    assert RoadbevConfig().far_field.enabled
    grid_only = {"backend": "bm", "mode": "5hz", "latency_ms": {"p50": 70.0}, "inference_p50_ms": 55.0,
                 "overhead_mean_ms": 10.0}
    far = {**grid_only, "latency_ms": {"p50": 90.0}}
    unnamed = node_rows([{"rows": [grid_only]}])
    named = node_rows([{"rows": [far], "node_params": {"far_field.enabled": True}}])
    (default,) = candidates_from_node(["bm"], named + unnamed)
    assert default.latency_s == pytest.approx(0.090)
    (off,) = candidates_from_node(["bm_near=bm:far_field.enabled=false"], named + unnamed)
    assert off.latency_s == pytest.approx(0.070)
    with pytest.raises(ValueError, match="no bench_node row"):
        candidates_from_node(["bm"], unnamed)


def test_a_candidate_is_charged_its_latency_on_arrival_the_schedule_adding_the_waits() -> None:
    """A node slower than the camera: its end-to-end p50 holds the frames' waits for the node,
    which node_schedule adds itself; the row's latency on arrival is charged instead."""
    slow = {"backend": "ensemble", "mode": "5hz", "latency_ms": {"p50": 180.0}, "latency_on_arrival_ms": {"p50": 130.0},
            "inference_p50_ms": 100.0, "overhead_mean_ms": 25.0}
    (c,) = candidates_from_node(["ensemble"], node_rows([{"rows": [slow], "node_params": {"far_field.enabled": True}}]))
    assert c.latency_s == pytest.approx(0.130) and c.period_s == pytest.approx(0.125)
    stamps = [k * 100 * MS for k in range(4)]
    # frame 1 arrives at 100 ms while the node is busy until 125 ms: received 25 ms later than on arrival
    schedule = node_schedule(stamps, c.period_s, c.latency_s)
    assert schedule[:2] == [(0, 130 * MS, False), (1, 255 * MS, False)]


def test_a_stated_charge_replaces_the_node_row() -> None:
    charges = parse_charges(["far=61/61.5", "bm_far=61/61"])
    assert sorted(charges) == ["bm_far", "far"]
    assert charges["far"] == pytest.approx((0.061, 0.0615)) and charges["bm_far"] == pytest.approx((0.061, 0.061))
    far, bm_far = candidates_from_node(["far=ensemble:far_field.enabled=true", "bm_far=bm:far_field.enabled=true"],
                                       node_rows([]), charges)  # no node row needed
    assert far.backend == "ensemble" and (far.latency_s, far.period_s) == pytest.approx((0.061, 0.0615))
    assert (bm_far.backend, dict(bm_far.params)) == ("bm", {"far_field.enabled": True})
    with pytest.raises(ValueError, match="no candidate named other"):
        candidates_from_node(["far=ensemble"], node_rows([]), parse_charges(["far=1/1", "other=1/1"]))
    for bad in ("far", "far=61", "far=61/x", "far=0/61", "=61/61", "far=nan/61"):
        with pytest.raises(ValueError, match="NAME=LATENCY_MS/PERIOD_MS"):
            parse_charges([bad])
    with pytest.raises(ValueError, match="charged twice"):
        parse_charges(["far=1/1", "far=2/2"])


def test_far_field_candidates_take_the_row_of_a_run_with_the_far_field() -> None:
    near = {"backend": "ensemble", "mode": "5hz", "latency_ms": {"p50": 75.0}, "inference_p50_ms": 55.0,
            "overhead_mean_ms": 5.0}
    far = {**near, "latency_ms": {"p50": 89.0}, "overhead_mean_ms": 19.0}
    rows = node_rows([{"rows": [near]}, {"rows": [far], "node_params": {"far_field.enabled": True}}])
    plain, with_far = candidates_from_node(["near=ensemble:far_field.enabled=false",
                                           "far=ensemble:far_field.enabled=true"], rows)
    assert plain.latency_s == pytest.approx(0.075) and plain.period_s == pytest.approx(0.060)
    assert with_far.latency_s == pytest.approx(0.089) and with_far.period_s == pytest.approx(0.074)
    # the preview's parameters cost nothing in the node: the row of the same far field serves
    (gapless,) = candidates_from_node(["g=ensemble:preview.max_gap_m=0"], rows)
    assert gapless.latency_s == pytest.approx(0.089)
    with pytest.raises(ValueError, match="no bench_node row"):
        candidates_from_node(["far=ensemble:far_field.enabled=true"], node_rows([{"rows": [near]}]))


def test_drives_label_the_far_grid_of_the_budgeted_far_field_candidates_only() -> None:
    grid = GridSpec()
    far = Candidate("far", "ensemble", {"far_field.enabled": True}, latency_s=0.1)
    near = Candidate("near", "bm", {"far_field.enabled": False}, latency_s=0.1)
    assert budgeted("far", []) and budgeted("far", ["far"]) and not budgeted("far", ["near"])
    assert not budgeted("far", None)
    assert far_label_grid([near, far], [], grid) == FarFieldConfig().grid(grid)
    assert far_label_grid([near, far], ["near"], grid) is None  # the far candidate is not budgeted
    assert far_label_grid([near, far], None, grid) is None
    other = Candidate("far12", "bm", {"far_field.enabled": True, "far_field.x_max": 12.12}, latency_s=0.1)
    with pytest.raises(ValueError, match="different far-field grids"):
        far_label_grid([far, other], [], grid)


def test_cached_estimates_build_the_same_backend_on_another_grid_once() -> None:
    built: list[GridSpec] = []

    class Inner:
        name, needs_stereo, far_field = "stub", False, True

        def __init__(self, grid: GridSpec) -> None:
            self.grid = grid
            built.append(grid)

        def estimate(self, frame: Any) -> Any:
            return SimpleNamespace(grid=self.grid)

    near, far = GridSpec(), FarFieldConfig().grid(GridSpec())
    cached = CachedEstimates(Inner(near), Inner)
    assert cached.on_grid(near) is cached and cached.far_field
    on_far = cached.on_grid(far)
    assert on_far is cached.on_grid(far) and on_far.grid == far and built == [near, far]
    with pytest.raises(ValueError, match="no backend on the grid"):
        CachedEstimates(Inner(near)).on_grid(far)


def test_cached_estimates_run_each_frame_once() -> None:
    calls: list[int] = []

    class Inner:
        name, grid, needs_stereo = "stub", GridSpec(), False

        def estimate(self, frame: Any) -> Any:
            calls.append(frame.stamp_ns)
            return SimpleNamespace(stamp=frame.stamp_ns)

    cached = CachedEstimates(Inner())
    for stamp in (1, 2, 1, 2, 3):
        estimate: Any = cached.estimate(SimpleNamespace(stamp_ns=stamp))  # type: ignore[arg-type]
        assert estimate.stamp == stamp
    assert calls == [1, 2, 3]


def _small_drive(frames: int = 6) -> RidingDrive:
    from roadbev_core.config import StereoCamera

    road = RoadConfig(road_class="B", features=("speed_bump",), feature_spacing_m=4.0)
    camera = StereoCamera.rsrd_half().scaled(0.25)
    return RidingDrive(RidingConfig(drive=DriveConfig(frames=frames, speed_mps=10.0, frame_rate_hz=10.0, seed=5,
                                                      road=road, camera=camera), tail_s=1.5))


class Noisy:
    """A backend that answers the drive's own labels with a 1 cm ripple along the road, left half
    of the grid only."""

    name, needs_stereo = "bm", True

    def __init__(self, grid: GridSpec, labels: dict[int, np.ndarray]) -> None:
        self.grid, self.labels = grid, labels

    def estimate(self, frame: Any) -> Estimate:
        rows = np.arange(self.grid.n_rows)[:, None]
        e = self.labels[int(frame.stamp_ns)] + 0.01 * np.sin(rows / 4.0)
        e[:, e.shape[1] // 2:] = np.nan
        return Estimate(e.astype(np.float32), np.where(np.isfinite(e), 0.004, np.nan).astype(np.float32))


def test_stored_frames_read_back_and_truth_goes_into_one_stage(tmp_path: Any) -> None:
    drive = _small_drive()
    store = DriveFrames(tmp_path)
    samples = store.samples(drive)
    again = store.samples(drive)  # read back, not rendered
    assert len(again) == len(drive) and len(list(store.folder(drive).glob("*.npz"))) == len(drive)
    for a, b in zip(samples, again, strict=True):
        np.testing.assert_array_equal(a.frame.left, b.frame.left)
        np.testing.assert_array_equal(a.truth.elevation, b.truth.elevation)
        assert a.frame.attitude == b.frame.attitude and a.frame.stamp_ns == b.frame.stamp_ns
    labels = {int(s.frame.stamp_ns): s.truth.elevation.copy() for s in samples}
    cached = CachedEstimates(Noisy(drive.config.grid, labels))
    candidate = Candidate("noisy", "bm", {"far_field.enabled": False}, latency_s=0.1, period_s=0.0)
    grid = drive.config.grid
    settings = RideSettings(arrival=ArrivalSettings(base_height=grid.base_height, camera_in_base=drive.base_to_camera))
    assert stages_of(candidate, grid) == tuple(s for s in STAGES if s not in FAR_STAGES)
    out = {stage: candidate_previews(drive, samples, candidate, cached, stage, ride_settings=settings)
           for stage in stages_of(candidate, grid)}
    assert len(cached.estimates) == len(drive)  # every stage used the same estimate of a frame
    for stage, previews in out.items():
        assert len(previews) == len(drive), stage
        assert all(p.reference == REFERENCE_CONTACT_PLANE for p in previews)
        delay = 0 if stage == "no_latency" else 100 * MS
        assert all(p.received_ns == p.stamp_ns + delay for p in previews)

    def right_known(stage: str) -> int:
        return int(sum(np.isfinite(p.profiles.track("front_right").elevation).sum() for p in out[stage]))

    def left_apart(a: str, b: str) -> float:  # mean |difference| of the left profiles, message by message
        diffs = [p.profiles.track("front_left").elevation - q.profiles.track("front_left").elevation
                 for p, q in zip(out[a], out[b], strict=True)]
        return float(np.nanmean(np.abs(np.concatenate(diffs))))

    # the labels with a ripple on the left only: the truth on the answered cells is the labels
    # there (no ripple); on every cell, the right track appears as well
    assert right_known("shipped") == right_known("true_answered") == 0 < right_known("true_all")
    assert left_apart("shipped", "true_answered") > 0.003
    assert left_apart("true_answered", "true_all") < 0.001
    # the ripple is shorter than a metre: the truth's short band takes most of it away, and the
    # cells off the bumps carry most of it
    assert left_apart("true_short", "true_answered") < 0.5 * left_apart("shipped", "true_answered")
    assert left_apart("true_surface", "true_answered") < left_apart("true_features", "true_answered")
    with pytest.raises(ValueError, match="unknown budget stage"):
        candidate_previews(drive, samples, candidate, cached, "true_everything", ride_settings=settings)
    for stage in FAR_STAGES:  # they change a far field, which this candidate has not
        with pytest.raises(ValueError, match="has none"):
            candidate_previews(drive, samples, candidate, cached, stage, ride_settings=settings)


def test_a_paced_candidate_fuses_the_pace_backends_estimate_on_the_frames_the_node_model_paced(tmp_path: Any
                                                                                              ) -> None:
    drive = _small_drive()
    samples = DriveFrames(tmp_path).samples(drive)
    labels = {int(s.frame.stamp_ns): s.truth.elevation.copy() for s in samples}
    grid = drive.config.grid

    class Offset(Noisy):
        name = "sgbm"

        def estimate(self, frame: Any) -> Estimate:
            out = super().estimate(frame)
            return Estimate(out.elevation + np.float32(0.05), out.uncertainty)

    chosen, pace = CachedEstimates(Offset(grid, labels)), CachedEstimates(Noisy(grid, labels))
    paced = PacedEstimates(chosen, pace)
    assert paced.on_grid(grid) is paced and (paced.name, paced.grid) == ("sgbm", grid)
    # 150 ms a frame at a 10 Hz camera: the chosen backend answers the first frame, the pace one the rest
    candidate = Candidate("paced", "sgbm", {"far_field.enabled": False, "pace_backend": "bm"}, latency_s=0.16,
                          period_s=0.15, pace=(0.07, 0.06))
    settings = RideSettings(arrival=ArrivalSettings(base_height=grid.base_height, camera_in_base=drive.base_to_camera))
    previews = candidate_previews(drive, samples, candidate, paced, "shipped", ride_settings=settings)
    stamps = sorted(labels)
    assert paced.paced == set(stamps[1:])
    assert sorted(chosen.estimates) == stamps[:1] and sorted(pace.estimates) == stamps[1:]
    assert [(p.received_ns or 0) - p.stamp_ns for p in previews] == [160 * MS, 120 * MS, 80 * MS] + [70 * MS] * 3
    # no latency: every frame at its stamp, by the chosen backend
    candidate_previews(drive, samples, candidate, paced, "no_latency", ride_settings=settings)
    assert paced.paced == set() and sorted(chosen.estimates) == stamps


def test_perfect_map_previews_are_unchanged_against_the_true_plane() -> None:
    drive = _small_drive(3)
    gt = drive.ground_truth_poses()
    truth = Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw)
    grid = drive.config.grid
    settings = RideSettings(arrival=ArrivalSettings(base_height=grid.base_height, camera_in_base=drive.base_to_camera))
    road_map = drive.road_map()
    perfect = perfect_map_previews(truth, road_map, drive.frame_stamps_ns, GridSpec(), settings)
    # perfect previews carry no plane: give each its true one, as a message would
    from dataclasses import replace

    from benchmarks.preview_budget import ContactPlane

    flat = [replace(p, profiles=replace(p.profiles, reference=REFERENCE_CONTACT_PLANE,
                                        contact_plane=ContactPlane(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
            for p in perfect]
    again = with_true_plane(flat, truth, road_map, settings)
    for a, b in zip(flat, again, strict=True):
        plane = b.profiles.contact_plane
        assert plane is not None
        for ta, tb in zip(a.profiles.tracks, b.profiles.tracks, strict=True):
            x = a.profiles.distances()
            # re-read against the true plane: the profile moves by the plane's tilt, nothing else
            diff = (tb.elevation - ta.elevation) + plane.height_at(x, np.full(x.size, ta.lateral_offset))
            ok = np.isfinite(diff)
            assert np.ptp(diff[ok]) < 1e-5


class Flat:
    """A backend that answers a flat road (0 m, sigma 1 cm) on every cell of whatever grid it is on."""

    name, needs_stereo, far_field = "bm", True, True

    def __init__(self, grid: GridSpec) -> None:
        self.grid = grid

    def estimate(self, frame: Any) -> Estimate:
        return Estimate(np.zeros(self.grid.shape, np.float32), np.full(self.grid.shape, 0.01, np.float32))


def test_a_labels_features_are_what_stands_off_the_road_around_them() -> None:
    grid = GridSpec()
    x = grid.x_centres()  # [R]
    label = np.repeat((0.01 * x)[:, None], grid.n_cols, axis=1)  # a grade: no feature
    assert not label_features(label, grid.resolution).any()
    bump = np.abs(x - 4.5) < 0.15  # a 5 cm bump 0.3 m long across the road
    label[bump] += 0.05
    label[:, :3] = np.nan
    features = label_features(label, grid.resolution)
    assert features[bump, 3:].all() and not features[:, :3].any()
    near = np.abs(x - 4.5) < 0.15 + 0.06 + 1e-6
    assert not features[~near].any()  # the bump and its margin only


def test_the_short_band_is_the_relief_shorter_than_a_metre() -> None:
    grid = GridSpec()
    x = grid.x_centres()[:, None]  # [R, 1]
    ripple = 0.004 * np.sin(2 * np.pi * x / 0.3)
    ramp = 0.02 * x
    band = short_band(np.repeat(ramp + ripple, 4, axis=1), grid.resolution)
    inner = slice(20, -20)  # a metre's mean is whole away from the edges
    np.testing.assert_allclose(band[inner], np.repeat(ripple, 4, axis=1)[inner], atol=0.0012)


def _with_far_grid(drive: RidingDrive) -> RidingDrive:
    from dataclasses import replace

    far_grid = FarFieldConfig().grid(drive.config.grid)
    return RidingDrive(replace(drive.riding, drive=replace(drive.riding.drive, far_grid=far_grid)))


def test_a_far_field_candidate_previews_to_the_far_edge_and_its_label_stages_take_the_far_truth(tmp_path: Any
                                                                                                ) -> None:
    drive = _small_drive(4)
    samples = DriveFrames(tmp_path).samples(drive)
    grid = drive.config.grid
    cached = CachedEstimates(Flat(grid), Flat)
    settings = RideSettings(arrival=ArrivalSettings(base_height=grid.base_height, camera_in_base=drive.base_to_camera))
    far = Candidate("far", "bm", {"far_field.enabled": True}, latency_s=0.1)
    near = Candidate("near", "bm", {"far_field.enabled": False}, latency_s=0.1)

    def reach(previews: list[Any]) -> float:  # farthest answered distance ahead of base_link (m)
        return max(float(p.profiles.distances()[np.isfinite(p.profiles.track("front_left").elevation)].max())
                   for p in previews)

    camera_x = float(drive.base_to_camera[0][0])
    far_edge = FarFieldConfig().grid(grid).x_max
    with_far = candidate_previews(drive, samples, far, cached, "shipped", ride_settings=settings)
    without = candidate_previews(drive, samples, near, cached, "shipped", ride_settings=settings)
    assert reach(without) <= camera_x + grid.x_max + 1e-6
    assert reach(with_far) > camera_x + grid.x_max + 1.0 and reach(with_far) <= camera_x + far_edge + 1e-6
    assert len(cached.on_grid(FarFieldConfig().grid(grid)).estimates) == len(drive)  # the far grid's own cache
    for stage in LABEL_STAGES:  # frames rendered without the far grid's labels
        with pytest.raises(ValueError, match="far field's labels"):
            candidate_previews(drive, samples, far, cached, stage, ride_settings=settings)
    # rendered with them, the far field's truth enters its label stages: beyond the grid the flat
    # estimate gives way to the true road's relief
    far_samples = DriveFrames(tmp_path).samples(_with_far_grid(drive))
    assert all(s.far_truth is not None for s in far_samples)
    true_all = candidate_previews(drive, far_samples, far, cached, "true_all", ride_settings=settings)

    def beyond_grid(previews: list[Any]) -> np.ndarray:
        parts = []
        for p in previews:
            x = p.profiles.distances()
            parts.append(p.profiles.track("front_left").elevation[(x > camera_x + grid.x_max + 0.5)])
        return np.concatenate(parts)

    shipped_far, true_far = beyond_grid(with_far), beyond_grid(true_all)
    both = np.isfinite(shipped_far) & np.isfinite(true_far)
    assert both.sum() > 20 and np.abs(shipped_far - true_far)[both].max() > 1e-3
    # the far stages change the far field's estimates alone, the grid's stay the shipped ones:
    # beyond the grid true_far takes the truth's relief (as true_all's there) and far_error_halved
    # lies about halfway between it and the shipped previews
    assert stages_of(far, grid) == STAGES
    far_only = {stage: candidate_previews(drive, far_samples, far, cached, stage, ride_settings=settings)
                for stage in FAR_STAGES}
    assert len(cached.estimates) == len(drive)  # the grid's estimates made once, as shipped
    beyond_true, beyond_half = beyond_grid(far_only["true_far"]), beyond_grid(far_only["far_error_halved"])
    assert np.abs(beyond_true - shipped_far)[both].max() > 1e-3
    # (about halfway: the map's alignment and weights see the halved sigmas as well)
    off = np.median(np.abs(beyond_half - beyond_true)[both]) / np.median(np.abs(shipped_far - beyond_true)[both])
    assert 0.35 < off < 0.65


def test_stored_frames_gain_far_field_labels_without_changing_and_keep_them(tmp_path: Any) -> None:
    drive = _small_drive(2)
    store = DriveFrames(tmp_path)
    plain = store.samples(drive)
    assert all(s.far_truth is None for s in plain)
    with_far = _with_far_grid(drive)
    added = store.samples(with_far)  # rendered again for the far labels, stored with them
    again = store.samples(with_far)  # read back
    far_grid = with_far.config.far_grid
    assert far_grid is not None
    for a, b, c in zip(plain, added, again, strict=True):
        np.testing.assert_array_equal(a.frame.left, b.frame.left)
        np.testing.assert_array_equal(a.truth.elevation, c.truth.elevation)
        assert b.far_truth is not None and c.far_truth is not None and c.far_truth.elevation.shape == far_grid.shape
        np.testing.assert_array_equal(b.far_truth.elevation, c.far_truth.elevation)
        assert np.isfinite(c.far_truth.elevation).any()
    assert all(s.far_truth is None for s in store.samples(drive))  # not asked for, not given
    # a stored frame the renderer no longer draws is refused, not mixed with new labels
    first = store.folder(drive) / "00000.npz"
    with np.load(first) as data:
        arrays = {k: data[k] for k in ("left", "right", "truth")}
    arrays["left"] = arrays["left"] + 1
    np.savez(first, **arrays)
    with pytest.raises(ValueError, match="not the one the renderer draws now"):
        store.samples(with_far)


def test_stored_frames_are_the_same_with_a_far_field_grid(tmp_path: Any) -> None:
    from dataclasses import replace

    drive = _small_drive(2)
    with_far = RidingDrive(replace(drive.riding, drive=replace(drive.riding.drive,
                                                               far_grid=FarFieldConfig().grid(drive.config.grid))))
    store = DriveFrames(tmp_path)
    assert store.folder(with_far) == store.folder(drive)
    other = RidingDrive(replace(drive.riding, drive=replace(drive.riding.drive, seed=6)))
    assert store.folder(other) != store.folder(drive)
