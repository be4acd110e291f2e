"""SwarmController and the behaviour supervisor (Eqs. 29-30): one episode per
obstacle pass, slot targets, centroid leader, deferred look-ahead, join/leave."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from gcs_swarm.control import (
    Avoidance,
    Box,
    ConstantForce,
    LawConfig,
    Leader,
    Readings,
    SwarmController,
    repulsion_force,
    rho,
)
from gcs_swarm.control.law import as_states
from gcs_swarm.control.obstacles import Ellipsoids
from gcs_swarm.integrator import SimResult, integrate

STARTS = [(2, 1, 2), (-1, -1, -1), (3, 4, 2), (4, 2, 2), (3, 3, 3), (-2, -2, -2)]
IDS = [11, 12, 13, 14, 15, 16]
Q = np.full(6, 10.0)
BOX = Box((40.0, 0.5, 0.3), (3.0, 2.0, 1.0))
DT = 0.02


def _config(**avoid: object) -> LawConfig:
    return LawConfig(
        leader=Leader(force=ConstantForce((10.0, 0.0, 0.0))),
        obstacles=(BOX,),
        avoidance=Avoidance(**avoid),  # type: ignore[arg-type]
    )


@cache
def _pass_run() -> SimResult:
    # The formation (1 m/s along +x) meets the box at ~32 s, is past it by ~50 s.
    return integrate(_config(), STARTS, duration=60.0, dt=DT, ids=IDS)


def test_one_episode_per_obstacle_pass() -> None:
    res = _pass_run()
    assert [e for _, e in res.switches] == ["start", "end"]
    assert int(res.episode[-1]) == 1
    t_start, t_end = (t for t, _ in res.switches)
    assert 25.0 < t_start < 40.0 and t_end < 55.0
    # The behaviour column agrees with the switches.
    avoiding = res.behaviour == "avoidance"
    assert np.all(avoiding == ((res.times_s >= t_start) & (res.times_s < t_end)))


def test_centroid_leader_during_the_episode_and_restart_after() -> None:
    res = _pass_run()
    avoiding = np.flatnonzero(res.behaviour == "avoidance")
    centroid = res.pos_m.mean(axis=1)
    # Eq. 30: the leader IS the centroid during the episode (bit-for-bit copy).
    np.testing.assert_allclose(res.leader_pos_m[avoiding], centroid[avoiding], atol=1e-12)
    # Eq. 13 restarts from the centroid's position and velocity at the end.
    k_end = avoiding[-1] + 1
    np.testing.assert_allclose(res.leader_pos_m[k_end], centroid[k_end], atol=1e-12)
    np.testing.assert_allclose(
        res.leader_vel_mps[k_end], res.vel_mps[k_end].mean(axis=0), atol=1e-12
    )


def test_slot_targets_lie_outside_the_field_beyond_the_obstacle() -> None:
    res = _pass_run()
    cfg = res.config
    k0 = int(np.flatnonzero(res.behaviour == "avoidance")[0])
    ctl = SwarmController(cfg, t0=res.times_s[k0 - 1])
    # Hand the controller the leader state the simulator had just before.
    out = None
    for k in (k0 - 1, k0):
        out = ctl.step(res.times_s[k], IDS, res.pos_m[k], res.vel_mps[k], Q)
    assert out is not None and out.event == "start" and out.targets_m is not None
    obs = Ellipsoids.from_boxes(cfg.obstacles)
    r = rho(out.targets_m, obs)
    assert np.all(r >= cfg.avoidance.r0 + cfg.avoidance.target_margin - 1e-12)
    assert np.all(out.targets_m[:, 0] > BOX.centre[0])  # beyond the box along the path
    # Slots keep the formation's shape: target - centroid(targets) = p - centroid(p).
    p = res.pos_m[k0]
    np.testing.assert_allclose(
        out.targets_m - out.targets_m.mean(axis=0), p - p.mean(axis=0), atol=1e-9
    )


def test_controller_reproduces_the_simulator_commands() -> None:
    # Fed the simulator's states at the simulator's sample times, the controller
    # (leader RK4 with the same step, same supervisor) issues the same
    # accelerations, through the whole episode. 1e-6: the two leaders are the
    # same RK4 in floats vs numpy arrays (rounding ~1e-15 per step, amplified
    # by the stiff r^3 attraction and the switch).
    res = _pass_run()
    ctl = SwarmController(res.config)
    worst = 0.0
    for k in range(len(res.times_s)):
        out = ctl.step(res.times_s[k], IDS, res.pos_m[k], res.vel_mps[k], Q)
        assert out.behaviour == res.behaviour[k]
        worst = max(worst, float(np.max(np.abs(out.accel_mps2 - res.accel_mps2[k]))))
    assert worst < 1e-6
    assert ctl.episode == 1


def test_deferred_lookahead_is_provisional_then_applied() -> None:
    res = _pass_run()
    k0 = int(np.flatnonzero(res.behaviour == "avoidance")[0])
    ctl = SwarmController(_config(), defer_lookahead=True)
    sync = SwarmController(_config())
    for k in range(k0 + 1):
        ctl.step(res.times_s[k], IDS, res.pos_m[k], res.vel_mps[k], Q)
        sync.step(res.times_s[k], IDS, res.pos_m[k], res.vel_mps[k], Q)
    job = ctl.pending_lookahead()
    assert job is not None and ctl.pending_lookahead() is None  # handed over once
    assert job.episode == 1 and job.ids == tuple(IDS)
    result = job()  # the station would run this in a worker thread
    assert result.vertical.shape == (6,) and np.all(np.isfinite(result.length_h_m))
    k = k0 + 300  # 6 s in: vehicles are deep in the field, where the plane matters
    before = ctl.step(res.times_s[k], IDS, res.pos_m[k], res.vel_mps[k], Q)
    sync.step(res.times_s[k], IDS, res.pos_m[k], res.vel_mps[k], Q)
    ctl.resolve_lookahead(job, result)
    after = ctl.step(res.times_s[k] + 1e-3, IDS, res.pos_m[k], res.vel_mps[k], Q)
    ref = sync.step(res.times_s[k] + 1e-3, IDS, res.pos_m[k], res.vel_mps[k], Q)
    # Resolved, it commands what the synchronous controller does.
    np.testing.assert_allclose(after.accel_mps2, ref.accel_mps2, atol=1e-9)
    if result.vertical.any():  # provisional horizontal differed
        assert not np.allclose(before.accel_mps2, after.accel_mps2)


def test_stale_lookahead_is_ignored() -> None:
    ctl = SwarmController(_config(), defer_lookahead=True)
    near = np.array(STARTS, dtype=float) + np.array([34.0, 0.0, 0.0])
    ctl.step(0.0, IDS, near, np.zeros((6, 3)), Q)
    job = ctl.pending_lookahead()
    assert job is not None and ctl.behaviour == "avoidance"
    far = near + np.array([100.0, 0.0, 0.0])
    out = ctl.step(0.1, IDS, far, np.zeros((6, 3)), Q)
    assert out.event == "end"
    ctl.resolve_lookahead(job, job())  # no effect, no error
    assert ctl.behaviour == "formation"


def test_ids_key_the_discrete_state_not_the_order() -> None:
    res = _pass_run()
    k0 = int(np.flatnonzero(res.behaviour == "avoidance")[0])
    perm = np.array([3, 0, 5, 1, 4, 2])
    a, b = SwarmController(res.config), SwarmController(res.config)
    for k in range(k0 - 5, k0 + 200, 5):
        out_a = a.step(res.times_s[k], IDS, res.pos_m[k], res.vel_mps[k], Q)
        out_b = b.step(
            res.times_s[k], [IDS[j] for j in perm], res.pos_m[k][perm], res.vel_mps[k][perm], Q
        )
        np.testing.assert_allclose(out_b.accel_mps2, out_a.accel_mps2[perm], atol=1e-9)


def test_join_and_leave_between_steps() -> None:
    ctl = SwarmController(LawConfig())
    p = np.array(STARTS, dtype=float)
    out6 = ctl.step(0.0, IDS, p, np.zeros((6, 3)), Q)
    out5 = ctl.step(0.02, IDS[:5], p[:5], np.zeros((5, 3)), Q[:5])
    out0 = ctl.step(0.04, [], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    out1 = ctl.step(0.06, [99], p[:1], np.zeros((1, 3)), Q[:1])
    assert out6.accel_mps2.shape == (6, 3) and out5.accel_mps2.shape == (5, 3)
    assert out0.accel_mps2.shape == (0, 3) and out1.ids == (99,)
    assert np.all(np.isfinite(out1.accel_mps2))


def test_bad_inputs_are_rejected() -> None:
    ctl = SwarmController(LawConfig())
    p = np.zeros((2, 3))
    with pytest.raises(ValueError, match="expected 2 ids"):
        ctl.step(0.0, [1, 2], np.zeros((3, 3)), p, np.ones(2))
    with pytest.raises(ValueError, match="repeat"):
        ctl.step(0.0, [1, 1], p, p, np.ones(2))
    with pytest.raises(ValueError, match=r"non-finite state for vehicle ids \[2\]"):
        ctl.step(0.0, [1, 2], np.array([[0, 0, 0], [np.nan, 0, 0]]), p, np.ones(2))


@pytest.mark.parametrize("n", [3, 40])  # below SMALL_N (floats) and above it (numpy)
def test_the_finite_check_names_each_bad_vehicle_and_passes_huge_finite_values(n: int) -> None:
    """``as_states`` checks finiteness on the sum of every value: a NaN or an
    infinity anywhere (position, velocity or charge) is named, and finite
    values whose sum overflows are still accepted."""
    ids = list(range(1, n + 1))
    zeros, ones = np.zeros((n, 3)), np.ones(n)
    for field, value in (("pos", np.inf), ("vel", -np.inf), ("charge", np.nan)):
        p, v, q = zeros.copy(), zeros.copy(), ones.copy()
        if field == "charge":
            q[1] = value
        else:
            (p if field == "pos" else v)[1, 2] = value
        with pytest.raises(ValueError, match=r"non-finite state for vehicle ids \[2\]"):
            as_states(ids, p, v, q)
    huge = np.full((n, 3), 1.0e308)  # the sum overflows; every value is finite
    key, p, _, _ = as_states(ids, huge, zeros, ones)
    assert key == tuple(ids) and p[0, 0] == 1.0e308


def test_time_going_backwards_does_not_move_the_leader() -> None:
    ctl = SwarmController(LawConfig(leader=Leader(force=ConstantForce((10.0, 0.0, 0.0)))))
    p, v, q = np.zeros((1, 3)), np.zeros((1, 3)), np.ones(1)
    ctl.step(1.0, [1], p, v, q)
    x1 = ctl.leader_pos_m.copy()
    ctl.step(0.5, [1], p, v, q)  # late or duplicate telemetry
    np.testing.assert_array_equal(ctl.leader_pos_m, x1)
    assert ctl.time_s == 1.0


@pytest.mark.parametrize("method", ["rotational", "classic"])
@pytest.mark.parametrize("repulsion", [False, True])
def test_degenerate_states_give_finite_commands(method: str, repulsion: bool) -> None:
    cfg = LawConfig(
        leader=Leader(force=ConstantForce((10.0, 0.0, 0.0))),
        obstacles=(BOX,),
        avoidance=Avoidance(method=method),  # type: ignore[arg-type]
        readings=Readings(repulsion_in_avoidance=repulsion),
    )
    ctl = SwarmController(cfg)
    zeros = np.zeros((6, 3))
    # Everyone coincident at the leader's centre, at rest: formation, finite.
    out = ctl.step(0.0, IDS, zeros, zeros, Q)
    assert out.behaviour == "formation" and np.all(np.isfinite(out.accel_mps2))
    # Everyone coincident at the obstacle's centre (on every field axis), at rest.
    at_box = np.tile(np.array(BOX.centre), (6, 1))
    out = ctl.step(0.02, IDS, at_box, zeros, Q)
    assert out.behaviour == "avoidance" and np.all(np.isfinite(out.accel_mps2))
    assert out.targets_m is not None and np.all(np.isfinite(out.targets_m))
    # One vehicle exactly on its slot target: Eq. 28 gives zero there, not NaN.
    on_target = at_box.copy()
    on_target[0] = out.targets_m[0]
    out = ctl.step(0.04, IDS, on_target, zeros, Q)
    assert np.all(np.isfinite(out.accel_mps2))


def test_paper_mode_drops_repulsion_during_avoidance() -> None:
    res = _pass_run()
    k = int(np.flatnonzero(res.behaviour == "avoidance")[0]) + 100
    cfg_keep = LawConfig(
        leader=res.config.leader,
        obstacles=res.config.obstacles,
        readings=Readings(repulsion_in_avoidance=True),
    )
    outs = []
    for cfg in (res.config, cfg_keep):
        ctl = SwarmController(cfg)
        for kk in (k - 100, k):
            out = ctl.step(res.times_s[kk], IDS, res.pos_m[kk], res.vel_mps[kk], Q)
        outs.append(out)
    assert outs[0].behaviour == outs[1].behaviour == "avoidance"
    rep = repulsion_force(res.pos_m[k], Q, res.config.gains.k_r) / res.config.gains.M
    np.testing.assert_allclose(outs[1].accel_mps2 - outs[0].accel_mps2, rep, atol=1e-12)
