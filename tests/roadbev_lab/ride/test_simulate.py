"""The pure simulation: preview sources over a drive's true road, perfect previews, scoring."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_core.preview import PreviewProfiles, TrackProfile
from roadbev_core.ride import PreviewLqr, RideError
from roadbev_lab.evaluation.arrival import REFERENCE_CONTACT_PLANE, ArrivalSettings, RoadMap, TimedPreview
from roadbev_lab.ride import (
    RideSettings,
    gain_share,
    hidden_from,
    perfect_map_previews,
    perfect_previews,
    preview_feedforward,
    ride,
    true_plane_slopes,
    wheel_road,
)
from tests.roadbev_core.ride._roads import T0, S, bump_map, straight

SETTINGS = RideSettings(controller=PreviewLqr(dt=0.002), arrival=ArrivalSettings(base_height=1.10))


def _stamps(rate: float, first_s: float, last_s: float) -> list[int]:
    return [T0 + int(round(t * S)) for t in np.arange(first_s, last_s + 1e-9, 1.0 / rate)]


def test_wheel_road_follows_the_bump() -> None:
    truth, road_map = straight(10.0, 6.0), bump_map(0.05, at=20.0)
    road = wheel_road(truth, road_map, SETTINGS, "front_left", T0, T0 + 5 * S)
    # the front wheel is 2.8 m ahead of base_link: it meets the bump at x = 20 m after 1.72 s
    t_peak = (road.stamp_ns[np.argmax(road.height)] - T0) / S
    assert t_peak == pytest.approx((20.0 - 2.8) / 10.0, abs=0.01)
    assert road.height.max() == pytest.approx(0.05, rel=0.1)  # the patch mean smooths the crest a little
    assert road.xy[0, 1] == pytest.approx(0.8)
    with pytest.raises(RideError):
        wheel_road(truth, road_map, SETTINGS, "front_middle", T0, T0 + S)
    with pytest.raises(RideError):
        wheel_road(truth, road_map, SETTINGS, "front_left", T0, T0 + 10 * S)


def test_sources_rank_true_window_none_passive() -> None:
    truth, road_map = straight(10.0, 7.0), bump_map(0.06, at=30.0)
    stamps = _stamps(10.0, 0.05, 5.0)
    window = perfect_previews(truth, road_map, stamps, GridSpec(), SETTINGS)
    sources: dict[str, str | list[TimedPreview]] = {"passive": "passive", "none": "none", "true": "true",
                                                    "window": window, "late": window[:3]}
    out = ride(truth, road_map, sources, SETTINGS, stamps[0], T0 + 7 * S, stamps[-1] + S // 10)
    wk = {k: v["mean"]["wk_rms_mps2"] for k, v in out.items()}
    assert wk["true"] < wk["none"] < wk["passive"]
    share = gain_share(wk["none"], wk["true"], wk["window"])
    assert share > 0.9  # at 10 m/s the window sees the bump long enough before the wheel
    assert gain_share(wk["none"], wk["true"], wk["late"]) == pytest.approx(0.0, abs=0.02)  # old messages miss it
    assert out["window"]["mean"]["preview_coverage_pct"] > 95.0
    assert math.isnan(out["none"]["mean"]["preview_coverage_pct"])
    with pytest.raises(RideError):
        ride(truth, road_map, {"x": "oracle"}, SETTINGS, stamps[0], T0 + 6 * S)


def test_window_limits_the_preview_at_speed() -> None:
    # at 30 m/s the window (5.9 m ahead of the front wheel at the stamp, 3 m eaten by the latency) leaves
    # less than 0.1 s of preview: much of the ceiling's gain is out of reach
    truth, road_map = straight(30.0, 2.2), bump_map(0.04, at=45.0)
    stamps = _stamps(10.0, 0.05, 1.5)
    window = perfect_previews(truth, road_map, stamps, GridSpec(), SETTINGS)
    out = ride(truth, road_map, {"none": "none", "true": "true", "window": window}, SETTINGS, stamps[0],
               T0 + int(2.2 * S), stamps[-1] + S // 10)
    wk = {k: v["mean"]["wk_rms_mps2"] for k, v in out.items()}
    assert gain_share(wk["none"], wk["true"], wk["window"]) < 0.85


def test_reference_offsets_drop_out_and_nan_is_flat() -> None:
    truth, road_map = straight(10.0, 6.0), bump_map(0.05, at=20.0)
    road = wheel_road(truth, road_map, SETTINGS, "front_left", T0, T0 + 5 * S)
    stamps = _stamps(5.0, 0.05, 4.0)
    msgs = perfect_previews(truth, road_map, stamps, GridSpec(), SETTINGS)
    shifted = [replace(m, profiles=replace(m.profiles, tracks=tuple(
        TrackProfile(t.name, t.lateral_offset, t.width, t.elevation + np.float32(0.3 * i), t.uncertainty)
        for t in m.profiles.tracks))) for i, m in enumerate(msgs)]
    ff, covered = preview_feedforward(msgs, road, truth, SETTINGS)
    ff_shift, _ = preview_feedforward(shifted, road, truth, SETTINGS)
    assert np.abs(ff - ff_shift).max() < 1e-3 * np.abs(ff).max()  # each message's offset drops out
    assert covered[250:2000].mean() > 0.95  # 2 ms steps, from 0.5 s to the last message (4 s)
    empty = [replace(m, profiles=replace(m.profiles, tracks=tuple(
        TrackProfile(t.name, t.lateral_offset, t.width, np.full_like(t.elevation, np.nan), t.uncertainty)
        for t in m.profiles.tracks))) for m in msgs]
    ff_empty, covered_empty = preview_feedforward(empty, road, truth, SETTINGS)
    assert not ff_empty.any() and not covered_empty.any()


def test_contact_plane_preview_needs_its_attitude() -> None:
    # bumps every 3.7 m on a 1.7 % grade: the contact plane tilts whenever one axle is on a bump, and that
    # tilt reads as road in a contact-plane profile unless the plane's slope is undone (a constant grade alone
    # would only bias the force: the Wk weighting ignores a constant)
    truth, road_map = straight(10.0, 7.0), bump_map(0.05, at=tuple(20.0 + 3.7 * i for i in range(8)), grade=0.017)
    stamps = _stamps(10.0, 0.05, 5.0)
    msgs = perfect_map_previews(truth, road_map, stamps, GridSpec(), SETTINGS)
    assert all(m.reference == REFERENCE_CONTACT_PLANE for m in msgs)
    slopes = true_plane_slopes(truth, road_map, SETTINGS, stamps)
    assert slopes(msgs[0]) == pytest.approx((0.017, 0.0), abs=1e-4)
    assert slopes(TimedPreview(stamps[0] + 1000, msgs[0].reference, msgs[0].profiles)) == pytest.approx((0.017, 0.0),
                                                                                                       abs=1e-4)
    out = ride(truth, road_map, {"none": "none", "true": "true", "plane": msgs, "attitude": msgs}, SETTINGS,
               stamps[0], T0 + 7 * S, stamps[-1] + S // 10, plane_slopes={"attitude": slopes})
    wk = {k: v["mean"]["wk_rms_mps2"] for k, v in out.items()}
    assert gain_share(wk["none"], wk["true"], wk["attitude"]) > 0.95
    assert gain_share(wk["none"], wk["true"], wk["plane"]) < gain_share(wk["none"], wk["true"], wk["attitude"]) - 0.02


def test_gain_share() -> None:
    assert gain_share(2.0, 1.0, 1.5) == pytest.approx(0.5)
    assert gain_share(2.0, 1.0, 0.9) == pytest.approx(1.1)  # a preview may beat the ceiling's Wk
    assert math.isnan(gain_share(1.0, 1.0, 0.5))
    assert math.isnan(gain_share(1.0, 1.2, 0.5))


def test_perfect_previews_hold_the_true_road() -> None:
    truth, road_map = straight(10.0, 3.0), bump_map(0.05, at=6.0)
    grid = GridSpec()
    (msg,) = perfect_previews(truth, road_map, [T0], grid, SETTINGS)
    p: PreviewProfiles = msg.profiles
    assert p.start_distance == pytest.approx(grid.x_min + 0.5 * grid.resolution)
    left = np.asarray(p.track("left").elevation)
    # camera at x = 1.6, 1.1 m up, base_height 1.1: heights relative to the road at z = 0; the bump at x 6 m
    x_peak = p.distances()[np.argmax(left)] + 1.6
    assert x_peak == pytest.approx(6.0, abs=0.05)
    assert np.nanmin(left) == pytest.approx(0.0, abs=1e-6)


def _hidden_along(road_map: RoadMap, xs: np.ndarray) -> np.ndarray:
    points = np.stack([xs, np.zeros_like(xs), road_map.height(xs, np.zeros_like(xs))], axis=1)
    return hidden_from(np.array([1.6, 0.0, 1.1]), points, road_map)  # the camera of straight() at T0


def test_the_road_behind_a_rim_or_a_crest_is_hidden_from_the_camera() -> None:
    xs = np.arange(3.0, 14.0, 0.02)
    dip = _hidden_along(bump_map(-0.06, at=9.0, length=0.8), xs)
    assert not dip[(xs < 8.6) | (xs > 9.4)].any()  # the road before and after it is seen
    assert dip[(xs > 8.6) & (xs < 9.0)].any()  # the dip's near half lies behind its rim
    assert not dip[(xs > 9.05) & (xs < 9.4)].any()  # its far wall faces the camera
    bump = _hidden_along(bump_map(0.06, at=9.0, length=0.8), xs)
    assert not bump[xs < 9.0].any() and bump[(xs > 9.05) & (xs < 9.4)].any()  # its back side is hidden
    assert not _hidden_along(bump_map(0.0), xs).any()  # a flat road hides nothing


def test_a_visible_only_preview_bridges_what_the_camera_cannot_see() -> None:
    truth, road_map = straight(10.0, 3.0), bump_map(-0.06, at=9.0, length=0.8)
    grid = replace(GridSpec(), x_max=15.0)
    (whole,) = perfect_previews(truth, road_map, [T0], grid, SETTINGS)
    (seen,) = perfect_previews(truth, road_map, [T0], grid, SETTINGS, visible_only=True)
    x = whole.profiles.distances() + 1.6
    hidden = _hidden_along(road_map, x)
    assert hidden.any()
    for name in ("left", "right"):
        true = np.asarray(whole.profiles.track(name).elevation)
        got, sigma = np.asarray(seen.profiles.track(name).elevation), np.asarray(seen.profiles.track(name).uncertainty)
        np.testing.assert_array_equal(got[~hidden], true[~hidden])
        assert np.all(sigma[~hidden] == 0.0)
        assert np.isfinite(got[hidden]).all() and np.all(sigma[hidden] > 0.0)  # bridged: the gap is short
        assert np.all(got[hidden] > true[hidden])  # the line over the rim misses the dip's depth
    (unbridged,) = perfect_previews(truth, road_map, [T0], grid, SETTINGS, visible_only=True, max_gap_m=0.0)
    assert np.isnan(np.asarray(unbridged.profiles.track("left").elevation)[hidden]).all()


def test_a_wrong_preview_is_turned_down_by_its_measured_gain() -> None:
    truth, road_map = straight(10.0, 6.5), bump_map(0.06, at=(12.0, 20.0, 28.0, 36.0, 44.0, 52.0, 60.0))
    stamps = _stamps(10.0, 0.05, 5.5)
    window = perfect_previews(truth, road_map, stamps, GridSpec(), SETTINGS)
    inverted = [replace(m, profiles=replace(m.profiles, tracks=tuple(
        replace(t, elevation=-t.elevation) for t in m.profiles.tracks))) for m in window]  # bumps read as holes
    sources: dict[str, str | list[TimedPreview]] = {"none": "none", "true": "true", "window": window,
                                                    "inverted": inverted}
    end = T0 + int(6.5 * S)
    applied = ride(truth, road_map, sources, SETTINGS, stamps[0], end, stamps[-1])
    blind = ride(truth, road_map, sources, replace(SETTINGS, preview_gain=False), stamps[0], end, stamps[-1])
    wk = {k: v["mean"]["wk_rms_mps2"] for k, v in applied.items()}
    wk_blind = {k: v["mean"]["wk_rms_mps2"] for k, v in blind.items()}
    assert gain_share(wk_blind["none"], wk_blind["true"], wk_blind["inverted"]) < -0.5  # worse than none
    assert gain_share(wk["none"], wk["true"], wk["inverted"]) > -0.2  # the first bump teaches it
    assert gain_share(wk["none"], wk["true"], wk["window"]) == pytest.approx(
        gain_share(wk_blind["none"], wk_blind["true"], wk_blind["window"]), abs=0.02)  # a right one keeps its gain
    with pytest.raises(RideError):
        RideSettings(gain_time_constant_s=0.0)
