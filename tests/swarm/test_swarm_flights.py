"""The station's core flown against the emulator's autopilots in one process
(``swarm_harness.Sky``, a hand-advanced clock): join, leave, lossy links,
spoofing and a vehicle that stops answering, each in well under a second.
The real-UDP end-to-end twins stay in tests/station and tests/reliability."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav
from swarm_harness import Sky, address, mission_from

from gcs_swarm.control import ConstantForce
from gcs_swarm.mavlink.coordinates import ned_to_mission
from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mission import Event, Mission
from sim_vehicle import Impairment


def _tetrahedron(duration: float, **changes: object) -> Mission:
    m = mission_from("example1_tetrahedron.yaml", duration=duration)
    return dataclasses.replace(m, **changes)  # type: ignore[arg-type]


def test_a_reserve_joins_on_its_event_and_gets_setpoints() -> None:
    base = _tetrahedron(3.0)
    reserve = dataclasses.replace(
        base.vehicles[3], sysid=5, start=(1.0, 1.0, 5.0), origin=(1.0, 1.0, 4.0), reserve=True
    )
    mission = dataclasses.replace(
        base, vehicles=(*base.vehicles, reserve), events=(Event(t=1.0, action="join", sysid=5),)
    )
    sky = Sky(mission)
    assert not sky.vehicles[5].ap.armed  # a reserve waits on the ground
    sky.ready()  # the reserve too: armed, took off, holding at its start
    sky.start()
    assert sky.core.flying == {1, 2, 3, 4}
    sky.run_until(lambda: sky.core.control.t_s >= 0.9, 2.0)
    assert 5 not in sky.core.flying and sky.answered[5] == 0
    sky.run_until(lambda: sky.core.finished, 5.0)
    log = "\n".join(sky.core.log)
    assert "t=1.00 s: vehicle 5 joins the formation (5 flying)" in log
    assert sky.core.flying == {1, 2, 3, 4, 5}
    # From its join to the end (2 s at 50 Hz), one setpoint per report.
    assert 99 <= sky.answered[5] <= 101 and sky.answered[1] >= 149
    sky.end()
    assert sky.core.outcome() == "completed"


def test_a_vehicle_leaves_on_its_event_and_the_rest_fly_on() -> None:
    mission = _tetrahedron(2.0, events=(Event(t=1.0, action="leave", sysid=2),))
    sky = Sky(mission)
    sky.ready()
    sky.start()
    sky.run_until(lambda: sky.core.finished, 4.0)
    log = "\n".join(sky.core.log)
    assert "t=1 s: vehicle 2 leaves" in log
    assert "vehicle 2 out of the formation (ending); 3 re-form" in log
    assert sky.core.flying == {1, 3, 4} and sky.core.left == {2}
    assert sky.core.vehicles[2].phase in (Phase.ENDING, Phase.ENDED)
    n = sky.answered
    assert 49 <= n[2] <= 51 and min(n[s] for s in (1, 3, 4)) >= 99, n
    sky.end()
    assert sky.core.outcome() == "completed"


def test_lossy_links_fly_on_without_losing_anyone() -> None:
    # 20 % of the datagrams each way lost (seeded): the step runs on the
    # fallback when a report is missing; nobody goes stale (1 s without a
    # report would take 50 losses in a row).
    lossy = Impairment(loss=0.2)
    sky = Sky(_tetrahedron(3.0), downlink=lossy, uplink=lossy, seed=7)
    sky.ready()
    sky.start()
    rx_lost0 = sky.stats.rx_lost
    sky.run_until(lambda: sky.core.finished, 5.0)
    assert sky.stats.tx_lost > 100 and sky.stats.rx_lost > 100
    assert sky.core.flying == {1, 2, 3, 4}
    # The missing reports cost no step: 50 Hz over 3 s, a step on the
    # fallback (half a period) when a report is missing.
    assert 148 <= sky.core.control.steps <= 151
    for s in sky.vehicles:
        # One setpoint per report that came through (about 80 %) ...
        assert 0.7 * 150 <= sky.answered[s] <= 0.9 * 150, sky.answered
    # ... of which about 80 % came through in turn (each its own datagram).
    sent = sum(sky.answered.values())
    lost = sky.stats.rx_lost - rx_lost0
    assert 0.1 * sent <= lost <= 0.3 * sent, (lost, sent)
    sky.end()
    assert sky.core.outcome() == "completed"


def test_a_frame_for_a_bound_vehicle_from_another_address_is_refused_and_counted() -> None:
    sky = Sky(_tetrahedron(2.0))
    sky.ready()
    sky.start()
    sky.advance(0.5)
    forger = mav.MAVLink(None, 2, 1)  # vehicle 2's system id, from elsewhere
    stray = ("10.6.6.6", 4242)
    for k in range(10):
        lpn = forger.local_position_ned_encode(10**6 + k, 99.0, 99.0, -99.0, 0, 0, 0)
        sky.inject(stray, bytes(lpn.pack(forger)))
    sky.transfer()
    assert sky.link.stats.spoofed == 10 and sky.link.rebinds_refused == {2: 10}
    assert sky.notices == [
        f"{sky.link.name}: frames of vehicle 2 from 10.6.6.6:4242 refused: it is bound to "
        f"{address(2)[0]}:{address(2)[1]} for the run (silent 0.0 s)"
    ]  # once per vehicle, not per frame
    assert sky.link.peer_count == 4  # the forger got no codec
    sky.run_until(lambda: sky.core.finished, 3.0)
    # The real vehicle 2 flew on: its reports were taken, the forged ones never.
    assert sky.core.flying == {1, 2, 3, 4}
    pos = sky.core.vehicles[2].position
    assert pos is not None and abs(pos.x) < 50
    assert sky.answered[2] >= 99


def test_a_vehicle_that_stops_answering_leaves_and_the_rest_go_on() -> None:
    mission = _tetrahedron(4.0)
    sky = Sky(mission)
    sky.ready()
    sky.start()
    sky.advance(1.0)
    sky.set_silent(3)
    t_off = sky.now
    sky.run_until(lambda: 3 not in sky.core.flying, 3.0)
    lost_after = sky.now - t_off
    stale = sky.core.config.protocol_config().stale_timeout_s
    assert stale <= lost_after <= stale + 0.1
    assert sky.core.vehicles[3].phase is Phase.LOST
    log = "\n".join(sky.core.log)
    assert "vehicle 3 out of the formation (lost); 3 re-form" in log
    heard = dict(sky.answered)
    sky.run_until(lambda: sky.core.finished, 4.0)
    assert sky.core.flying == {1, 2, 4}
    # The three went on at the full rate: each step waited for them only.
    for s in (1, 2, 4):
        assert sky.answered[s] - heard[s] >= 50 * (4.0 - 1.0 - lost_after) - 2
    assert sky.answered[3] == heard[3]
    sky.end()
    assert sky.core.outcome() == "degraded"


def test_a_vehicle_lost_while_it_ends_is_ended_when_heard_again_not_readied() -> None:
    """Measured on a stalled shard at its ending (CHANGELOG.md, "Benchmark
    history"): 196 of 500 vehicles heard nothing for the heartbeat timeout,
    went LOST, and when heard again were readied from scratch (CONFIGURING:
    streams, parameters, then GUIDED) instead of ended. A vehicle the
    station is ending that comes back gets its end mode, confirmed (BRAKE
    here: ArduCopter mode 17)."""
    sky = Sky(_tetrahedron(30.0))
    sky.ready()
    sky.start()
    sky.advance(1.0)
    sky.set_silent(3)
    sky.core.finish_all(sky.now)
    sky.transfer()
    vp = sky.core.vehicles[3]
    sky.run_until(lambda: vp.phase is Phase.LOST, 5.0)
    assert vp.phase is Phase.LOST
    sky.set_silent(3, False)
    sky.run_until(lambda: vp.phase in (Phase.ENDED, Phase.FAILED), 5.0)
    assert vp.phase is Phase.ENDED, (vp.phase, vp.failure)
    assert sky.vehicles[3].ap.mode == 17  # BRAKE, as the others
    assert {v.phase for v in sky.core.vehicles.values()} == {Phase.ENDED}


def _silent_then_rejoined(
    sky: Sky, sysid: int, silent_s: float, limit_s: float
) -> tuple[float, set[str]]:
    """Vehicle ``sysid`` silent until the core calls it lost and ``silent_s``
    [s] more, then heard again; fly until it is in the formation again
    (fail after ``limit_s`` [s]). Returns the mission time it was heard
    again at [s] and the controls its autopilot flew meanwhile
    (``Autopilot.control``)."""
    core = sky.core
    sky.set_silent(sysid)
    sky.run_until(lambda: sysid not in core.flying, 3.0)
    sky.advance(silent_s)
    assert sysid not in core.flying and not core.finished
    sky.set_silent(sysid, False)
    t_back = core.control.t_s
    ap, controls = sky.vehicles[sysid].ap, set()

    def rejoined() -> bool:
        controls.add(ap.control)
        return sysid in core.flying

    sky.run_until(rejoined, limit_s)
    return t_back, controls


def test_a_vehicle_heard_again_rejoins_a_moving_formation() -> None:
    """Scenario 3 with the safety filter, its leader moving at 1-1.4 m/s:
    vehicle 3 goes silent for 6 s. Heard again, it is taken over in the air
    and flies to its rejoin point (the safety separation outside the
    formation on its slot's ray) with the leader's velocity as the
    setpoint's feed-forward (GUIDED pos-vel, type_mask 3520); READY asks for
    the leader's velocity, not rest, so it rejoins (before, READY asked for
    0.3 m/s absolute and it chased its slot to the mission's end). Measured:
    heard again at 26.0 s, in the formation 5.7 s later."""
    sky = Sky(mission_from("scenario3_safety.yaml", duration=60.0))
    core = sky.core
    sky.ready()
    sky.start()
    sky.run_until(lambda: core.control.t_s >= 20.0, 30.0)
    # Bound 10 s: 1.75 times the measured 5.7 s (the hand clock repeats it
    # exactly; the margin is for changes in the take-over's reads).
    t_back, controls = _silent_then_rejoined(sky, 3, 5.0, 10.0)
    assert "posvel" in controls, controls  # it chased a moving point, not a fixed one
    speed = float(np.linalg.norm(core.control.controller.leader_vel_mps))
    assert speed > 0.9  # the formation was moving when it came back
    log = "\n".join(core.log)
    assert f"vehicle {core.vehicles[3].label} joins the formation (4 flying)" in log
    # While unheard the others kept out of its column (Eq. K1); heard, no longer.
    assert "vehicle 3 left unheard, still in the air" in log
    assert "vehicle 3 heard again: the others no longer keep out" in log
    assert core.control.keep_out == {}
    assert core.control.t_s - t_back < 10.0
    sky.run_until(lambda: core.finished, 40.0)
    assert core.flying == {1, 2, 3, 4}
    # The safety filter keeps its 1 m all along, through the rejoin.
    assert core.control.min_separation_m > 1.0


def test_an_emulated_px4_heard_again_rejoins_a_moving_formation() -> None:
    """The same on the emulator's PX4 (OFFBOARD): the tetrahedron's leader
    pushed to 0.67 m/s, vehicle 3 silent 3 s. PX4's offboard-loss failsafe
    acts meanwhile (COM_OF_LOSS_T 1 s); heard again, it is taken over in the
    air (OFFBOARD asked after the pre-stream), flies pos-vel setpoints to its
    rejoin point and rejoins. Measured: heard again at 19.02 s, in the
    formation at 26.78 s; bound 15 s after it is heard again."""
    m = mission_from("px4_tetrahedron.yaml", duration=60.0)
    leader = dataclasses.replace(m.law.leader, force=ConstantForce((10.0, 0.0, 0.0)))
    sky = Sky(dataclasses.replace(m, law=dataclasses.replace(m.law, leader=leader)))
    core = sky.core
    sky.ready()
    sky.start()
    sky.run_until(lambda: core.control.t_s >= 15.0, 30.0)
    assert float(np.linalg.norm(core.control.controller.leader_vel_mps)) > 0.6
    _, controls = _silent_then_rejoined(sky, 3, 3.0, 15.0)
    assert "posvel" in controls, controls
    sky.run_until(lambda: core.finished, 60.0)
    assert core.flying == {1, 2, 3, 4}


def _closest_members(sky: Sky, away: int, seconds: float, each: Callable[[], object]) -> float:
    """Fly ``seconds`` [s] step by step (``each`` after every step) and return
    how close any member came to vehicle ``away``: the emulator's truth, in
    the mission frame."""
    core = sky.core
    fleet = sky.vehicles[away].radio.emu.fleet  # type: ignore[union-attr]
    rows = {s: v.hosted.row for s, v in sky.vehicles.items()}

    def where(sysid: int) -> np.ndarray:
        return ned_to_mission(fleet.pos[rows[sysid]], core.vehicles[sysid].offset_m)

    closest = math.inf
    for _ in range(round(seconds / sky.dt)):
        sky.advance(sky.dt)
        each()
        there = where(away)
        for s in core.flying - {away}:
            closest = min(closest, float(np.linalg.norm(where(s) - there)))
    return closest


@pytest.mark.parametrize(
    ("mission", "lost_id", "lost_at_s"),
    [
        ("example1_octahedron.yaml", 1, 60.0),
        ("example1_octahedron.yaml", 5, 60.0),
        ("example1_tetrahedron.yaml", 1, 60.0),
        ("scenario3_safety.yaml", 2, 20.0),
    ],
)
def test_a_lost_vehicle_s_failsafe_descent_keeps_the_separation(
    mission: str, lost_id: int, lost_at_s: float
) -> None:
    """The safety filter on (1 m separation) and the vehicles' own GCS-loss
    failsafe set (``failsafe.gcs``, as on real vehicles: Land 5 s after the
    station's last HEARTBEAT). One vehicle loses its radio; the others
    re-form, and 5 s later it lands straight down, for Example 1's vehicle
    1 onto vehicle 6 (3.5 m below it and 0.23 m aside as the octahedron
    formed). Every member must stay at least the separation from it (the
    emulator's truth) while it comes down: they keep out of its column
    (Eq. K1, docs/vehicle-safety.md). Measured before the column
    (2026-12-04): 0.068 m from vehicle 6 in Example 1 (filter off: 0.05 m),
    vehicle 5 lost 0.56 m, the tetrahedron's vehicle 1 1.33 m; Scenario 3,
    whose leader moves on, 3.2-4.6 m."""
    m = mission_from(mission, duration=lost_at_s + 30.0)
    m = dataclasses.replace(
        m,
        settings=dataclasses.replace(
            m.settings, failsafe=dataclasses.replace(m.settings.failsafe, gcs=True)
        ),
        law=dataclasses.replace(m.law, safety=dataclasses.replace(m.law.safety, enabled=True)),
    )
    sky = Sky(m)
    core = sky.core
    sky.ready()
    sky.start()
    sky.run_until(lambda: core.control.t_s >= lost_at_s, lost_at_s + 10.0)
    sky.set_silent(lost_id)
    landing: list[str] = []
    closest = _closest_members(sky, lost_id, 20.0, lambda: landing.append(
        sky.vehicles[lost_id].ap.control))  # fmt: skip
    assert "land" in landing and core.vehicles[lost_id].phase is Phase.LOST  # the scenario happened
    assert lost_id in core.control.keep_out
    print(
        f"closest member to the lost vehicle: {closest:.3f} m; to its column "
        f"{core.control.min_keep_out_m:.3f} m"
    )
    assert closest >= m.law.safety.separation, closest


@pytest.mark.parametrize("end", ["land", "hold"])
def test_a_vehicle_that_leaves_and_flies_on_is_kept_out_of(end: str) -> None:
    """Example 1 with the filter on (1 m separation): vehicle 1, an upper
    vertex with vehicle 6 3.5 m below it, leaves on an event at 60 s with the
    mission's ``end``: LAND brings it straight down through the formation,
    Hold keeps it where it stopped while the others re-form. The station
    still hears it: the others keep the separation from its column at its
    latest report (Eq. K1) until it is on the ground (the emulator's truth
    checked every step). Measured (2026-12-04): LAND 1.944 m, Hold 2.454 m;
    without the column LAND passed 0.101 m from vehicle 6 (Hold 2.966 m)."""
    m = mission_from("example1_octahedron.yaml", duration=130.0)
    leave = (Event(60.0, "leave", 1),)
    m = dataclasses.replace(
        m,
        settings=dataclasses.replace(m.settings, end=end),
        law=dataclasses.replace(m.law, safety=dataclasses.replace(m.law.safety, enabled=True)),
        events=leave,
    )
    sky = Sky(m)
    core = sky.core
    sky.ready()
    sky.start()
    sky.run_until(lambda: core.control.t_s >= 59.5, 70.0)
    kept: list[bool] = []
    closest = _closest_members(sky, 1, 60.0, lambda: kept.append(1 in core.control.live_keep_out))
    assert 1 not in core.flying and any(kept)  # it left, and was kept out of
    log = "\n".join(core.log)
    assert "vehicle 1 out of the formation and in the air" in log
    if end == "land":  # down: no column any more
        assert sky.vehicles[1].ap.control == "ground" or core.vehicles[1].on_ground
        assert 1 not in core.control.live_keep_out
    else:
        assert 1 in core.control.live_keep_out
    print(f"end {end}: closest member to the vehicle that left {closest:.3f} m")
    assert closest >= m.law.safety.separation, closest


def test_a_reserve_holding_at_its_start_is_kept_out_of_until_it_joins() -> None:
    """Scenario 2 with the filter on: the reserve holds at its start ahead of
    the moving formation until its join at 25 s. Until then the members keep
    the separation from where it may be (the cube of Eq. K1c: it does not
    come down), at its latest report; once it joins it is a member, kept
    apart by the pair rows instead."""
    m = mission_from("scenario2_join.yaml", duration=30.0)
    m = dataclasses.replace(
        m, law=dataclasses.replace(m.law, safety=dataclasses.replace(m.law.safety, enabled=True))
    )
    sky = Sky(m)
    core = sky.core
    sky.ready()
    sky.start()
    sky.run_until(lambda: core.control.t_s >= 1.0, 5.0)
    box = core.control.live_keep_out[5]
    fleet = sky.vehicles[5].radio.emu.fleet  # type: ignore[union-attr]
    where = ned_to_mission(fleet.pos[sky.vehicles[5].hosted.row], core.vehicles[5].offset_m)
    np.testing.assert_allclose(box.centre, where, atol=0.05)  # its report, at 50 Hz
    assert box.half_extents[2] == pytest.approx(box.half_extents[0])  # not a column
    assert "vehicle 5 out of the formation and in the air" in "\n".join(core.log)
    sky.run_until(lambda: 5 in core.flying, 30.0)
    sky.advance(0.1)
    assert 5 not in core.control.live_keep_out and core.control.keep_outs_taken == 1
