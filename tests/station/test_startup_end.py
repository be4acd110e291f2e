"""Start-up and ending over MAVLink against the emulator (issues 6 and 14): a
mode switched before arming is set back to GUIDED, a swarm that cannot be
readied lands whoever took off and disarms whoever is on the ground,
cancellation leaves everyone holding."""

from __future__ import annotations

import asyncio
import dataclasses

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect
from station_harness import fly, lockstep_config, mission_from

from gcs_swarm.errors import StartupError
from gcs_swarm.mission import Mission
from gcs_swarm.runtime import RunSummary
from sim_vehicle import Emulator

LAND = 9


def _short(n: int, duration: float, *, ready_timeout: float = 60.0) -> Mission:
    m = mission_from("example1_octahedron.yaml", n=n, duration=duration)
    startup = dataclasses.replace(m.settings.startup, ready_timeout=ready_timeout)
    return dataclasses.replace(m, settings=dataclasses.replace(m.settings, startup=startup))


class _Pilot(asyncio.DatagramProtocol):
    """Another ground station (system 250) on the vehicle's link."""


async def _switch_mode(addr: tuple[str, int], sysid: int, mode: int) -> None:
    loop = asyncio.get_running_loop()
    transport, _ = await loop.create_datagram_endpoint(_Pilot, local_addr=("127.0.0.1", 0))
    mav = dialect.MAVLink(None, 250, 190)
    msg = mav.command_long_encode(sysid, 1, 176, 0, 1, mode, 0, 0, 0, 0, 0)
    transport.sendto(bytes(msg.pack(mav)), addr)
    transport.close()


def test_mode_switched_before_arming_is_set_back_to_guided_and_never_armed_in_land() -> None:
    mission = _short(2, 3.0)

    async def pilot_lands_vehicle_1(emu: Emulator, run: asyncio.Task[RunSummary]) -> None:
        # After the station has seen GUIDED (heartbeat at 1 s) and well before
        # the EKF is ready (10 s; the heartbeats from 2 s on show the switch,
        # and arrive before the EKF report that says ready: a margin of 8 s
        # of vehicle time, 0.4 s of wall time at the ground pace of 20 x),
        # another station switches vehicle 1 to LAND, where ArduCopter would
        # refuse to arm ("Arm: Mode not armable").
        await emu.wait_until(lambda: emu.sim_time_s >= 1.5)
        assert emu.vehicle_state(1).mode_name == "GUIDED"
        await _switch_mode(emu.endpoints[1], 1, LAND)
        await emu.wait_until(lambda: emu.vehicle_state(1).mode_name == "LAND")
        assert emu.sim_time_s < 9.0 and not emu.vehicle_state(1).armed

    # boot_s 0: no end-of-boot STABILIZE here, the pilot's switch is the test
    cfg = lockstep_config(mission, airborne=False, ekf_ready_s=10.0, boot_s=0.0)
    flown = asyncio.run(fly(mission, cfg, during=pilot_lands_vehicle_1))
    s = flown.ok
    # Seen in the HEARTBEAT: GUIDED asked again at once, no arm sent in LAND.
    assert any(
        line.startswith("vehicle 1: in LAND while") and "asking for GUIDED again" in line
        for line in s.log
    ), s.log
    assert not [line for line in s.log if "refused" in line]
    log = "\n".join(s.log)
    assert "vehicle 1: takeoff" in log and "formation started with vehicles [1, 2]" in log
    assert s.outcome == "completed"
    assert all(st.armed and st.mode_name == "BRAKE" for st in flown.states.values())


def test_vehicle_that_never_becomes_ready_stops_the_mission_cleanly() -> None:
    mission = _short(2, 30.0, ready_timeout=4.0)

    def ekf_never_ready(emu: Emulator) -> None:
        emu.set_param(2, "SIM_EKF_DELAY", 1e9)

    cfg = lockstep_config(mission, airborne=False, ekf_ready_s=1.0)
    flown = asyncio.run(fly(mission, cfg, before=ekf_never_ready))
    assert isinstance(flown.error, StartupError)
    assert str(flown.error) == "not ready after 4 s: vehicle 2 waiting"
    s = flown.summary
    assert s is not None and s.outcome == "startup failed" and s.steps == 0
    # The formation never started; vehicle 1, which had taken off, was landed.
    v1, v2 = flown.states[1], flown.states[2]
    assert v1.mode_name == "LAND" and v1.home_ned_m[2] - v1.pos_ned_m[2] > 1.0
    assert not v2.armed and v2.landed


def test_failed_start_up_disarms_a_vehicle_armed_on_the_ground() -> None:
    # Vehicle 2 arms and accepts its take-off but never leaves the ground
    # (its spool-up never ends): armed on the ground when the start-up times
    # out. It is disarmed; vehicle 1, in the air, lands. Nothing re-arms
    # vehicle 2 afterwards.
    mission = _short(2, 30.0, ready_timeout=6.0)

    def never_lifts_off(emu: Emulator) -> None:
        emu.set_param(2, "SIM_TKOFF_DLY", 1e9)

    async def settle(emu: Emulator, run: asyncio.Task[RunSummary]) -> None:
        await emu.wait_steps(250)  # 5 s of vehicle time after the ending

    cfg = lockstep_config(mission, airborne=False, ekf_ready_s=1.0)
    flown = asyncio.run(fly(mission, cfg, before=never_lifts_off, after=settle))
    assert isinstance(flown.error, StartupError)
    assert str(flown.error) == "not ready after 6 s: vehicle 2 takeoff"
    s = flown.summary
    assert s is not None and s.outcome == "startup failed"
    v1, v2 = flown.states[1], flown.states[2]
    assert v1.mode_name == "LAND" and v1.home_ned_m[2] - v1.pos_ned_m[2] > 1.0
    assert not v2.armed and v2.landed
    assert v2.mode_name == "GUIDED"  # disarmed where it stood: no LAND needed
    # Today's emulator sends no EXTENDED_SYS_STATE ("0.0 m above its EKF
    # origin, no landed state"); one that does says "(EXTENDED_SYS_STATE)".
    said = [line for line in s.log if line.startswith("vehicle 2 is on the ground (")]
    assert len(said) == 1 and said[0].endswith("): disarming it"), said
    assert {v.sysid: v.phase for v in s.vehicles}[2] == "ended"


def test_cancelling_the_run_leaves_every_vehicle_holding_with_zero_acceleration() -> None:
    mission = _short(6, 100.0)
    states_at_cancel: dict[int, object] = {}

    async def cancel_at_5_s(emu: Emulator, run: asyncio.Task[RunSummary]) -> None:
        await emu.wait_until(lambda: emu.sim_time_s >= 5.0)
        states_at_cancel.update({s: emu.vehicle_state(s) for s in range(1, 7)})
        run.cancel()

    async def settle(emu: Emulator, run: asyncio.Task[RunSummary]) -> None:
        await emu.wait_steps(250)  # 5 s of vehicle time after the ending

    flown = asyncio.run(fly(mission, lockstep_config(mission), during=cancel_at_5_s, after=settle))
    assert isinstance(flown.error, asyncio.CancelledError)
    assert flown.summary is not None and flown.summary.outcome == "cancelled"
    moving = [np.linalg.norm(st.vel_ned_m_s) for st in states_at_cancel.values()]  # type: ignore[attr-defined]
    assert max(moving) > 0.05  # they were flying the formation when cancelled
    # The last command each vehicle got from the station is zero acceleration.
    assert {v.last_accel_ned_mps2 for v in flown.summary.vehicles} == {(0.0, 0.0, 0.0)}
    for st in flown.states.values():
        assert st.mode_name == "BRAKE" and st.armed and not st.landed
        # Holding still 5 s later: BRAKE has stopped it (the emulator's own
        # braking decays exponentially; 5e-3 is far below any commanded value).
        np.testing.assert_allclose(st.accel_ned_m_s2, 0.0, atol=5e-3)
        np.testing.assert_allclose(st.vel_ned_m_s, 0.0, atol=1e-2)


@pytest.mark.parametrize("end", ["land", "rtl"])
def test_end_action_is_confirmed_by_heartbeat(end: str) -> None:
    mission = _short(2, 2.0)
    mission = dataclasses.replace(mission, settings=dataclasses.replace(mission.settings, end=end))
    flown = asyncio.run(fly(mission, lockstep_config(mission)))
    s = flown.ok
    want = {"land": "LAND", "rtl": "RTL"}[end]
    assert {v.mode for v in s.vehicles} == {want}
    assert {st.mode_name for st in flown.states.values()} == {want}
