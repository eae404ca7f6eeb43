"""The preview LQR: a perfect preview beats none on a bump, gains, the step law."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.ride import LqrWeights, PreviewLqr, RideError
from roadbev_lab.ride import simulate, weighted_rms


def _bump_velocity(dt: float, speed: float = 10.0, height: float = 0.05, length: float = 0.6) -> np.ndarray:
    x = np.arange(0.0, 40.0, speed * dt)  # 4 s at 10 m/s
    h = np.where(np.abs(x - 15.0) < length / 2, 0.5 * height * (1 + np.cos(2 * math.pi * (x - 15.0) / length)), 0.0)
    return np.append(np.diff(h) / dt, 0.0)


def test_perfect_preview_beats_no_preview_beats_passive_on_a_bump() -> None:
    ctl = PreviewLqr()
    w = _bump_velocity(ctl.dt)
    fs = 1.0 / ctl.dt
    passive = weighted_rms(simulate(ctl, w, None, passive=True)["acceleration"], fs)
    none = weighted_rms(simulate(ctl, w, None)["acceleration"], fs)
    perfect = simulate(ctl, w, ctl.feedforward(w))
    assert none < passive
    assert weighted_rms(perfect["acceleration"], fs) < 0.8 * none
    # the preview acts before the wheel reaches the bump (x = 15 m at 1.5 s)
    assert np.abs(perfect["force"][int(1.2 / ctl.dt): int(1.45 / ctl.dt)]).max() > 50.0


def test_gains_decay_and_the_step_law_matches_the_feedforward() -> None:
    ctl = PreviewLqr(horizon_s=1.0)
    g = np.abs(ctl.preview_gains)
    assert ctl.steps == 1000 and g[-1] < 0.01 * g.max()
    w = _bump_velocity(ctl.dt)
    ff = ctl.feedforward(w)
    k = int(1.4 / ctl.dt)
    state = np.array([0.001, 0.01, -0.0005, 0.02])
    expected = -float(ctl.feedback @ state) - ff[k]
    assert ctl.force(state, w[k: k + ctl.steps + 1]) == pytest.approx(expected)
    assert ctl.force(state, None) == pytest.approx(-float(ctl.feedback @ state))


def test_closed_loop_is_stable_and_weights_are_checked() -> None:
    ctl = PreviewLqr()
    Phi, Gu, _ = ctl.matrices
    assert np.abs(np.linalg.eigvals(Phi - Gu @ ctl.feedback[None, :])).max() < 1.0
    with pytest.raises(RideError):
        LqrWeights(body_acceleration=-1.0)
    with pytest.raises(RideError):
        PreviewLqr(horizon_s=10.0)
