"""The land detector through the real server over UDP (the server polls an autopilot
when its vehicle touches down, not only at its deadline).

Real emulator on 127.0.0.1, port 0, real time at 10 x; every figure is in
emulator (sim) time, read from ``VehicleState`` after the steps, never from the
wall clock. One physics step (0.02 s) of tolerance on event times.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mav
from sv_client import connect

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec, VehicleState

DT = 0.02


async def _at(emu: Emulator, pred: Callable[[VehicleState], bool]) -> float:
    """Sim time of the first step after which ``pred`` holds for vehicle 1 (checked by the
    emulator right after each step, so later steps cannot blur it)."""
    seen: list[float] = []

    def check() -> bool:
        st = emu.vehicle_state(1)
        if not seen and pred(st):
            seen.append(st.sim_time_s)
        return bool(seen)

    await emu.wait_until(check)
    return seen[0]


def test_guided_descent_then_land_complete_then_disarm_delay_and_no_motion_after() -> None:
    cfg = EmulatorConfig(
        vehicles=(VehicleSpec(sysid=1),),
        speedup=10.0,
        ekf_ready_s=0.0,
        params={"DISARM_DELAY": 2, "SIM_TKOFF_DLY": 0.5, "GUID_TIMEOUT": 5.0},
    )

    async def run() -> None:
        async with asyncio.timeout(60), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            try:
                c.heartbeat()
                await c.recv("HEARTBEAT")
                assert (await c.command(1, mav.MAV_CMD_DO_SET_MODE, 1, 4)).result == 0
                assert (await c.command(1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)).result == 0
                ack = await c.command(1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)
                assert ack.result == 0
                await emu.wait_until(lambda: emu.vehicle_state(1).control == "hold")
                assert emu.vehicle_state(1).landed_state == 2
                c.accel(1, (0.0, 0.0, 0.5))  # one setpoint lasts GUID_TIMEOUT (5 s): 3.5 s down
                touchdown = await _at(emu, lambda st: st.landed)
                # the land detector: land complete 1 s after touchdown, still armed (GUIDED
                # does not disarm on landing), then DISARM_DELAY (2 s) disarms
                t1 = await _at(emu, lambda st: st.landed_state == 1)
                assert abs(t1 - touchdown - 1.0) <= DT + 1e-9
                t2 = await _at(emu, lambda st: not st.armed)
                assert abs(t2 - touchdown - 1.0 - 2.0) <= DT + 1e-9
                st = emu.vehicle_state(1)
                rest = st.pos_ned_m
                assert (await c.command(1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)).result == 0
                await emu.wait_steps(200)  # 4 s of RTL while disarmed on the ground
                st = emu.vehicle_state(1)
                assert st.mode_name == "RTL" and not st.armed
                assert st.pos_ned_m == rest and st.vel_ned_m_s == (0.0, 0.0, 0.0)
            finally:
                c.close()

    asyncio.run(run())
