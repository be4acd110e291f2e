"""The control step without I/O: vehicle-time clock, limits, join slots."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs_swarm.control import ConstantForce, LawConfig, Leader, Limits
from gcs_swarm.control.loop import MAX_CLOCK_JUMP_S
from gcs_swarm.runtime import ControlLoop


def test_mission_clock_follows_vehicle_time_not_the_wall() -> None:
    loop = ControlLoop(LawConfig(), {1: 10.0, 2: 10.0, 3: 10.0}, 50.0)
    assert loop.advance_clock({1: 5000, 2: 9000}) == 0.0  # first sight: no increment
    # Vehicles booted at different times: each one's own increment counts.
    assert loop.advance_clock({1: 5020, 2: 9020}) == pytest.approx(0.02)
    # The median ignores one vehicle's odd increment (late packet).
    assert loop.advance_clock({1: 5040, 2: 9040, 3: 100}) == pytest.approx(0.04)
    assert loop.advance_clock({1: 5060, 2: 9200, 3: 120}) == pytest.approx(0.06)
    # A rebooted vehicle (time going back) adds nothing; a long gap is capped.
    assert loop.advance_clock({2: 10}) == pytest.approx(0.06)
    assert loop.advance_clock({1: 65060}) == pytest.approx(0.06 + MAX_CLOCK_JUMP_S)


def test_steps_on_different_subsets_never_run_ahead_of_vehicle_time() -> None:
    # Two vehicles on one clock; vehicle 1's reports arrive late (jitter), so
    # steps see {2}, {2}, then vehicle 1's 60 ms report. Summing each step's
    # increments counted vehicle 1's 40 ms on top of vehicle 2's (0.10 s at
    # 60 ms of vehicle time): measured, a 20 s mission ended after 10 s of
    # flight through 200 ms jitter. The clock is vehicle time, 0.06 s.
    loop = ControlLoop(LawConfig(), {1: 10.0, 2: 10.0}, 50.0)
    for boot in ({1: 0, 2: 0}, {1: 20, 2: 20}, {2: 40}, {2: 60}, {1: 60}):
        t = loop.advance_clock(boot)
    assert t == pytest.approx(0.06, abs=1e-12)
    assert loop.advance_clock({1: 80, 2: 80}) == pytest.approx(0.08, abs=1e-12)


def test_leader_moves_in_vehicle_time() -> None:
    force = ConstantForce((10.0, 0.0, 0.0))  # terminal speed 1 m/s (total damping 10)
    law = LawConfig(leader=Leader(force=force))
    loop = ControlLoop(law, {1: 10.0}, 50.0)
    pos, vel = np.zeros((1, 3)), np.zeros((1, 3))
    for k in range(0, 20001, 20):  # 20 s of vehicle time
        loop.advance_clock({1: k})
        res = loop.step([1], pos, vel)
    # x(t) = v_inf (t - tau (1 - e^{-t/tau})), tau = M / (D + k) = 0.1 s.
    assert res.law.leader_pos_m[0] == pytest.approx(20.0 - 0.1 * (1 - math.exp(-200)), abs=1e-4)


def test_acceleration_limit_is_applied_to_every_setpoint() -> None:
    law = LawConfig(limits=Limits(a_max=2.0))
    loop = ControlLoop(law, {1: 10.0, 2: 10.0}, 50.0)
    far = np.array([[30.0, 0.0, 0.0], [0.0, -30.0, 0.0]])  # cubic attraction: huge demand
    res = loop.step([1, 2], far, np.zeros((2, 3)))
    assert np.linalg.norm(res.law.accel_mps2, axis=1).min() > 1e3
    np.testing.assert_allclose(np.linalg.norm(res.accel_mps2, axis=1), 2.0, rtol=1e-9)
    assert loop.peak_accel_mps2 == pytest.approx(2.0, rel=1e-9)  # what was commanded


def test_slot_of_a_returning_vehicle_moves_with_the_leader() -> None:
    law = LawConfig(leader=Leader(start=(1.0, 1.0, 1.0), force=ConstantForce((10.0, 0.0, 0.0))))
    loop = ControlLoop(law, {1: 10.0}, 50.0)
    for k in range(0, 5001, 20):
        loop.advance_clock({1: k})
        loop.step([1], np.array([[1.0, 1.0, 1.0]]), np.zeros((1, 3)))
    slot = loop.slot_m((2.0, 1.0, 1.0))
    np.testing.assert_allclose(slot - loop.controller.leader_pos_m, [1.0, 0.0, 0.0])


def test_the_rejoin_point_is_a_separation_outside_every_member() -> None:
    """``ControlLoop.rejoin_m``: on the ray from the leader through the slot,
    the separation beyond the farther of the slot and the farthest member,
    so every member is at least the separation from it (here with the slot
    taken: a member sits on it)."""
    from gcs_swarm.control.params import Safety

    law = LawConfig(safety=Safety(separation=6.0))
    loop = ControlLoop(law, {i: 10.0 for i in range(1, 5)}, 50.0)
    rng = np.random.default_rng(5)
    for _ in range(50):
        start = rng.normal(0.0, 10.0, 3)
        members = rng.normal(0.0, 12.0, (3, 3))
        members[0] = start  # the others re-formed onto its slot
        radius = float(np.linalg.norm(members, axis=1).max())
        point = loop.rejoin_m(start, np.zeros(3), radius)
        assert np.linalg.norm(members - point, axis=1).min() >= 6.0 - 1e-9
        ray = point / np.linalg.norm(point)
        np.testing.assert_allclose(ray, start / np.linalg.norm(start), atol=1e-12)
        assert np.linalg.norm(point) == pytest.approx(max(np.linalg.norm(start), radius) + 6.0)
    # Moved with the leader: the same point beside a leader elsewhere.
    lead = np.array([100.0, -50.0, 30.0])
    np.testing.assert_allclose(
        loop.rejoin_m((3.0, 4.0, 0.0), lead, 2.0), lead + np.array([3.0, 4.0, 0.0]) * 11 / 5
    )
