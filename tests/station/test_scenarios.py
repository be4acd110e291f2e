"""Obstacle avoidance and an ArduPilot-like vehicle over MAVLink (issue 6)."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from station_harness import fly, lockstep_config, mission_from, radii

from gcs_swarm.integrator import integrate


@pytest.mark.slow
def test_scenario3_every_vehicle_passes_the_box_and_the_formation_re_forms() -> None:
    mission = mission_from("scenario3_obstacle.yaml")  # 60 s, box centred (20, 15, 5)
    flown = asyncio.run(fly(mission, lockstep_config(mission)))
    s = flown.ok
    assert flown.emu.stats.lockstep_timeouts == 0
    # One avoidance episode, started and ended, then Eq. 12 again.
    assert s.episodes == 1 and s.behaviour == "formation"
    log = "\n".join(s.log)
    assert "avoidance episode 1 starts" in log and "avoidance episode 1 ends" in log
    box = mission.law.obstacles[0]
    beyond = box.centre[0] + box.half_extents[0]
    pos = np.array([s.positions()[i] for i in range(1, 5)])
    assert (pos[:, 0] > beyond + 30.0).all()  # every vehicle is far past the box
    # Re-formed where the in-process law (RK4, same 50 Hz step) puts it. 0.25 m:
    # the episode's switch and plane choice are sampled at 50 Hz here; measured
    # 0.09 m after 60 s at ~1 m/s (0.11 m while the look-ahead still landed a
    # few steps late from its worker thread in lockstep too).
    ref = integrate(mission.law, [v.start for v in mission.vehicles], duration=60.0, dt=0.02)
    np.testing.assert_allclose(pos, ref.pos_m[-1], atol=0.25)
    np.testing.assert_allclose(s.leader_pos_m, ref.leader_pos_m[-1], atol=0.25)
    ref_r = np.linalg.norm(ref.pos_m[-1] - ref.leader_pos_m[-1], axis=1)
    np.testing.assert_allclose(list(radii(s).values()), ref_r, atol=0.05)
    # The paper's law gives no clearance guarantee (formation-law.md s11): it is
    # measured and reported, not asserted positive here (the safety filter's job).
    assert np.isfinite(s.min_clearance_m)


def test_a_lockstep_run_with_the_plane_look_ahead_is_repeatable_bit_for_bit() -> None:
    """Lockstep promises exact, repeatable closed loops. With ``plane: auto``
    the look-ahead ran in a worker thread and its result landed at whatever
    step the wall clock allowed: three runs of Scenario 3 ended up to 4e-5 m
    apart. In lockstep the station now runs it at its step (the emulator
    waits for it): the same floats every run."""
    mission = mission_from("scenario3_obstacle.yaml", duration=20.0)  # episode from ~12 s
    runs = [asyncio.run(fly(mission, lockstep_config(mission))).ok for _ in range(2)]
    for s in runs:
        assert "avoidance episode 1 starts" in "\n".join(s.log)
    a, b = (np.array([s.positions()[i] for i in range(1, 5)]) for s in runs)
    assert a.tobytes() == b.tobytes()


@pytest.mark.slow
def test_ardupilot_like_lag_settles_within_2_percent() -> None:
    mission = mission_from("example1_octahedron.yaml", duration=30.0)
    # ArduCopter-like 0.2 s first-order acceleration lag, in lockstep: the lag
    # acts in vehicle time, exactly. (This test used to be paced by the wall
    # clock at 5 x real time; on a loaded 2-core machine the process could not
    # keep that pace, measured: 1617 of 1624 emulator steps late, radii
    # 1.4-17.7 m, and 1570 of 1625 late at 1 x real time: loop delay that the
    # machine adds, not the law. Real-time pacing with delay is
    # test_delay_compensation's subject.)
    # The lag alone (accel_shaping off): the paper's gains ask for more than the
    # jerk-limited ArduCopter model can do, as on SITL (example1_arducopter.yaml
    # and docs/vehicle-envelope.md fly Example 1 within it).
    cfg = lockstep_config(mission, dynamics="ardupilot", accel_shaping=False, accel_tau_s=0.2)
    assert cfg.tau_s == pytest.approx(0.2)
    flown = asyncio.run(fly(mission, cfg))
    s = flown.ok
    assert s.mission_time_s == pytest.approx(30.0, abs=0.1)
    r = np.array(list(radii(s).values()))
    # Issue: within 2 % of the radius 2.48418.
    assert np.abs(r / 2.48418 - 1.0).max() < 0.02, r
    # In lockstep every telemetry is answered by one setpoint before the next.
    assert s.setpoints_dropped == 0 and flown.emu.stats.lockstep_timeouts == 0
