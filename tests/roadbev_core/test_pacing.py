"""The pacer: the camera's period from set stamps, the chosen backend's cost, probes, resets."""

from __future__ import annotations

import pytest

from roadbev_core.pacing import MAX_INTERVAL_S, PROBE_EVERY, Pacer, stand_in


def _camera(pacer: Pacer, period_ms: int, sets: int = 10, start_s: float = 1000.0) -> float:
    arrival = start_s
    for _ in range(sets):
        pacer.note_set(arrival)
        arrival += period_ms * 1e-3
    return arrival


def test_the_period_is_the_median_interval_and_a_late_set_or_a_pause_does_not_move_it() -> None:
    pacer = Pacer(0.9)
    assert pacer.period_s is None
    arrival = _camera(pacer, 100)
    assert pacer.period_s == pytest.approx(0.1)
    pacer.note_set(arrival + 0.03)  # one set late
    assert pacer.period_s == pytest.approx(0.1)
    pacer.note_set(arrival + 0.03 + 2 * MAX_INTERVAL_S)  # a paused stream: not a period
    assert pacer.period_s == pytest.approx(0.1)
    pacer.note_set(arrival)  # an earlier time: no interval
    assert pacer.period_s == pytest.approx(0.1)


def test_a_backend_that_fits_the_period_answers_and_one_that_does_not_is_paced() -> None:
    pacer = Pacer(0.9)
    assert not pacer.choose()  # nothing known: the chosen backend answers
    pacer.note_cost(False, 0.08)
    assert not pacer.choose()  # no period yet
    _camera(pacer, 100)
    assert not pacer.choose()  # 80 ms of 90 allowed
    for _ in range(5):
        pacer.note_cost(False, 0.17)
    assert pacer.choose() and pacer.state().paced
    pacer.load = 2.0  # allowed two periods: fits
    assert not pacer.choose()


def test_while_paced_the_chosen_backend_answers_one_frame_in_probe_every_and_takes_over_when_it_fits() -> None:
    pacer = Pacer(0.9, probe_every=4)
    _camera(pacer, 100)
    for _ in range(3):
        pacer.note_cost(False, 0.17)
    choices = []
    for _ in range(10):
        paced = pacer.choose()
        choices.append(paced)
        pacer.note_cost(paced, 0.07 if paced else 0.17)
    assert choices == [True] * 4 + [False] + [True] * 4 + [False]
    state = pacer.state()
    assert state.pace_cost_s == pytest.approx(0.07) and state.cost_s == pytest.approx(0.17)
    # the load went away: the next probe measures 60 ms, which replaces the running cost at once
    for _ in range(4):
        assert pacer.choose()
        pacer.note_cost(True, 0.05)
    assert not pacer.choose()
    pacer.note_cost(False, 0.06)
    assert not pacer.choose() and pacer.state().cost_s == pytest.approx(0.06)


def test_a_reset_forgets_the_period_and_keeps_the_costs() -> None:
    pacer = Pacer(0.9)
    _camera(pacer, 100)
    pacer.note_cost(False, 0.2)
    assert pacer.choose()
    pacer.reset()
    assert pacer.period_s is None and not pacer.choose() and pacer.state().cost_s == pytest.approx(0.2)
    _camera(pacer, 100, sets=2)
    assert pacer.choose()


def test_the_state_says_who_answers_and_why() -> None:
    pacer = Pacer(0.9)
    assert pacer.state().describe("ensemble", "bm", 0.9) == \
        "ensemble answers (measuring its cost and the camera's period)"
    _camera(pacer, 100)
    pacer.note_cost(False, 0.05)
    assert pacer.state().describe("ensemble", "bm", 0.9) == \
        "ensemble answers: ensemble takes 50 ms a frame, the camera's period is 100 ms (pace_load 0.9)"
    pacer.note_cost(False, 0.5)
    pacer.note_cost(True, 0.07)
    assert pacer.state().describe("ensemble", "bm", 0.9) == (
        f"bm answers, 70 ms a frame: ensemble takes 185 ms a frame, the camera's period is 100 ms (pace_load 0.9); "
        f"ensemble answers one frame in {PROBE_EVERY + 1}")


def test_at_speed_the_pace_backend_answers_while_the_chosen_ones_extra_time_is_more_travel_than_the_lead() -> None:
    pacer = Pacer(0.9, probe_every=4, lead_m=0.5)
    _camera(pacer, 200)  # a 5 Hz camera: the chosen backend's 125 ms fit its period
    pacer.note_cost(False, 0.125)
    assert not pacer.choose(None) and not pacer.choose(3.0)  # no speed; 3 m/s x 125 ms < 0.5 m even against a free one
    # 20 m/s x 125 ms > 0.5 m: the pace backend answers a frame to be measured
    assert pacer.choose(20.0) and pacer.state().by_speed
    pacer.note_cost(True, 0.080)
    assert pacer.choose(20.0)  # 45 ms more a frame: 0.9 m of travel
    assert not pacer.choose(10.0)  # 0.45 m: the chosen backend answers
    assert not pacer.choose(float("nan"))  # an unknown speed leaves the rule out
    choices = []
    for _ in range(10):  # the chosen backend is still probed, its cost measured afresh
        paced = pacer.choose(-20.0)  # reversing as fast
        choices.append(paced)
        pacer.note_cost(paced, 0.08 if paced else 0.125)
    assert choices == [True] * 3 + [False] + [True] * 4 + [False] + [True]
    assert pacer.state().describe("ensemble", "bm", 0.9) == (
        "bm answers, 80 ms a frame: at 20.0 m/s the 45 ms more a frame that ensemble takes are 0.90 m of travel "
        "(pace_lead_m 0.5); ensemble answers one frame in 5")
    pacer.lead_m = 0.0  # off: by the load alone, which the chosen backend fits
    assert not pacer.choose(20.0) and not pacer.state().paced
    with pytest.raises(ValueError, match="pace lead must be a non-negative distance"):
        Pacer(0.9, lead_m=-1.0)


def test_a_load_that_is_not_positive_is_refused() -> None:
    with pytest.raises(ValueError, match="pace load must be positive"):
        Pacer(0.0)


def test_a_backend_stands_in_for_another_only_where_it_is_named_and_not_the_same() -> None:
    assert stand_in("bm", "ensemble") == "bm"
    assert stand_in("bm", "bm") == "" and stand_in("", "ensemble") == ""
    # a spec with options stands in as given, and not for its own backend
    assert stand_in("bm:plane_parallax_px=16", "ensemble") == "bm:plane_parallax_px=16"
    assert stand_in("bm:plane_parallax_px=16", "bm") == ""
