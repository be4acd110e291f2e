"""The virtual leader (Eq. 13) and its force laws."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gcs_swarm.control import ConstantForce, ExpressionForce, Gains, LeaderLaw, WaypointForce
from gcs_swarm.errors import ExpressionError


def test_constant_force_matches_the_closed_form() -> None:
    # M v' = F - c v from rest: v = F/c (1 - exp(-c t / M)),
    # x = F/c (t - M/c (1 - exp(-c t / M))).
    g = Gains(M=2.0, D=1.0, k=9.0)
    law = LeaderLaw(ConstantForce((10.0, -4.0, 2.0)), g)
    s = law.advance(0.0, law.initial_state((1.0, 1.0, 1.0), (0.0, 0.0, 0.0)), 3.0)
    c, m, t = 10.0, 2.0, 3.0
    e = math.exp(-c * t / m)
    f = np.array([10.0, -4.0, 2.0])
    # RK4 with h = 0.02 and c/M = 5: local error ~ (h c/M)^5 / 120 -> global ~1e-9.
    np.testing.assert_allclose(s.vel_mps, f / c * (1 - e), atol=1e-8)
    np.testing.assert_allclose(s.pos_m, 1.0 + f / c * (t - m / c * (1 - e)), atol=1e-8)


def test_terminal_speed_is_force_over_damping() -> None:
    law = LeaderLaw(ConstantForce((10.0, 0.0, 0.0)), Gains())
    s = law.advance(0.0, law.initial_state((0, 0, 0), (0, 0, 0)), 10.0)
    assert s.vel_mps[0] == pytest.approx(1.0, abs=1e-12)  # |f| / (D + k) = 10 / 10


def test_scenario2_expression_force() -> None:
    law = LeaderLaw(ExpressionForce(("10", "10*sin(x/8)", "2")), Gains())
    s0 = law.initial_state((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    assert law.force(0.0, s0.pos_m, s0.vel_mps) == pytest.approx((10.0, 10 * math.sin(1 / 8), 2.0))
    s = law.advance(0.0, s0, 20.0)
    # x moves at ~1 m/s, z at ~0.2 m/s; y follows sin(x/8) with amplitude ~1 m/s.
    assert 19.0 < s.pos_m[0] < 21.0
    assert s.pos_m[2] == pytest.approx(1.0 + 0.2 * (20.0 - 0.1 * (1 - math.exp(-200))), abs=1e-9)


def test_expression_errors_surface_at_build_and_run_time() -> None:
    with pytest.raises(ExpressionError, match="unknown name 'w'"):
        LeaderLaw(ExpressionForce(("w", "0", "0")), Gains())
    law = LeaderLaw(ExpressionForce(("1/(x-1)", "0", "0")), Gains())
    with pytest.raises(ExpressionError, match="cannot be evaluated"):
        law.force(0.0, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def test_time_jumps_are_integrated_in_sub_steps() -> None:
    law = LeaderLaw(ExpressionForce(("10*cos(t)", "10*sin(x/8)", "0")), Gains())
    s0 = law.initial_state((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    one = law.advance(0.0, s0, 2.0)
    many = s0
    for k in range(100):  # 50 Hz calls
        many = law.advance(k * 0.02, many, (k + 1) * 0.02)
    np.testing.assert_allclose(one.pos_m, many.pos_m, atol=1e-12)
    # Irregular steps: same trajectory to the RK4 error (h <= 0.02 -> ~1e-9).
    irregular = s0
    ts = [0.0, 0.013, 0.05, 0.31, 0.312, 1.0, 2.0]
    for a, b in itertools.pairwise(ts):
        irregular = law.advance(a, irregular, b)
    np.testing.assert_allclose(one.pos_m, irregular.pos_m, atol=1e-8)
    assert law.advance(2.0, one, 2.0) is one and law.advance(2.0, one, 1.0) is one


def test_waypoints_are_visited_and_the_leader_stops_on_the_last() -> None:
    wps = ((5.0, 0.0, 0.0), (5.0, 5.0, 0.0), (0.0, 5.0, 2.0))
    law = LeaderLaw(WaypointForce(wps, cruise_speed=1.5), Gains())
    s = law.initial_state((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    closest = [math.inf] * 3
    speeds = []
    overshoot = 0.0
    for k in range(3000):  # 60 s
        s = law.advance(k * 0.02, s, (k + 1) * 0.02)
        for i, w in enumerate(wps):
            closest[i] = min(closest[i], math.dist(w, s.pos_m))
        speeds.append(math.hypot(*s.vel_mps))
        if s.wp_index == 2:
            # Critically damped final approach: never past the last waypoint
            # along the last leg's direction.
            leg = np.subtract(wps[2], wps[1])
            overshoot = max(overshoot, float(np.dot(np.subtract(s.pos_m, wps[2]), leg)))
    assert s.wp_index == 2
    assert closest[0] <= 0.5 + 1e-9 and closest[1] <= 0.5 + 1e-9  # accept radius
    assert math.dist(s.pos_m, wps[2]) < 1e-6 and speeds[-1] < 1e-6
    assert max(speeds) <= 1.5 + 1e-9  # terminal speed = cruise speed, never above
    assert overshoot <= 1e-9


def test_bad_waypoint_laws_are_rejected() -> None:
    with pytest.raises(ValueError, match="at least one"):
        LeaderLaw(WaypointForce((), cruise_speed=1.0), Gains())
    with pytest.raises(ValueError, match="cruise_speed"):
        LeaderLaw(WaypointForce(((0.0, 0.0, 0.0),), cruise_speed=0.0), Gains())
