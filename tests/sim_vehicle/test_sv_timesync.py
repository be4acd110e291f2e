"""TIMESYNC as ArduPilot answers it: a request (tc1 = 0) gets the vehicle's
boot time in ns in tc1 and the request's ts1 back; an answer is not answered.
The station's delay compensation measures round trip and clock offset so."""

from __future__ import annotations

import asyncio

from pymavlink.dialects.v20 import ardupilotmega as mav
from sv_client import connect

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec


def test_timesync_request_is_answered_with_boot_time() -> None:
    async def run() -> None:
        cfg = EmulatorConfig(vehicles=(VehicleSpec(sysid=2),), speedup=20.0)
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[2])
            c.heartbeat()
            await emu.wait_until(lambda: emu.sim_time_s >= 0.2)
            c.send(mav.MAVLink_timesync_message(tc1=0, ts1=123456789))
            reply = await c.recv("TIMESYNC")
            boot_ns = emu.sim_time_s * 1e9
            assert reply.ts1 == 123456789 and reply.get_srcSystem() == 2
            assert 0 < reply.tc1 <= boot_ns + 1  # the vehicle's boot time, ns
            assert reply.tc1 >= 0.2 * 1e9
            c.send(mav.MAVLink_timesync_message(tc1=5, ts1=1))  # an answer: not answered
            c.send(mav.MAVLink_timesync_message(tc1=0, ts1=42))
            assert (await c.recv("TIMESYNC")).ts1 == 42
            c.close()

    asyncio.run(run())
