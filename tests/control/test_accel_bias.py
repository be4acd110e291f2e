"""The acceleration-bias observer (gcs_swarm.control.accel_bias), in process,
on hand-made point masses with a hand-advanced clock."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import pytest

from gcs_swarm.control.accel_bias import AccelBiasObserver, AccelBiasSettings

DT = 0.02


def test_a_constant_bias_is_found_exactly_whatever_is_commanded() -> None:
    """v' = a_sent + b, a_sent three sines (up to 2 m/s^2) less b held per step,
    so that the vehicle stays in place (|mean v| < still_mps): the window's
    (dv - integral of a_sent) / W is b to rounding (1e-12 m/s^2)."""
    b = (0.21, -0.13, 0.07)
    obs = AccelBiasObserver()
    v = [0.0, 0.0, 0.0]
    for k in range(1500):
        t = k * DT
        est = obs.update(t, (v[0], v[1], v[2]))
        wave = (
            0.02 * 0.7 * math.cos(0.7 * t),
            0.02 * 13 * math.cos(13 * t),
            0.01 * math.sin(3.1 * t),
        )
        a = (wave[0] - b[0], wave[1] - b[1], wave[2] - b[2])
        obs.sent(a)
        for i in range(3):
            v[i] += (a[i] + b[i]) * DT
    np.testing.assert_allclose(est, b, atol=1e-12)
    assert not obs.saturated and obs.resets == 0


def test_the_estimate_is_held_while_the_vehicle_moves() -> None:
    """A vehicle cruising at 1 m/s against a drag of 1/s (sent +1 m/s^2): the
    window's flown - sent is -1 m/s^2, the drag, not a bias; with the vehicle
    not holding still (mean |v| 1 m/s > still_mps) no estimate is made."""
    obs = AccelBiasObserver()
    v = 1.0
    for k in range(1500):
        obs.update(k * DT, (v, 0.0, 0.0))
        obs.sent((1.0, 0.0, 0.0))
        v += (1.0 - 1.0 * v) * DT
    assert obs.bias == (0.0, 0.0, 0.0) and obs.estimate == (0.0, 0.0, 0.0)


def _fly(correct: bool, bias: tuple[float, float, float], steps: int = 6000) -> np.ndarray:
    """A spring-damper law (stiffness 1.29, damping 1.6: sitl_px4's radial mode)
    flown by a vehicle with drag 1/s, a 0.3 s delay and a constant bias, as PX4
    SIH flies OFFBOARD accelerations; returns the final position."""
    obs = AccelBiasObserver()
    p, v = np.zeros(3), np.zeros(3)
    delay = deque([np.zeros(3)] * 15)  # 15 steps = 0.3 s
    for k in range(steps):
        t = k * DT
        est = np.array(obs.update(t, (float(v[0]), float(v[1]), float(v[2]))))
        a = -1.29 * p - 1.6 * v - (est if correct else 0.0)
        obs.sent((float(a[0]), float(a[1]), float(a[2])))
        delay.append(a)
        flown = delay.popleft() + np.array(bias) - 1.0 * v
        p = p + v * DT + 0.5 * flown * DT * DT
        v = v + flown * DT
    return p


def test_taking_the_bias_out_holds_the_point_where_the_law_puts_it() -> None:
    """Without the correction the spring holds the bias at b / K (0.155 m for
    0.2 m/s^2: PX4 SITL's +1.3 % on 17 m); with it the vehicle ends within 1 mm
    of the law's equilibrium after 120 s (the window converges in one W)."""
    b = (0.2, -0.15, 0.1)
    off = _fly(False, b)
    np.testing.assert_allclose(off, np.array(b) / 1.29, rtol=1e-3)
    on = _fly(True, b)
    assert np.linalg.norm(on) < 1e-3


def test_a_gap_restarts_the_window_and_a_large_estimate_is_capped() -> None:
    obs = AccelBiasObserver(AccelBiasSettings(max_mps2=0.5, still_mps=100.0))
    v = 0.0
    for k in range(300):
        obs.update(k * DT, (v, 0.0, 0.0))
        obs.sent((0.0, 0.0, 0.0))
        v += 2.0 * DT  # 2 m/s^2 flown with nothing sent
    assert obs.saturated and obs.bias[0] == pytest.approx(0.5)
    obs.update(300 * DT + 1.0, (v, 0.0, 0.0))  # a 1 s gap
    assert obs.resets == 1 and obs.bias == (0.0, 0.0, 0.0) and not obs.saturated


def test_auto_applies_to_px4_only() -> None:
    auto = AccelBiasSettings()
    assert auto.applies("px4") and not auto.applies("ardupilot") and not auto.applies("sim")
    assert AccelBiasSettings(correct=True).applies("ardupilot")
    assert not AccelBiasSettings(correct=False).applies("px4")
    with pytest.raises(ValueError):
        AccelBiasSettings(window_s=0.0)
