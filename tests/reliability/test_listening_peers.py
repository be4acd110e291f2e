"""Listening links keep no state for strangers (issue 15 item 7).

Before: every source address that sent one datagram got a codec for the
run (5,000 ports: +18.5 MB never freed) and the station's HEARTBEAT at
1 Hz (a reflection source). Now only an address whose frame carried one of
the link's system ids, and bound it, gets state and broadcasts. Real UDP
on 127.0.0.1; the station's own ``Link``.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.mavlink import builders as b
from gcs_swarm.runtime.links import Link

N_STRANGERS = 300


class _Peer(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.got: asyncio.Queue[bytes] = asyncio.Queue()

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.got.put_nowait(data)


def _heartbeat(sysid: int) -> bytes:
    mav = dialect.MAVLink(None, sysid, 1)
    return bytes(mav.heartbeat_encode(2, 3, 1, 4, 4).pack(mav))


def test_garbage_and_foreign_ids_from_many_ports_keep_no_state_and_get_no_heartbeat() -> None:
    async def main() -> None:
        heard: list[int] = []
        changed = asyncio.Event()

        def on_message(m: Any, lk: Link) -> None:
            heard.append(m.get_srcSystem())
            changed.set()

        async with asyncio.timeout(20):
            loop = asyncio.get_running_loop()
            link = Link("udpin:127.0.0.1:0", on_message, sysids=[1, 2])
            async with link:
                addr = link.local_address
                assert addr is not None
                strangers = []
                for k in range(N_STRANGERS):
                    s = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
                    s.bind(("127.0.0.1", 0))
                    s.setblocking(False)
                    # Garbage from most, a valid frame of a system id the link does
                    # not serve from every tenth.
                    s.sendto(_heartbeat(99) if k % 10 == 0 else b"\xfd\x09garbage" * 3, addr)
                    strangers.append(s)
                    # Let the link read every 50: a socket's receive buffer is finite.
                    # (Polled: bad packets signal nothing.)
                    while k % 50 == 49 and link.stats.bad_packets + len(heard) < k + 1:  # noqa: ASYNC110
                        await asyncio.sleep(0.005)
                vehicle, vp = await loop.create_datagram_endpoint(
                    _Peer, local_addr=("127.0.0.1", 0)
                )
                vehicle.sendto(_heartbeat(1), addr)  # after the strangers' (loopback order)
                while 1 not in heard:
                    changed.clear()
                    await changed.wait()
                assert heard.count(99) == N_STRANGERS // 10  # delivered (the station counts them)
                assert link.peer_count == 1 and link.stats.peers == {vehicle_name(vehicle)}
                link.send(b.heartbeat())  # the station's 1 Hz broadcast
                link.flush()
                await asyncio.wait_for(vp.got.get(), 5.0)  # the vehicle got it ...
                # ... and, written in the same flush before the vehicle's arrived,
                # nobody else did.
                for s in strangers:
                    try:
                        data = s.recv(65536)
                    except BlockingIOError:
                        continue
                    raise AssertionError(f"a stranger got {data!r}")
                vehicle.close()
                assert link.stats.bad_packets >= N_STRANGERS * 9 // 10

    with contextlib.ExitStack() as stack:  # every socket closed however the test ends
        asyncio.run(main())


def vehicle_name(transport: asyncio.DatagramTransport) -> str:
    host, port = transport.get_extra_info("sockname")[:2]
    return f"{host}:{port}"
