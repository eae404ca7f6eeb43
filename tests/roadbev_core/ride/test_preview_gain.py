"""The preview's measured gain: 1 for a preview that follows the road, 0 for one that does not, the
same online and in the simulation, and what it does to a ride."""

from __future__ import annotations

import numpy as np
import pytest

from roadbev_core.ride import PreviewGain, PreviewLqr, RideError, preview_gains

CTL = PreviewLqr(dt=0.005)


def _road_velocity(steps: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.convolve(rng.normal(0.0, 0.2, steps), np.ones(20) / 20, "same")  # [J] a rough road's w'


def test_a_preview_that_follows_the_road_keeps_all_of_its_gain() -> None:
    w = _road_velocity(3000)
    realised = CTL.feedforward(w)
    gains = preview_gains(realised, realised, CTL.steps, CTL.dt)
    assert np.all(gains == pytest.approx(1.0))
    half = preview_gains(2.0 * realised, realised, CTL.steps, CTL.dt)  # twice what the road asks
    assert half[-1] == pytest.approx(0.5, abs=1e-6)
    assert np.all(half[: CTL.steps + 1] == 1.0)  # nothing is known until a horizon has been ridden


def test_a_preview_unrelated_to_the_road_is_turned_off() -> None:
    realised = CTL.feedforward(_road_velocity(6000, 1))
    wrong = CTL.feedforward(_road_velocity(6000, 2))
    gains = preview_gains(wrong, realised, CTL.steps, CTL.dt, time_constant_s=3.0)
    assert gains[-1] < 0.3
    assert np.all((gains >= 0.0) & (gains <= 1.0))
    inverted = preview_gains(-realised, realised, CTL.steps, CTL.dt)
    assert inverted[-1] == 0.0  # a preview of the wrong sign is never applied


def test_online_gain_equals_the_simulations() -> None:
    w = _road_velocity(2000, 3)
    realised = CTL.feedforward(w)
    previewed = 0.7 * realised + CTL.feedforward(_road_velocity(2000, 4))
    batch = preview_gains(previewed, realised, CTL.steps, CTL.dt)
    online = PreviewGain(CTL.steps, CTL.dt)
    ridden: list[float] = []
    values = []
    for k in range(w.size):
        values.append(online.value)
        ridden.append(float(w[k]))
        known = k >= CTL.steps
        # the feedforward of the step a horizon ago, from the road ridden since
        lagged = float(CTL.preview_gains @ np.asarray(ridden[-CTL.steps - 1:])) if known else None
        online.update(float(previewed[k]), lagged)
    # feedforward() treats the road beyond the end as flat; compare where the lagged sums are complete
    np.testing.assert_allclose(values[: w.size - CTL.steps], batch[: w.size - CTL.steps], atol=1e-9)
    online.reset()
    assert online.value == 1.0


def test_bad_settings_are_refused() -> None:
    with pytest.raises(RideError):
        PreviewGain(-1, 0.001)
    with pytest.raises(RideError):
        PreviewGain(10, 0.001, time_constant_s=0.0)
    with pytest.raises(RideError):
        preview_gains(np.zeros(3), np.zeros(4), 1, 0.001)
