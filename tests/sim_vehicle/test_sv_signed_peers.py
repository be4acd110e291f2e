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
