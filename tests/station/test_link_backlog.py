"""A station that fell behind its telemetry (docs/architecture.md, "From a
datagram to a setpoint", step 1): a UDP link reads what is queued behind a
datagram at once and decodes only each not-flying vehicle's newest report
of it, over a real socket on 127.0.0.1."""

from __future__ import annotations

import asyncio
import socket
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.report.record import TelemetryCounter
from gcs_swarm.runtime.links import Link

_SENDERS: dict[int, Any] = {}


def _frame(sysid: int, make: str, *fields: Any) -> bytes:
    """One frame of vehicle ``sysid``, numbered after its last (pymavlink's
    ``pack`` leaves the sequence to ``send``)."""
    mav = _SENDERS.setdefault(sysid, dialect.MAVLink(None, sysid, 1))
    data = bytes(getattr(mav, make)(*fields).pack(mav))
    mav.seq = (mav.seq + 1) % 256
    return data


def _report(sysid: int, t_ms: int) -> bytes:
    return _frame(sysid, "local_position_ned_encode", t_ms, 1.0, 2.0, 3.0, 0, 0, 0)


def _ack(sysid: int) -> bytes:
    return _frame(sysid, "command_ack_encode", dialect.MAV_CMD_DO_SET_MODE, 0)


def test_a_backlog_is_read_at_once_and_only_each_vehicles_newest_report_goes_on() -> None:
    """Five datagrams queued in the socket before the loop reads any (as behind
    a stall): the command answer and each vehicle's newest report come out,
    in order; the three older reports are dropped unread and counted. Before
    the read-ahead, every report went through its vehicle's protocol, one
    datagram per loop turn, while the answer waited behind them. The flight
    recorder's counts still hear every frame: the dropped reports are
    received, not lost."""
    _SENDERS.clear()
    counter = TelemetryCounter()

    async def main() -> tuple[list[Any], int]:
        got: list[Any] = []
        heard = asyncio.Event()

        def on_message(msg: Any, lk: Link) -> None:  # what a station records (SwarmCore.receive)
            counter.add(msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq(), msg.get_msgId())
            got.append(msg)
            heard.set()

        table = TelemetryTable([1, 2])
        table.on_inbound = counter.add
        link = Link("udpin:127.0.0.1:0", on_message, telemetry=table, sysids=[1, 2])
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            async with asyncio.timeout(5), link:
                addr = link.local_address
                assert addr is not None
                tx.sendto(_report(1, 1), addr)  # binds the peer
                await heard.wait()
                got.clear()
                heard.clear()
                for data in (_report(1, 2) + _report(2, 2), _ack(1), _report(1, 3),
                             _report(1, 4) + _report(2, 3)):  # fmt: skip
                    tx.sendto(data, addr)  # queued: the loop has not run since
                await heard.wait()  # one read: all five datagrams at once
                await asyncio.sleep(0.05)  # nothing more comes
        finally:
            tx.close()
        return got, link.stats.reports_superseded

    got, superseded = asyncio.run(main())
    kinds = [(m.get_type(), m.get_srcSystem(), getattr(m, "time_boot_ms", None)) for m in got]
    assert kinds == [
        ("COMMAND_ACK", 1, None),
        ("LOCAL_POSITION_NED", 1, 4),
        ("LOCAL_POSITION_NED", 2, 3),
    ]
    assert superseded == 3
    one, two = counter.counts[1], counter.counts[2]
    assert (one.received, one.lost, one.late, two.received, two.lost) == (5, 0, 0, 2, 0)
