"""MAVLink over TCP (as SITL serves ``tcp:127.0.0.1:5760 + 10 i``), over real sockets.

A plain asyncio TCP client with pymavlink's parser (frames may span reads),
against the real emulator on 127.0.0.1 with ephemeral ports; UDP keeps working
beside it. Every wait is inside ``asyncio.timeout``.
"""

from __future__ import annotations

import asyncio
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav
from sv_client import connect

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec
from sim_vehicle.cli import build_config, parse_args

ESS = mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE


class TcpClient:
    """A ground station on one TCP connection."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.mav = mav.MAVLink(None, 255, 190)
        self.pending: list[Any] = []

    def send(self, msg: Any) -> None:
        self.writer.write(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256

    async def recv(self, kind: str, pred: Any = lambda m: True) -> Any:
        while True:
            while self.pending:
                m = self.pending.pop(0)
                if m.get_type() == kind and pred(m):
                    return m
            data = await self.reader.read(4096)
            assert data, "connection closed"
            self.pending += self.mav.parse_buffer(data) or []

    async def command(self, cmd: int, *p: float) -> Any:
        q = [*p, 0, 0, 0, 0, 0, 0, 0][:7]
        self.send(mav.MAVLink_command_long_message(1, 1, cmd, 0, *q))
        return await self.recv("COMMAND_ACK", lambda m: m.command == cmd)

    def close(self) -> None:
        self.writer.close()


async def _tcp(addr: tuple[str, int]) -> TcpClient:
    reader, writer = await asyncio.open_connection(*addr)
    return TcpClient(reader, writer)


def test_tcp_serves_the_protocol_beside_udp() -> None:
    cfg = EmulatorConfig(
        vehicles=(VehicleSpec(sysid=1), VehicleSpec(sysid=2)), tcp_base_port=0, ekf_ready_s=0.0
    )

    async def run() -> None:
        async with asyncio.timeout(30), Emulator(cfg) as emu:
            assert set(emu.tcp_endpoints) == {1, 2}
            assert emu.tcp_endpoints[1] != emu.tcp_endpoints[2]
            c = await _tcp(emu.tcp_endpoints[1])
            hb = await c.recv("HEARTBEAT")  # sent on connection, before we say anything
            assert hb.get_srcSystem() == 1 and hb.custom_mode == 0
            ack = await c.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, ESS, 100000)
            assert ack.result == mav.MAV_RESULT_ACCEPTED
            ess = await c.recv("EXTENDED_SYS_STATE")
            assert ess.landed_state == 1 and ess.vtol_state == 0
            for name in ("WPNAV_ACCEL", "PSC_JERK_XY", "PSC_JERK_Z", "ANGLE_MAX", "SYSID_MYGCS"):
                c.send(mav.MAVLink_param_request_read_message(1, 1, name.encode(), -1))
                pv = await c.recv("PARAM_VALUE", lambda m, n=name: m.param_id == n)
                assert pv.param_value == {"ANGLE_MAX": 3000, "WPNAV_ACCEL": 250,
                                          "SYSID_MYGCS": 255}.get(name, 5.0)  # fmt: skip
            c.send(mav.MAVLink_param_set_message(1, 1, b"FS_GCS_ENABLE", 5, 2))
            pv = await c.recv("PARAM_VALUE", lambda m: m.param_id == "FS_GCS_ENABLE")
            assert pv.param_value == 5 and emu.vehicle_state(1).params["FS_GCS_ENABLE"] == 5
            assert (await c.command(mav.MAV_CMD_DO_SET_MODE, 1, 4)).result == 0
            await emu.wait_until(lambda: emu.vehicle_state(1).mode == 4)
            u = await connect(emu.endpoints[1])  # UDP still serves the same vehicle
            try:
                u.heartbeat()
                assert (await u.recv("HEARTBEAT")).custom_mode == 4
            finally:
                u.close()
            second = await _tcp(emu.tcp_endpoints[1])  # one client at a time: newest wins
            await second.recv("HEARTBEAT")
            await _drained(c)  # the first was closed by the emulator (EOF)
            assert (await second.command(mav.MAV_CMD_DO_SET_MODE, 1, 5)).result == 0
            c.close()
            second.close()

    asyncio.run(run())


async def _drained(c: TcpClient) -> None:
    """Read until the emulator has closed the replaced connection (EOF)."""
    while await c.reader.read(1 << 16):
        pass


def test_lockstep_over_tcp_takes_every_step_on_the_answer() -> None:
    cfg = EmulatorConfig(
        vehicles=(VehicleSpec(sysid=1, start_ned_m=(0.0, 0.0, -10.0), airborne=True),),
        clock="lockstep",
        tcp_base_port=0,
        dynamics="ideal",
    )

    async def run() -> None:
        async with asyncio.timeout(30), Emulator(cfg) as emu:
            c = await _tcp(emu.tcp_endpoints[1])
            await c.recv("HEARTBEAT")
            ack = await c.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20000)
            assert ack.result == mav.MAV_RESULT_ACCEPTED
            while emu.step_count < 100:
                await c.recv("LOCAL_POSITION_NED")
                c.send(
                    mav.MAVLink_set_position_target_local_ned_message(
                        0, 1, 1, 1, 3135, 0, 0, 0, 0, 0, 0, 1.0, 0.0, 0.0, 0, 0
                    )
                )
            await emu.wait_steps(0)
            st = emu.vehicle_state(1)
            assert emu.stats.lockstep_timeouts == 0 and st.control == "accel"
            t = emu.step_count * 0.02  # ideal: exactly x = a t^2 / 2 after the steps taken
            assert abs(st.pos_ned_m[0] - 0.5 * t * t) < 1e-9
            c.close()

    asyncio.run(run())


def test_cli_tcp_flags() -> None:
    cfg = build_config(parse_args(["--count", "2", "--tcp"]))
    assert cfg.tcp_base_port == 5760 and cfg.boot_s == 0.0 and cfg.ekf_ready_s == 2.0
    cfg = build_config(parse_args(["--tcp-base-port", "6000", "--sitl-times"]))
    assert cfg.tcp_base_port == 6000 and cfg.boot_s == 1.0 and cfg.ekf_ready_s == 25.0
    assert build_config(parse_args([])).tcp_base_port is None  # UDP only by default
    assert build_config(parse_args(["--no-shaping"])).shaping is False


def test_boot_ends_one_second_after_the_first_connection_as_on_sitl() -> None:
    """Lockstep: sim time is frozen at 0 until the TCP connection (rule 1), so the
    connection is at t = 0 and boot ends at t = SIM_BOOT_S = 1 s (one step of tolerance)."""
    cfg = EmulatorConfig(
        vehicles=(VehicleSpec(sysid=1),), clock="lockstep", speedup=10.0, tcp_base_port=0,
        boot_s=1.0,
    )  # fmt: skip

    async def run() -> None:
        async with asyncio.timeout(30), Emulator(cfg) as emu:
            c = await _tcp(emu.tcp_endpoints[1])
            await c.recv("HEARTBEAT")
            ack = await c.command(mav.MAV_CMD_DO_SET_MODE, 1, 4)
            assert ack.result == mav.MAV_RESULT_ACCEPTED
            assert (await c.recv("HEARTBEAT", lambda m: m.custom_mode == 4)).custom_mode == 4
            seen: list[float] = []

            def back_in_stabilize() -> bool:
                st = emu.vehicle_state(1)
                if not seen and st.mode == 0:
                    seen.append(st.sim_time_s)
                return bool(seen)

            await emu.wait_until(back_in_stabilize)
            assert abs(seen[0] - 1.0) <= 0.02 + 1e-9
            text = await c.recv("STATUSTEXT")
            assert text.text == "ArduPilot Ready"
            assert (await c.recv("HEARTBEAT")).custom_mode == 0
            c.close()

    asyncio.run(run())
