"""The vehicle envelope on the station's side (control/envelope.py, reaction.py)
and the law's time scale (Gains.time_scale), stepped in process."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gcs_swarm.control.envelope import (
    ARDUCOPTER,
    CommandShaper,
    Demand,
    cap_accel,
    demand_lines,
    jerk_limit,
    suggest_time_scale,
)
from gcs_swarm.control.params import ExpressionForce, Gains, LawConfig, Leader
from gcs_swarm.control.reaction import reaction_bound, stop_distance
from gcs_swarm.integrator import integrate

RNG = np.random.default_rng(14)


def test_unbounded_envelope_is_the_identity_bit_for_bit() -> None:
    from gcs_swarm.control.params import Envelope

    a = RNG.normal(size=(7, 3)) * 50.0
    assert np.array_equal(cap_accel(a, Envelope()), a)
    assert np.array_equal(jerk_limit(np.zeros((7, 3)), a, Envelope(), 0.02), a)
    shaper = CommandShaper(Envelope(), 0.02)
    assert shaper.shape(list(range(7)), a) is a  # not even a copy


def test_caps_keep_direction_and_bound_each_axis() -> None:
    a = RNG.normal(size=(200, 3)) * 5.0
    out = cap_accel(a, ARDUCOPTER)
    assert np.all(np.linalg.norm(out[:, :2], axis=1) <= 2.5 + 1e-12)
    assert np.all(np.abs(out[:, 2]) <= 1.0)
    # Horizontal direction kept: the cross product of old and new xy is zero.
    cross = a[:, 0] * out[:, 1] - a[:, 1] * out[:, 0]
    np.testing.assert_allclose(cross, 0.0, atol=1e-12)


def test_shaper_ramps_at_the_jerk_and_starts_new_vehicles_from_hover() -> None:
    dt = 0.02
    shaper = CommandShaper(ARDUCOPTER, dt)
    want = np.array([[2.0, 1.0, -0.8], [-2.5, 0.0, 1.0]])
    sent = [np.zeros((2, 3))]
    for _ in range(40):
        sent.append(shaper.shape([1, 2], want))
    steps = np.diff(np.array(sent), axis=0)
    # Exactly PSC_JERK_XY * dt horizontally and PSC_JERK_Z * dt vertically at most.
    assert np.linalg.norm(steps[..., :2], axis=-1).max() <= 5.0 * dt * (1 + 1e-12)
    assert np.abs(steps[..., 2]).max() <= 5.0 * dt * (1 + 1e-12)
    np.testing.assert_allclose(sent[-1], cap_accel(want, ARDUCOPTER), atol=1e-12)
    # Vehicle 3 joins: its first command is one jerk step from zero; 2 is
    # missing from a step but has not left: it keeps its last command.
    out = shaper.shape([1, 3], want)
    assert np.linalg.norm(out[1, :2]) == pytest.approx(5.0 * dt)
    np.testing.assert_allclose(shaper.previous([2]), sent[-1][1:])
    shaper.forget(2)  # it left
    np.testing.assert_allclose(shaper.previous([2]), 0.0)


def test_time_scale_flies_the_same_solution_lambda_times_slower() -> None:
    """x(t) = X(t / lambda): Scenario 2's leader law and its tetrahedron. RK4 of
    the scaled system with step lambda h is the unscaled RK4 with step h in
    scaled variables, so the two agree to rounding (1e-9 m over 1500 steps)."""
    lam = 2.5
    leader = Leader(start=(1.0, 1.0, 1.0), force=ExpressionForce(("10", "10*sin(x/8)", "2")))
    base = LawConfig(gains=Gains(k_s=5.0, k_r=5.0), leader=leader)
    slow = replace(base, gains=replace(base.gains, time_scale=lam))
    starts = [(2.6, 2.6, 2.6), (2.6, -0.6, -0.6), (-0.6, 2.6, -0.6), (-0.6, -0.6, 2.6)]
    fast = integrate(base, starts, duration=15.0, dt=0.01)
    slow_run = integrate(slow, starts, duration=15.0 * lam, dt=0.01 * lam)
    np.testing.assert_allclose(slow_run.pos_m, fast.pos_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(slow_run.leader_pos_m, fast.leader_pos_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(slow_run.vel_mps * lam, fast.vel_mps, rtol=0, atol=1e-9)
    np.testing.assert_allclose(slow_run.accel_mps2 * lam**2, fast.accel_mps2, rtol=0, atol=1e-8)


def test_suggested_time_scale_uses_the_scaling_exponents() -> None:
    demand = Demand(
        accel_xy=10.0, accel_z=0.5, jerk_xy=5.0, jerk_z=5.0, speed_xy=1.0, speed_up=0.1,
        speed_down=0.1,
    )  # fmt: skip
    # accel: sqrt(10 / 2.5) = 2 wins over cbrt(5 / 5) = 1 and 1 / 10.
    assert suggest_time_scale(demand, ARDUCOPTER) == 2.0
    jerky = replace(demand, accel_xy=1.0, jerk_z=5.0 * 3.3**3)
    assert suggest_time_scale(jerky, ARDUCOPTER) == pytest.approx(3.3)
    assert suggest_time_scale(jerky, ARDUCOPTER, current=2.0) == pytest.approx(6.6)
    fits = replace(demand, accel_xy=1.0)
    assert demand_lines(fits, ARDUCOPTER) == []
    (line,) = demand_lines(demand, ARDUCOPTER)
    assert "accel_xy 10 m/s^2 > 2.5" in line and line.endswith("gains.time_scale: 2")


def _plan_distance(s: float, c: float, a_b: float, c_cap: float, j: float, tau: float) -> float:
    """(B0') integrated by brute force (20 us steps): the largest displacement."""
    h = 2e-5
    x, v, t, best = 0.0, s, 0.0, 0.0
    while t < 60.0:
        acc = min(max(c + j * (tau - t), -a_b), c_cap)
        x += v * h + 0.5 * acc * h * h
        v += acc * h
        t += h
        best = max(best, x)
        if v < 0.0 and acc < 0.0 and t > tau:
            break
    return best


@pytest.mark.parametrize(
    ("s", "c"), [(2.0, 0.0), (2.0, 1.0), (-1.0, 1.2), (0.5, -1.0), (3.0, -0.4), (0.0, 0.0)]
)
def test_stop_distance_is_the_plan_integrated(s: float, c: float) -> None:
    """S(s, c) of (B1') against a brute-force integration of (B0'); the step
    error of that integration (exact per step but for the kinks) is below 1e-4 m."""
    got = float(stop_distance(np.array(s), np.array(c), np.array(0.6), np.array(1.2), 5.0, 0.2))
    assert got == pytest.approx(_plan_distance(s, c, 0.6, 1.2, 5.0, 0.2), abs=1e-4)


def test_stop_distance_without_lag_or_jerk_is_the_point_mass_barrier() -> None:
    s = np.linspace(-2.0, 4.0, 13)
    got = stop_distance(s, np.zeros(13), np.full(13, 1.5), np.full(13, 3.0), math.inf, 0.0)
    np.testing.assert_allclose(got, np.maximum(s, 0.0) ** 2 / 3.0, rtol=1e-12)


def test_the_plan_step_is_always_admissible() -> None:
    """Time consistency of (B0'): where H' >= 0 the bound never asks more than
    one jerk step, u_min <= n.a' + j dt, so a jerk-limited vehicle can obey."""
    n = 5000
    dist = RNG.uniform(0.0, 6.0, n)
    s = RNG.uniform(-3.0, 3.0, n)
    c = RNG.uniform(-1.2, 1.2, n)
    a_b, cap = np.full(n, 0.6), np.full(n, 1.2)
    h = dist - stop_distance(s, c, a_b, cap, 5.0, 0.2)
    u = reaction_bound(dist, s, c, a_b, cap, jerk=5.0, lag=0.2, dt=0.02, gamma=2.0)
    ok = h >= 0.0
    assert ok.sum() > 1000
    assert np.all(u[ok] <= -c[ok] + 5.0 * 0.02 + 1e-9)
    assert np.all(u <= a_b + 1e-12)


def test_example1_arducopter_forms_inside_the_envelope() -> None:
    """The shipped mission, simulated with ArduCopter's envelope modelled for
    its first 40 s: every radius within 1 % of the law's 2.48418 m (measured
    from 25 s), separation above the 1 m configured, the commands inside the
    envelope; the whole shape settles later (272 s, docs/vehicle-envelope.md)."""
    from pathlib import Path

    from gcs_swarm.mission import load_mission
    from gcs_swarm.offline import simulate_mission

    path = Path(__file__).resolve().parents[2] / "config/missions/example1_arducopter.yaml"
    mission = load_mission(path)
    assert mission.law.limits.envelope == ARDUCOPTER
    out = simulate_mission(mission, duration_s=40.0)
    assert out.envelope == ARDUCOPTER
    res = out.result
    r = np.linalg.norm(res.pos_m[-1] - res.leader_pos_m[-1], axis=-1)
    np.testing.assert_allclose(r, 2.48418, rtol=0.01)
    assert res.figures().min_separation_m >= 1.0
    a = res.accel_mps2
    assert np.linalg.norm(a[..., :2], axis=-1).max() <= 1.0 + 1e-9  # a_max 1 inside 2.5
    assert np.abs(a[..., 2]).max() <= 1.0 + 1e-9
    assert np.abs(np.diff(a, axis=0)).max() <= 5.0 * 0.02 + 1e-9


def test_time_scale_keeps_the_avoidance_episode() -> None:
    """Through Scenario 3's obstacle too: the episode starts at lambda times the
    paper's time, the look-ahead and slot targets (their steps and horizons
    scaled alike) choose the same, and the paths agree to rounding."""
    from pathlib import Path

    from gcs_swarm.mission import load_mission

    path = Path(__file__).resolve().parents[2] / "config/missions/scenario3_obstacle.yaml"
    law = load_mission(path).law
    starts = [(2.6, 2.6, 2.6), (2.6, -0.6, -0.6), (-0.6, 2.6, -0.6), (-0.6, -0.6, 2.6)]
    lam = 2.5
    fast = integrate(law, starts, duration=20.0, dt=0.01)
    slow = integrate(replace(law, gains=replace(law.gains, time_scale=lam)), starts,
                    duration=20.0 * lam, dt=0.01 * lam)  # fmt: skip
    assert len(fast.switches) == len(slow.switches) == 1
    assert slow.switches[0][0] == pytest.approx(lam * fast.switches[0][0])
    np.testing.assert_allclose(slow.pos_m, fast.pos_m, rtol=0, atol=1e-9)
