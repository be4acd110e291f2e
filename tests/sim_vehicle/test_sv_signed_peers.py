"""A signed emulator serves only well-signed peers (issue 15 item 8).

Before: an unsigned RADIO_STATUS (the one frame a signed ArduPilot lets
through unsigned) from any address registered that address as a peer, and
it got HEARTBEAT x4 and LOCAL_POSITION_NED x30 in 3 s. Now it is heard but
registers nobody. Real UDP on 127.0.0.1, the real emulator (real time).

Proof without a timed wait: loopback keeps the order of the datagrams a
socket receives, and a new peer gets its HEARTBEAT at once, inside the
handling of its datagram. So once the well-signed peer, which sent after
the unsigned one, has its HEARTBEAT, the unsigned sender would already
hold one if it had been registered.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec, signing

KEY = bytes(range(50, 82))


def test_an_unsigned_radio_status_registers_no_peer_and_draws_no_telemetry() -> None:
    cfg = EmulatorConfig(
        vehicles=(VehicleSpec(sysid=1, origin=(47.0, 8.0, 400.0)),), signing_key=KEY
    )

    async def main() -> tuple[list[int], int]:
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            addr = emu.endpoints[1]
            unsigned = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
            unsigned.bind(("127.0.0.1", 0))
            unsigned.setblocking(False)
            plain = mav.MAVLink(None, 77, 1)
            radio = plain.radio_status_encode(200, 190, 100, 100, 100, 0, 0).pack(plain)
            for _ in range(5):
                unsigned.sendto(bytes(radio), addr)
            # Then the genuine station, well signed.
            good = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
            good.bind(("127.0.0.1", 0))
            good.setblocking(False)
            signer = signing.mavlink(255, 190, KEY)
            hb = signer.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            good.sendto(bytes(hb.pack(signer)), addr)
            loop = asyncio.get_running_loop()
            parser = signing.mavlink(0, 0, KEY)
            ids: list[int] = []
            while mav.MAVLINK_MSG_ID_HEARTBEAT not in ids:
                data = await loop.sock_recv(good, 65536)
                ids += [m.get_msgId() for m in parser.parse_buffer(data) or []]
            # A few more steps of telemetry to the registered peer.
            await emu.wait_steps(20)
            stray = 0
            while True:
                try:
                    unsigned.recv(65536)
                    stray += 1
                except BlockingIOError:
                    break
            return ids, stray

    with contextlib.ExitStack() as stack:  # the sockets closed however the test ends
        ids, stray = asyncio.run(main())
    assert mav.MAVLINK_MSG_ID_HEARTBEAT in ids
    assert stray == 0


def test_a_tcp_client_is_served_only_after_a_well_signed_frame() -> None:
    """Item 8 over TCP: the UDP rule holds for the emulator's TCP server too.

    Before: a TCP client was a peer from its connection on, so an unsigned one
    got a HEARTBEAT at once and then the telemetry stream. Now it is served
    only once it has sent a well-signed frame. Real TCP on 127.0.0.1 (port 0),
    the real emulator (real time).

    Proof without a timed read: the server serves one client at a time and
    closes the old connection (after flushing what it wrote) when a new one
    connects, so the unsigned client reads to EOF exactly what it was ever
    sent. Its window: from connecting, through its three frames (a RADIO_STATUS,
    an unsigned HEARTBEAT, a wrong-key HEARTBEAT; the two HEARTBEATs counted as
    rejected), and 50 more physics steps (1 s at 50 Hz: 10 LOCAL_POSITION_NED
    at the configured 10 Hz and a HEARTBEAT, if it were served), until the
    signed client replaces it.
    """
    lpn = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
    cfg = EmulatorConfig(
        vehicles=(VehicleSpec(sysid=1, origin=(47.0, 8.0, 400.0)),),
        signing_key=KEY,
        tcp_base_port=0,
        ekf_ready_s=0.0,
        streams={lpn: 10.0},
    )

    async def main() -> tuple[bytes, int, list[int]]:
        async with asyncio.timeout(20), Emulator(cfg) as emu:
            addr = emu.tcp_endpoints[1]
            rejected = emu.stats.link.signature_rejected
            reader, writer = await asyncio.open_connection(*addr)
            plain = mav.MAVLink(None, 255, 190)
            radio = plain.radio_status_encode(200, 190, 100, 100, 100, 0, 0)
            hb = plain.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            wrong = signing.mavlink(255, 190, bytes(32))
            writer.write(bytes(radio.pack(plain)) + bytes(hb.pack(plain)))
            writer.write(bytes(hb.pack(wrong)))
            await writer.drain()
            # TCP keeps the order: both rejections counted = all three frames handled.
            await emu.wait_until(lambda: emu.stats.link.signature_rejected >= rejected + 2)
            await emu.wait_steps(50)
            # The genuine station, well signed, on the same server: it replaces the client.
            r2, w2 = await asyncio.open_connection(*addr)
            signer = signing.mavlink(255, 190, KEY)
            w2.write(bytes(hb.pack(signer)))
            heard = await reader.read()  # to EOF: all the unsigned client was ever sent
            writer.close()
            parser = signing.mavlink(0, 0, KEY)
            ids: list[int] = []
            while not {mav.MAVLINK_MSG_ID_HEARTBEAT, lpn} <= set(ids):
                data = await r2.read(65536)
                assert data, "connection closed"
                ids += [m.get_msgId() for m in parser.parse_buffer(data) or []]
            w2.close()
            return heard, emu.stats.link.signature_rejected - rejected, ids

    heard, rejected, ids = asyncio.run(main())
    assert rejected == 2  # the unsigned and the wrong-key HEARTBEAT; RADIO_STATUS may pass
    # not one byte to the client that never signed (before: HEARTBEAT, then LOCAL_POSITION_NED)
    assert [m.get_type() for m in signing.mavlink(0, 0, KEY).parse_buffer(heard) or []] == []
    assert heard == b""
    assert ids[0] == mav.MAVLINK_MSG_ID_HEARTBEAT  # rule 1: HEARTBEAT first, then telemetry
    assert lpn in ids
