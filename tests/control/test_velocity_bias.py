"""The reported velocity's bias (control/velocity_bias.py), stepped in process
on telemetry generated here: exact trajectories, a known bias, 50 Hz."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs_swarm.control.velocity_bias import BiasSettings, VelocityBiasObserver

RATE_HZ = 50.0
DT = 1.0 / RATE_HZ


def _fly(
    obs: VelocityBiasObserver,
    seconds: float,
    bias: tuple[float, float, float],
    *,
    t0: float = 0.0,
    noise_m: float = 0.0,
    seed: int = 0,
) -> float:
    """Feed ``seconds`` of a vehicle on a figure of eight (accelerating all the
    time, up to 2 m/s), its velocity reported ``bias`` off; the end time."""
    rng = np.random.default_rng(seed)
    b = np.asarray(bias)
    n = round(seconds * RATE_HZ)
    for k in range(n + 1):
        t = t0 + k * DT
        p = np.array([8.0 * math.sin(0.25 * t), 4.0 * math.sin(0.5 * t), -10.0 - math.sin(0.2 * t)])
        v = np.array([2.0 * math.cos(0.25 * t), 2.0 * math.cos(0.5 * t), -0.2 * math.cos(0.2 * t)])
        p = p + noise_m * rng.standard_normal(3)
        obs.update(t, *p.tolist(), *(v + b).tolist())
    return t0 + n * DT


def test_a_constant_bias_is_recovered_while_the_vehicle_manoeuvres() -> None:
    obs = VelocityBiasObserver(BiasSettings(window_s=10.0))
    bias = (-0.015, 0.013, 0.0003)
    _fly(obs, 30.0, bias)
    # Trapezoid rule on a smooth 2 m/s path at 50 Hz: the integral's error over
    # 10 s is below 1e-5 m/s of bias (the path's third derivative is < 0.13 m/s^3).
    np.testing.assert_allclose(obs.bias, bias, atol=1e-5)
    assert obs.correction == obs.bias and not obs.saturated and obs.resets == 0


def test_no_bias_gives_none_and_correction_off_subtracts_nothing() -> None:
    obs = VelocityBiasObserver(BiasSettings(correct=False))
    _fly(obs, 20.0, (0.0, 0.0, 0.0))
    np.testing.assert_allclose(obs.bias, 0.0, atol=1e-5)
    _fly(obs, 20.0, (0.1, 0.0, 0.0), t0=20.0 + DT)
    assert obs.bias[0] == pytest.approx(0.1, abs=1e-5)
    assert obs.correction == (0.0, 0.0, 0.0)


def test_position_noise_of_sitl_size_stays_small() -> None:
    """Position noise 5 mm (SITL's hover std was 2-7 mm): the estimate's error
    is about sqrt(2) x 5 mm / 10 s = 0.7 mm/s; allow 3 mm/s (4 sigma)."""
    obs = VelocityBiasObserver(BiasSettings(window_s=10.0))
    _fly(obs, 40.0, (0.02, -0.01, 0.0), noise_m=0.005, seed=3)
    np.testing.assert_allclose(obs.bias, (0.02, -0.01, 0.0), atol=3e-3)


def test_nothing_before_the_window_spans_its_minimum() -> None:
    obs = VelocityBiasObserver(BiasSettings(window_s=10.0, min_span_s=2.0))
    _fly(obs, 1.5, (0.05, 0.0, 0.0))
    assert obs.bias == (0.0, 0.0, 0.0)
    _fly(obs, 1.0, (0.05, 0.0, 0.0), t0=1.5 + DT)
    assert obs.bias[0] == pytest.approx(0.05, abs=1e-4)


def test_a_changed_bias_is_followed_within_one_window() -> None:
    obs = VelocityBiasObserver(BiasSettings(window_s=10.0))
    t = _fly(obs, 30.0, (-0.015, 0.013, 0.0))
    _fly(obs, 10.5, (0.013, -0.013, 0.0), t0=t + DT)
    np.testing.assert_allclose(obs.bias, (0.013, -0.013, 0.0), atol=1e-4)


def test_a_gap_or_a_reboot_restarts_the_window_and_keeps_the_estimate() -> None:
    obs = VelocityBiasObserver(BiasSettings(window_s=10.0, max_gap_s=0.5))
    t = _fly(obs, 20.0, (0.02, 0.0, 0.0))
    before = obs.bias
    _fly(obs, 1.0, (0.02, 0.0, 0.0), t0=t + 2.0)  # a 2 s gap
    assert obs.resets == 1 and obs.bias == before
    _fly(obs, 5.0, (0.02, 0.0, 0.0), t0=0.0)  # time went back: a reboot
    assert obs.resets == 2
    assert obs.bias[0] == pytest.approx(0.02, abs=1e-4)


def test_a_position_jump_the_velocity_does_not_explain_restarts() -> None:
    """An EKF position reset (a 3 m step) must not read as 3 m of velocity bias."""
    obs = VelocityBiasObserver(BiasSettings(window_s=10.0, jump_m=1.0))
    for k in range(600):
        x = 0.0 if k < 300 else 3.0
        obs.update(k * DT, x, 0.0, -10.0, 0.0, 0.0, 0.0)
    assert obs.resets == 1
    assert obs.bias == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_an_absurd_estimate_is_held_at_the_cap_and_flagged() -> None:
    obs = VelocityBiasObserver(BiasSettings(window_s=5.0, max_mps=0.3))
    _fly(obs, 10.0, (0.8, 0.6, 0.0))
    assert obs.saturated
    assert math.hypot(*obs.bias) == pytest.approx(0.3, rel=1e-9)
    np.testing.assert_allclose(np.array(obs.bias) / 0.3, (0.8, 0.6, 0.0), atol=1e-4)


def test_duplicates_change_nothing() -> None:
    a = VelocityBiasObserver()
    b = VelocityBiasObserver()
    for k in range(1000):
        t = k * DT
        a.update(t, 0.01 * t, 0.0, -5.0, 0.05, 0.0, 0.0)
        b.update(t, 0.01 * t, 0.0, -5.0, 0.05, 0.0, 0.0)
        b.update(t, 0.01 * t, 0.0, -5.0, 0.05, 0.0, 0.0)
    assert a.bias == b.bias and b.resets == 0
    assert a.bias[0] == pytest.approx(0.04, abs=1e-9)


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="window_s"):
        BiasSettings(window_s=0.0)
    with pytest.raises(ValueError, match="max_mps"):
        BiasSettings(max_mps=-1.0)
