"""Protocol-level tests: raw pymavlink over UDP on 127.0.0.1 against the emulator."""

from __future__ import annotations

import asyncio
import itertools

from pymavlink.dialects.v20 import ardupilotmega as mav
from sv_client import connect

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec
from sim_vehicle.params import PARAM_TABLE

# boot_s 0: this walks the sheet's steps one by one; the end-of-boot return to
# STABILIZE that makes a station set GUIDED again is tested on its own
# (test_sv_vehicle_life.test_boot_ends_in_stabilize_after_guided_was_accepted).
FAST = {"speedup": 20.0, "ekf_ready_s": 4.0, "boot_s": 0.0}


def test_startup_sequence_of_the_protocol_sheet() -> None:
    async def run() -> None:
        cfg = EmulatorConfig(vehicles=(VehicleSpec(sysid=3),), **FAST)  # type: ignore[arg-type]
        async with asyncio.timeout(30), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[3])
            c.heartbeat()
            hb = await c.recv("HEARTBEAT")  # 1. heartbeat: ids, autopilot, mode, armed flag
            assert (hb.get_srcSystem(), hb.type, hb.autopilot) == (3, 2, 3)
            assert not hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
            for msgid, us in ((32, 20000), (193, 500000), (24, 500000)):  # 2. streams
                assert (await c.command(3, 511, msgid, us)).result == mav.MAV_RESULT_ACCEPTED
            early = await c.command(3, 512, 49)  # origin not set yet
            assert early.result == mav.MAV_RESULT_FAILED
            assert (await c.command(3, 176, 1, 4)).result == mav.MAV_RESULT_ACCEPTED  # 3. GUIDED
            assert (await c.recv("HEARTBEAT")).custom_mode == 4
            refused = await c.command(3, 400, 1)  # 5. too early: refused with a reason
            assert refused.result == mav.MAV_RESULT_FAILED
            await c.recv("EKF_STATUS_REPORT", lambda m: m.flags & 0x3F == 0x3F)  # 4. ready
            await c.recv("GPS_RAW_INT", lambda m: m.fix_type >= 3)
            assert (await c.command(3, 512, 49)).result == mav.MAV_RESULT_ACCEPTED
            origin = await c.recv("GPS_GLOBAL_ORIGIN")
            assert origin.latitude == round(-35.363261e7)
            assert (await c.command(3, 400, 1)).result == mav.MAV_RESULT_ACCEPTED
            hb = await c.recv("HEARTBEAT")
            assert hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
            assert (await c.command(3, 22, 0, 0, 0, 0, 0, 0, 10)).result == 0  # 6. takeoff
            t0 = emu.sim_time_s
            up = await c.recv("LOCAL_POSITION_NED", lambda m: m.z < -9.5)
            # sheet: 9.5 m reached 9.4 s after the takeoff; 1 s tolerance on the profile
            assert abs(up.time_boot_ms / 1000 - t0 - 9.4) < 1.0
            await emu.wait_until(lambda: abs(emu.vehicle_state(3).vel_ned_m_s[2]) < 0.02)
            assert (await c.command(3, 511, 85, 100000)).result == 0  # ask for the echo
            for _ in range(10):  # 7. stream setpoints
                await c.recv("LOCAL_POSITION_NED")
                c.accel(3, (0.5, -0.25, 0.0))
            echo = await c.recv("POSITION_TARGET_LOCAL_NED", lambda m: m.afx != 0)
            assert echo.type_mask == 3135 and (echo.afx, echo.afy, echo.afz) == (0.5, -0.25, 0.0)
            c.close()

    asyncio.run(run())


def test_refusals_carry_statustext_and_unknown_commands_are_unsupported() -> None:
    async def run() -> None:
        cfg = EmulatorConfig(vehicles=(VehicleSpec(sysid=1),), speedup=20.0, ekf_ready_s=100)
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            assert (await c.command(1, 400, 1)).result == mav.MAV_RESULT_FAILED
            assert c.texts[-1].startswith("PreArm:")  # sent just before the ACK
            assert (await c.command(1, 176, 1, 9)).result == 0  # LAND
            assert (await c.command(1, 400, 1, 2989)).result == mav.MAV_RESULT_FAILED
            assert c.texts[-1] == "Arm: Mode not armable"
            assert (await c.command(1, 22, 0, 0, 0, 0, 0, 0, 5)).result == mav.MAV_RESULT_FAILED
            assert (await c.command(1, 176, 1, 99)).result == mav.MAV_RESULT_FAILED
            assert (await c.command(1, 183, 1, 1500)).result == mav.MAV_RESULT_UNSUPPORTED
            c.close()

    asyncio.run(run())


def test_message_intervals_in_sim_time() -> None:
    async def run() -> None:
        cfg = EmulatorConfig(vehicles=(VehicleSpec(sysid=1),), speedup=20.0)
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            await emu.wait_steps(5)
            assert not any(m.get_type() == "LOCAL_POSITION_NED" for m in _drain(c))  # not asked
            await c.command(1, 511, 32, 100000)  # 10 Hz
            times = [(await c.recv("LOCAL_POSITION_NED")).time_boot_ms for _ in range(6)]
            assert {b - a for a, b in itertools.pairwise(times[1:])} == {100}
            await c.command(1, 511, 32, 0)  # default rate: 10 Hz
            await c.command(1, 511, 32, -1)  # off
            _drain(c)
            await emu.wait_steps(10)
            assert not any(m.get_type() == "LOCAL_POSITION_NED" for m in _drain(c))
            c.send(c.mav.command_long_encode(1, 1, 510, 0, 32, 0, 0, 0, 0, 0, 0))
            assert (await c.recv("MESSAGE_INTERVAL")).interval_us == -1
            c.close()

    asyncio.run(run())


def _drain(c: object) -> list[object]:
    q = c.queue  # type: ignore[attr-defined]
    out = []
    while not q.empty():
        out.append(q.get_nowait())
    return out


def test_parameters_list_read_and_set() -> None:
    async def run() -> None:
        cfg = EmulatorConfig(vehicles=(VehicleSpec(sysid=4),), speedup=20.0)
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[4])
            c.heartbeat()
            c.send(c.mav.param_request_list_encode(4, 1))
            got = [await c.recv("PARAM_VALUE") for _ in PARAM_TABLE]
            assert sorted(m.param_index for m in got) == list(range(len(PARAM_TABLE)))
            assert {m.param_id for m in got} == set(PARAM_TABLE)
            assert {m.param_id: m.param_value for m in got}["SYSID_THISMAV"] == 4
            c.send(c.mav.param_set_encode(4, 1, b"GUID_TIMEOUT", 0.5, 9))
            reply = await c.recv("PARAM_VALUE")
            assert (reply.param_id, reply.param_value) == ("GUID_TIMEOUT", 0.5)
            assert emu.vehicle_state(4).params["GUID_TIMEOUT"] == 0.5
            c.send(c.mav.param_set_encode(4, 1, b"NO_SUCH_PARAM", 1.0, 9))
            c.send(c.mav.param_request_read_encode(4, 1, b"WP_YAW_BEHAVIOR", -1))
            by_name = await c.recv("PARAM_VALUE")  # the unknown name got no reply
            assert (by_name.param_id, by_name.param_value) == ("WP_YAW_BEHAVIOR", 2.0)
            c.send(c.mav.param_request_read_encode(4, 1, b"", 1))
            assert (await c.recv("PARAM_VALUE")).param_id == "GUID_TIMEOUT"
            c.close()

    asyncio.run(run())


def test_several_sysids_on_one_endpoint() -> None:
    async def run() -> None:
        specs = tuple(VehicleSpec(sysid=s) for s in (11, 12, 13))
        cfg = EmulatorConfig(vehicles=specs, shared_port=0, speedup=20.0)
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            assert len(set(emu.endpoints.values())) == 1
            c = await connect(emu.endpoints[11])
            c.heartbeat()
            seen = {(await c.recv("HEARTBEAT")).get_srcSystem() for _ in range(3)}
            assert seen == {11, 12, 13}
            ack = await c.command(12, 176, 1, 5)
            assert ack.get_srcSystem() == 12 and ack.result == 0
            await emu.wait_steps(2)
            modes = {s: emu.vehicle_state(s).mode for s in (11, 12, 13)}
            assert modes == {11: 0, 12: 5, 13: 0}
            c.close()

    asyncio.run(run())


def test_add_and_remove_vehicles_at_run_time() -> None:
    async def run() -> None:
        cfg = EmulatorConfig(vehicles=(VehicleSpec(sysid=1),), speedup=20.0)
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            addr = await emu.add_vehicle(
                VehicleSpec(sysid=9, start_ned_m=(1, 2, -5), airborne=True)
            )
            assert emu.endpoints[9] == addr
            c = await connect(addr)
            c.heartbeat()
            hb = await c.recv("HEARTBEAT")
            assert hb.get_srcSystem() == 9 and hb.custom_mode == 4
            assert hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
            emu.remove_vehicle(9)
            assert set(emu.endpoints) == {1}
            # Everything vehicle 9 sent before its removal may still be on its way
            # to the client (a loaded loop reads one datagram per turn): wait for
            # all of it (the emulator counts what it sent; vehicle 1 has no peer,
            # so it sent nothing; loopback loses nothing), then nothing more may come.
            sent = emu.stats.link.tx_datagrams
            await c.wait_datagrams(sent)
            _drain(c)
            c.heartbeat()
            await emu.wait_steps(60)  # more than one heartbeat period of sim time
            assert _drain(c) == [] and c.datagrams == sent
            c.close()

    asyncio.run(run())


def test_mavutil_udpout_connects_and_reads() -> None:
    from pymavlink import mavutil

    def standard_tool(port: int) -> tuple[int, float]:
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
        try:
            conn.mav.heartbeat_send(6, 8, 0, 0, 0)
            hb = conn.wait_heartbeat(timeout=10)
            assert hb is not None
            conn.mav.command_long_send(hb.get_srcSystem(), 1, 511, 0, 32, 50000, 0, 0, 0, 0, 0)
            lpn = conn.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=10)
            assert lpn is not None
            return conn.target_system, lpn.z
        finally:
            conn.close()

    async def run() -> None:
        spec = VehicleSpec(sysid=2, start_ned_m=(0, 0, -7), airborne=True)
        async with asyncio.timeout(30), Emulator(EmulatorConfig(vehicles=(spec,))) as emu:
            sysid, z = await asyncio.to_thread(standard_tool, emu.endpoints[2][1])
            assert sysid == 2 and abs(z + 7) < 1e-6

    asyncio.run(run())


def test_a_realtime_clock_takes_its_first_step_at_start_at() -> None:
    """``start_at_s`` (a network's phase): no physics step before that
    ``time.monotonic()``, steps after it, paced from it (generous bounds: the
    loop's own latency on a loaded machine is some ms)."""
    import time

    async def main() -> None:
        t0 = time.monotonic()
        cfg = EmulatorConfig(vehicles=(VehicleSpec(sysid=1),), start_at_s=t0 + 0.4)
        async with Emulator(cfg) as emu:
            await asyncio.sleep(max(0.0, t0 + 0.3 - time.monotonic()))
            assert emu.step_count == 0
            await asyncio.sleep(max(0.0, t0 + 1.0 - time.monotonic()))
            # 0.6 s at 50 Hz from the first step: 30 steps (31 counting it)
            assert 20 <= emu.step_count <= 32

    asyncio.run(main())
