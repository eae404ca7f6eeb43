"""The quarter car: modes, static load, the simulated passive response against the analytic transmissibility."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.ride import GRAVITY, PreviewLqr, QuarterCar, RideError
from roadbev_lab.ride import simulate


def test_modes_and_static_load() -> None:
    car = QuarterCar()
    assert 1.0 < car.body_frequency_hz() < 1.5  # a passenger car's body mode
    assert 10.0 < car.wheel_hop_hz() < 13.0
    assert car.static_tyre_load_n == pytest.approx(415.0 * GRAVITY)


@pytest.mark.parametrize("f", [0.7, 1.13, 3.0, 11.8])
def test_passive_response_matches_the_transmissibility(f: float) -> None:
    car = QuarterCar()
    ctl = PreviewLqr(car=car, dt=0.001, horizon_s=0.0)
    t = np.arange(0.0, 30.0, ctl.dt)
    amplitude = 0.01
    w = amplitude * np.sin(2 * math.pi * f * t)
    result = simulate(ctl, np.append(np.diff(w) / ctl.dt, 0.0), None, passive=True)
    # body displacement z_s = x1 + x3 + w (deflections add up to the body's height), steady state
    z_s = result["state"][:, 0] + result["state"][:, 2] + w
    steady = z_s[t > 20.0]
    measured = (steady.max() - steady.min()) / 2 / amplitude
    assert measured == pytest.approx(float(car.transmissibility(f)), rel=0.02)
    assert np.all(result["force"] == 0.0)


def test_refuses_bad_parameters() -> None:
    with pytest.raises(RideError):
        QuarterCar(sprung_mass_kg=-1.0)
    with pytest.raises(RideError):
        PreviewLqr(dt=0.5)
