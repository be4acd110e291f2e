"""The MAVLink closed loop (issue 6): the real station flies the real
emulator over UDP on 127.0.0.1 in lockstep, ideal dynamics, 50 Hz, and lands
where the in-process law does."""

from __future__ import annotations

import asyncio
import dataclasses
from functools import cache

import numpy as np
import pytest
from station_harness import fly, lockstep_config, mission_from, radii

from gcs_swarm.analysis import group_values, pairwise_distances
from gcs_swarm.mission import geodetic_at
from gcs_swarm.runtime import RunSummary
from sim_vehicle import VehicleSpec


@cache
def _example1(n: int, duration: float) -> RunSummary:
    mission = mission_from("example1_octahedron.yaml", n=n, duration=duration)
    flown = asyncio.run(fly(mission, lockstep_config(mission)))
    assert flown.emu.stats.lockstep_timeouts == 0  # every telemetry answered in time
    return flown.ok


@pytest.mark.slow
def test_example1_n6_octahedron_over_mavlink() -> None:
    s = _example1(6, 100.0)
    assert s.outcome == "completed" and s.mission_time_s == pytest.approx(100.0, abs=0.03)
    # Issue: every radius 2.48418 +- 1e-3.
    np.testing.assert_allclose(list(radii(s).values()), 2.48418, atol=1e-3)
    # The law tests' distances: 12 x 3.51316 and 3 x 4.96836. Tolerance 2e-3:
    # the tangential re-arrangement is the slowest mode (decays ~0.079 1/s,
    # measured); at 100 s the in-process RK4 run itself is 8e-4 away and this
    # 50 Hz sampled loop 1.4e-3 (measured); the law tests reach 1e-4 at 200 s.
    pos = np.array(list(s.positions().values()))
    d = pairwise_distances(pos)
    np.testing.assert_allclose(d[:12], 3.51316, atol=2e-3)
    np.testing.assert_allclose(d[12:], 4.96836, atol=2e-3)
    assert [c for _, c in group_values(d, tol=1e-2)] == [12, 3]
    # Everyone ended in the hold mode, nothing dropped or misread on the links.
    assert {v.mode for v in s.vehicles} == {"BRAKE"}
    assert (s.setpoints_dropped, s.bad_packets, s.unknown_sysid_messages) == (0, 0, 0)


@pytest.mark.slow
def test_example1_n4_tetrahedron_over_mavlink() -> None:
    s = _example1(4, 60.0)
    # Issue: 2.33359 +- 1e-3; the tetrahedron has no slow tangential mode
    # left by 60 s (in-process: 3e-11 at 200 s), so its 6 edges are checked too.
    np.testing.assert_allclose(list(radii(s).values()), 2.33359, atol=1e-3)
    d = pairwise_distances(np.array(list(s.positions().values())))
    np.testing.assert_allclose(d, 3.81074, atol=1e-3)


COMPARE_S = 30.0  # s of formation flight for run-against-run comparisons


def _positions(s: RunSummary) -> np.ndarray:
    return np.array([s.positions()[i] for i in sorted(s.positions())])


@pytest.mark.slow
def test_different_ekf_origins_fly_the_same_mission_frame_formation() -> None:
    base = _example1(6, COMPARE_S)
    mission = mission_from("example1_octahedron.yaml", duration=COMPARE_S)
    frame = mission.origin_geo()  # keep the base run's mission frame
    assert frame is not None
    rng = np.random.default_rng(6)
    # Homes tens of metres apart east/north and a few metres apart in height,
    # all on the ground below the formation (mission-frame offsets, metres).
    homes = [
        geodetic_at(frame, (rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(-23, -17)))
        for _ in range(6)
    ]
    mission = dataclasses.replace(
        mission,
        settings=dataclasses.replace(mission.settings, origin=frame),
        vehicles=tuple(
            dataclasses.replace(v, origin=h) for v, h in zip(mission.vehicles, homes, strict=True)
        ),
    )
    flown = asyncio.run(fly(mission, lockstep_config(mission)))
    s = flown.ok
    spread = np.ptp([flown.states[i].origin for i in range(1, 7)], axis=0)
    assert min(spread[:2]) > 3e-4  # degrees, i.e. more than 30 m apart
    assert flown.emu.stats.lockstep_timeouts == 0
    # Same mission-frame result. 1e-4 m: LOCAL_POSITION_NED is float32, whose
    # rounding at tens of metres (~4e-6 m) is the only difference between the
    # two loops, and the converging closed loop does not amplify it.
    np.testing.assert_allclose(_positions(s), _positions(base), atol=1e-4)


@pytest.mark.slow
def test_several_system_ids_on_one_link_fly_like_one_link_each() -> None:
    base = _example1(6, COMPARE_S)
    mission = mission_from("example1_octahedron.yaml", duration=COMPARE_S)
    cfg = lockstep_config(mission, shared_port=0)
    # A seventh vehicle the mission does not name, on the ground, on the same link.
    cfg = dataclasses.replace(cfg, vehicles=(*cfg.vehicles, VehicleSpec(sysid=42)))
    flown = asyncio.run(fly(mission, cfg))
    s = flown.ok
    assert len(set(flown.endpoints.values())) == 1  # one UDP endpoint, seven system ids
    assert flown.emu.stats.lockstep_timeouts == 0
    # Its traffic (HEARTBEAT at 1 Hz) was counted and ignored; nobody commanded it.
    assert s.unknown_sysid_messages > 0
    assert any("ignoring traffic from system 42" in line for line in s.log)
    assert flown.states[42].mode_name == "STABILIZE" and not flown.states[42].armed
    # Lockstep makes the telemetry a pure function of the answers (sim_vehicle
    # docstring), so one shared link gives the very same flight.
    np.testing.assert_array_equal(_positions(s), _positions(base))


def test_mission_origin_learnt_from_the_first_real_vehicle() -> None:
    # Real vehicles and "origin: first-vehicle": the station takes vehicle 1's
    # GPS_GLOBAL_ORIGIN as the mission origin and offsets the others from it.
    m = mission_from("example1_octahedron.yaml", n=2, duration=5.0)
    leader = dataclasses.replace(m.law.leader, start=(0.0, 0.0, 10.0))
    vehicles = tuple(
        dataclasses.replace(v, link="udpout:127.0.0.1:9", autopilot="ardupilot", origin=None,
                            start=(v.start[0], v.start[1], 10.0 + v.start[2]))
        for v in m.vehicles
    )  # fmt: skip
    # The emulator does not answer SYSID_MYGCS, FENCE_* or the envelope's
    # parameters yet: off for these "real" vehicles (docs/vehicle-safety.md).
    off = dataclasses.replace(m.settings.failsafe, gcs=False, fence=False)
    startup = dataclasses.replace(m.settings.startup, read_envelope=False)
    settings = dataclasses.replace(
        m.settings, origin="first-vehicle", failsafe=off, startup=startup
    )
    mission = dataclasses.replace(
        m, vehicles=vehicles, settings=settings, law=dataclasses.replace(m.law, leader=leader)
    )
    assert mission.origin_geo() is None
    home = (-35.363261, 149.165230, 584.0)
    east_5m = (home[0], home[1] + 5.0 / (6378137.0 * np.cos(np.radians(home[0]))) * 180 / np.pi)
    second = (round(east_5m[0] * 1e7) / 1e7, round(east_5m[1] * 1e7) / 1e7, 584.0)
    specs = (
        VehicleSpec(sysid=1, origin=home, start_ned_m=(1.0, 2.0, -12.0), airborne=True),
        VehicleSpec(sysid=2, origin=second, start_ned_m=(-1.0, -6.0, -9.0), airborne=True),
    )
    cfg = dataclasses.replace(lockstep_config(m), vehicles=specs)
    s = asyncio.run(fly(mission, cfg)).ok
    log = "\n".join(s.log)
    assert "mission origin = vehicle 1's EKF origin" in log
    assert "vehicle 2: frame offset +5.00 E +0.00 N +0.00 U m" in log
    assert s.outcome == "completed" and s.steps > 0
    # The NED starts above are the mission starts in each vehicle's own frame:
    # with the learnt offsets both were found at their start points at once.
    assert "vehicle 1: ready" in log and "vehicle 2: ready" in log
