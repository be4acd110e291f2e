"""The station's core against the emulator's autopilots in one process
(``swarm_harness.Sky``), on links that delay and duplicate, with a PX4 in the
formation, and with the station gone (the vehicles' own failsafes). Each in
well under a second; the real-UDP twins are tests/reliability
(test_lossy_links, test_station_killed, test_station_killed_px4)."""

from __future__ import annotations

import dataclasses

from swarm_harness import Sky, mission_from

from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mission import Event, Mission
from sim_vehicle import Impairment

LAND = 9
"""ArduCopter's LAND mode (the GCS failsafe's action for FS_GCS_ENABLE 5)."""


def _tetrahedron(duration: float, **autopilots: str) -> Mission:
    """Example 1's four vehicles; ``autopilots``: ``v<sysid>="px4"`` etc., each with
    its autopilot's default setpoint (the loader's: velocity+acceleration for PX4)."""
    m = mission_from("example1_tetrahedron.yaml", duration=duration)
    vehicles = []
    for v in m.vehicles:
        ap = autopilots.get(f"v{v.sysid}", v.autopilot)
        sp = "velocity+acceleration" if ap == "px4" else v.setpoint
        vehicles.append(dataclasses.replace(v, autopilot=ap, setpoint=sp))
    return dataclasses.replace(m, vehicles=tuple(vehicles))


def test_delayed_and_duplicated_links_still_form_and_hold_the_formation() -> None:
    # 20-40 ms of delay (one or two physics steps, with reordering) and 20 %
    # duplicates, both ways: each duplicated report is refused as not newer
    # (counted), so every step still answers each vehicle once.
    link = Impairment(delay_s=0.02, jitter_s=0.02, duplicate=0.2)
    sky = Sky(_tetrahedron(2.0), downlink=link, uplink=link, seed=3)
    sky.ready()
    sky.start()
    sky.run_until(lambda: sky.core.finished, 4.0)
    assert sky.core.flying == {1, 2, 3, 4}
    assert sky.stats.tx_lost == sky.stats.rx_lost == 0
    assert sky.stats.duplicated > 100  # both ways
    refused = {s: vp.stale_telemetry for s, vp in sky.core.vehicles.items()}
    # About 20 % of ~100 reports each came twice during the flight: the copies refused.
    assert all(8 <= n <= 40 for n in refused.values()), refused
    steps = sky.core.control.steps
    assert 98 <= steps <= 102, steps
    for s in (1, 2, 3, 4):
        # One setpoint per step per vehicle: duplicates never answered twice.
        assert steps - 2 <= sky.answered[s] <= steps, (s, sky.answered[s], steps)
        assert sky.vehicles[s].ap.control == "accel"  # the law flies it (no brake)
    sky.end()
    assert sky.core.outcome() == "completed"


def test_a_px4_flies_in_the_formation_with_arducopters() -> None:
    sky = Sky(_tetrahedron(2.0, v4="px4"))
    px4 = sky.vehicles[4].ap
    assert px4.mode_name == "AUTO.LOITER"  # started hovering in Hold
    sky.ready()  # taken over in Hold: no take-off
    sky.start()
    sky.run_until(lambda: sky.core.control.t_s >= 1.0, 3.0)
    # The station streamed PX4's default (velocity + acceleration) and switched it to
    # OFFBOARD; the ArduCopters fly the acceleration alone in GUIDED.
    assert px4.mode_name == "OFFBOARD" and px4.control == "vel"
    assert {sky.vehicles[s].ap.control for s in (1, 2, 3)} == {"accel"}
    assert sky.core.flying == {1, 2, 3, 4}
    sky.run_until(lambda: sky.core.finished, 3.0)
    assert sky.answered[4] >= 99 and abs(sky.answered[4] - sky.answered[1]) <= 2
    sky.end()
    assert sky.core.outcome() == "completed"
    assert px4.mode_name == "AUTO.LOITER" and px4.armed  # end: hold is PX4's Hold


def test_a_px4_reserve_takes_off_and_joins_the_formation_on_its_event() -> None:
    base = _tetrahedron(2.0)
    reserve = dataclasses.replace(
        base.vehicles[3], sysid=5, start=(1.0, 1.0, 5.0), origin=(1.0, 1.0, 4.0), reserve=True,
        autopilot="px4", setpoint="velocity+acceleration",
    )  # fmt: skip
    mission = dataclasses.replace(
        base, vehicles=(*base.vehicles, reserve), events=(Event(t=1.0, action="join", sysid=5),)
    )
    sky = Sky(mission)
    px4 = sky.vehicles[5].ap
    assert px4.mode_name == "AUTO.LOITER" and not px4.armed  # on the ground, in Hold
    # PX4's start-up in the core: its envelope read, COM_OBL_RC_ACT set, armed in
    # Hold after the pre-arm checks, an AMSL take-off, then to its start.
    sky.ready(limit_s=40.0)
    assert px4.armed and px4.params["COM_OBL_RC_ACT"] == 4
    sky.start()
    sky.run_until(lambda: sky.core.control.t_s >= 0.9, 2.0)
    assert 5 not in sky.core.flying and sky.answered[5] == 0
    sky.run_until(lambda: sky.core.finished, 3.0)
    assert "t=1.00 s: vehicle 5 joins the formation (5 flying)" in "\n".join(sky.core.log)
    assert sky.core.flying == {1, 2, 3, 4, 5}
    assert px4.mode_name == "OFFBOARD" and px4.control == "vel"
    # From its join to the end (1 s at 50 Hz), one setpoint per report.
    assert 49 <= sky.answered[5] <= 51, sky.answered
    sky.end()
    assert sky.core.outcome() == "completed"


def test_with_the_station_gone_each_vehicle_fails_safe_on_its_own() -> None:
    # Vehicle 1 an ArduCopter whose GCS failsafe the station sets (FS_GCS_ENABLE
    # 5 Land for end: hold, FS_GCS_TIMEOUT), vehicle 4 a PX4 whose offboard-loss
    # failsafe it sets (COM_OF_LOSS_T 1 s, COM_OBL_RC_ACT 4 Land).
    mission = _tetrahedron(30.0, v1="ardupilot", v4="px4")
    timeout = mission.settings.failsafe.timeout
    sky = Sky(mission)
    sky.ready()
    sky.start()
    sky.advance(0.5)
    copter, px4 = sky.vehicles[1].ap, sky.vehicles[4].ap
    assert copter.params["FS_GCS_ENABLE"] == 5 and copter.params["FS_GCS_TIMEOUT"] == timeout
    assert px4.params["COM_OF_LOSS_T"] == 1.0 and px4.params["COM_OBL_RC_ACT"] == 4
    assert copter.last_gcs_hb is not None
    sky.station_off()
    last_hb = copter.last_gcs_hb
    t_off = sky.now
    # PX4: COM_OF_LOSS_T after its last setpoint (the last step, at most 20 ms before).
    sky.run_until(lambda: px4.mode_name != "OFFBOARD", 2.0)
    assert 1.0 - 0.02 <= sky.now - t_off <= 1.0 + 0.02 + 1e-9, sky.now - t_off
    assert px4.mode_name == "AUTO.LAND" and px4.control == "land"
    # ArduCopter: GUID_TIMEOUT braked it meanwhile (still GUIDED); the GCS failsafe
    # lands it FS_GCS_TIMEOUT after the station's last HEARTBEAT.
    assert copter.mode == 4 and copter.control in ("brake", "hold")
    sky.run_until(lambda: copter.mode == LAND, timeout + 1.0)
    assert timeout <= sky.now - last_hb <= timeout + 0.02 + 1e-3, sky.now - last_hb
    assert copter.fs_active and copter.control == "land"
    # The others (the emulator's "sim" vehicles: no failsafe set) brake and hold.
    assert {sky.vehicles[s].ap.control for s in (2, 3)} <= {"brake", "hold"}
    assert all(vp.phase is Phase.FLYING for vp in sky.core.vehicles.values())  # nobody told it
