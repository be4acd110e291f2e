"""Spoofing (issue 9): once a system id is bound to its link (and, on a
listening link, to its peer), the same system id from anywhere else is
ignored and counted. Real sockets on 127.0.0.1; no signing here."""

from __future__ import annotations

import asyncio
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.mavlink import builders as b
from gcs_swarm.runtime.links import Link


def _frame(sysid: int, x: float) -> bytes:
    mav = dialect.MAVLink(None, sysid, 1)
    return bytes(mav.local_position_ned_encode(1, x, 0.0, -5.0, 0, 0, 0).pack(mav))


class _Peer(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.got: asyncio.Queue[bytes] = asyncio.Queue()

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.got.put_nowait(data)


def test_same_sysid_from_another_peer_is_ignored_and_replies_stay_with_the_first() -> None:
    async def main() -> None:
        got: asyncio.Queue[float] = asyncio.Queue()
        async with asyncio.timeout(5):
            loop = asyncio.get_running_loop()
            async with Link("udpin:127.0.0.1:0", lambda m, lk: got.put_nowait(m.x)) as link:
                addr = link.local_address
                assert addr is not None and addr[0] == "127.0.0.1"
                (real, rp), (fake, fp) = [
                    await loop.create_datagram_endpoint(_Peer, local_addr=("127.0.0.1", 0))
                    for _ in range(2)
                ]
                real.sendto(_frame(7, 1.0), addr)
                assert await got.get() == 1.0
                for _ in range(20):
                    fake.sendto(_frame(7, 666.0), addr)  # same sysid, other peer
                real.sendto(_frame(7, 2.0), addr)  # loopback keeps the order of the sends
                assert await got.get() == 2.0
                assert got.empty() and link.stats.spoofed == 20
                link.send(b.accel_setpoint(7, 1, 0, (1.0, 0.0, 0.0)), 7)
                await asyncio.wait_for(rp.got.get(), 1.0)  # the reply goes to the real peer
                await asyncio.sleep(0.05)
                assert fp.got.empty()
                real.close()
                fake.close()

    asyncio.run(main())
