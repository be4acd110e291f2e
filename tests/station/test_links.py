"""Links over real sockets on 127.0.0.1 (port 0): every connection-string
scheme, several system ids on one link, bad packets and queue policies."""

from __future__ import annotations

import asyncio
import socket
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.errors import LinkError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import Codec
from gcs_swarm.runtime.links import UDP_RECEIVE_BUFFER_BYTES, Link, parse_connection
from mavwire import MAX_DATAGRAM_BYTES


def _frame(sysid: int, t_ms: int = 1) -> bytes:
    mav = dialect.MAVLink(None, sysid, 1)
    return bytes(mav.local_position_ned_encode(t_ms, 1.0, 2.0, 3.0, 0, 0, 0).pack(mav))


class _Peer(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.got: asyncio.Queue[tuple[bytes, Any]] = asyncio.Queue()
        self.parser = dialect.MAVLink(None, 1, 1)

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.got.put_nowait((data, addr))


def test_parse_connection_strings() -> None:
    ep = parse_connection("udpin:0.0.0.0:14550")
    assert (ep.scheme, ep.host, ep.port) == ("udpin", "0.0.0.0", 14550)
    assert str(parse_connection("tcp:127.0.0.1:5760")) == "tcp:127.0.0.1:5760"
    for bad in ("udp:1.2.3.4:5", "tcp:127.0.0.1", "udpout:127.0.0.1:0", "tcpin:h:x", "serial"):
        with pytest.raises(LinkError, match="connection string"):
            parse_connection(bad)


def test_udpin_routes_replies_to_each_sysids_peer_and_counts_bad_packets() -> None:
    async def main() -> None:
        got: list[tuple[int, Link]] = []
        two = asyncio.Event()

        def on_message(msg: Any, lk: Link) -> None:
            got.append((msg.get_srcSystem(), lk))
            if len(got) == 2:
                two.set()

        async with asyncio.timeout(5):
            link = Link("udpin:127.0.0.1:0", on_message)
            async with link:
                addr = link.local_address
                assert addr is not None
                loop = asyncio.get_running_loop()
                peers = []
                for _ in range(2):
                    tr, pr = await loop.create_datagram_endpoint(_Peer, local_addr=("127.0.0.1", 0))
                    peers.append((tr, pr))
                # Two vehicles (sysids 7 and 8) behind two different peers.
                peers[0][0].sendto(_frame(7), addr)
                peers[1][0].sendto(_frame(8), addr)
                peers[1][0].sendto(b"\xfd\x10not mavlink at all", addr)
                await two.wait()
                assert sorted(s for s, _ in got) == [7, 8]
                link.send(b.accel_setpoint(8, 1, 0, (1.0, 0.0, 0.0)), 8)
                data, _ = await peers[1][1].got.get()
                msg = peers[1][1].parser.parse_buffer(data)[0]
                assert (msg.get_type(), msg.target_system) == ("SET_POSITION_TARGET_LOCAL_NED", 8)
                assert peers[0][1].got.empty()  # not sent to the other peer
                link.send(b.heartbeat())  # broadcast: every peer
                for _, pr in peers:
                    data, _ = await pr.got.get()
                    assert pr.parser.parse_buffer(data)[0].get_type() == "HEARTBEAT"
                assert link.stats.bad_packets == 1
                for tr, _ in peers:
                    tr.close()

    asyncio.run(main())


def test_setpoint_slot_is_newest_wins_and_counts_drops() -> None:
    async def main() -> None:
        async with asyncio.timeout(5):
            loop = asyncio.get_running_loop()
            tr, pr = await loop.create_datagram_endpoint(_Peer, local_addr=("127.0.0.1", 0))
            port = tr.get_extra_info("sockname")[1]
            async with Link(f"udpout:127.0.0.1:{port}", lambda m, lk: None) as link:
                for ax in (1.0, 2.0, 3.0):  # no await in between: one slot per vehicle
                    link.send(b.accel_setpoint(5, 1, 0, (ax, 0.0, 0.0)), 5)
                data, _ = await pr.got.get()
                msg = pr.parser.parse_buffer(data)[0]
                assert msg.afx == 3.0
                assert link.stats.setpoints_dropped == 2
                await asyncio.sleep(0.05)
                assert pr.got.empty()
            tr.close()

    asyncio.run(main())


def test_one_steps_setpoints_to_one_peer_share_datagrams_of_at_most_1200_bytes() -> None:
    """60 vehicles behind one peer: their reports (one datagram) come to
    ``on_message`` in order; the 60 answers go out in the fewest datagrams that each
    fit ``MAX_DATAGRAM_BYTES``, every frame whole, and each adds one latency sample."""

    async def main() -> None:
        raws: list[Any] = []
        all_in = asyncio.Event()

        def on_message(msg: Any, lk: Link) -> None:
            raws.append(msg)
            if len(raws) == 60:
                all_in.set()

        async with asyncio.timeout(5):
            loop = asyncio.get_running_loop()
            tr, pr = await loop.create_datagram_endpoint(_Peer, local_addr=("127.0.0.1", 0))
            link = Link("udpin:127.0.0.1:0", on_message)
            async with link:
                addr = link.local_address
                assert addr is not None
                tr.sendto(b"".join(_frame(s, 1000 + s) for s in range(1, 61)), addr)
                await all_in.wait()
                ids = list(range(1, 61))
                assert [(r.get_srcSystem(), r.time_boot_ms) for r in raws] == [
                    (s, 1000 + s) for s in ids
                ]
                assert bytes(raws[0].get_msgbuf()) == _frame(1, 1001)
                for s in range(1, 61):
                    spec = b.accel_setpoint(s, 1, 1000 + s, (float(s), 0.0, 0.0))
                    link.send(spec, s, since_s=link.rx_time_s)
                link.flush()
                got = []
                sizes = []
                while len(got) < 60:
                    data, _ = await pr.got.get()
                    sizes.append(len(data))
                    got += pr.parser.parse_buffer(data)
                assert [(m.target_system, m.afx) for m in got] == [(s, float(s)) for s in ids]
                frame = len(Codec().encode(spec))  # every setpoint frame: 65 bytes
                per = MAX_DATAGRAM_BYTES // frame  # 18
                assert sizes == [per * frame] * (60 // per) + [60 % per * frame]
                assert link.latency.count == 60 and link.stats.sent == 60
            tr.close()

    asyncio.run(main())


def test_a_steps_setpoint_batch_replaces_queued_ones_and_follows_queued_messages() -> None:
    """``send_accel_setpoints`` for 30 vehicles behind one peer: written at
    once, after the FIFO message queued before it; a setpoint still queued
    for one of them is replaced (counted as dropped); the frames are the
    ones ``accel_setpoint`` gives, in datagrams of at most 1200 bytes."""

    async def main() -> None:
        async with asyncio.timeout(5):
            loop = asyncio.get_running_loop()
            tr, pr = await loop.create_datagram_endpoint(_Peer, local_addr=("127.0.0.1", 0))
            port = tr.get_extra_info("sockname")[1]
            async with Link(f"udpout:127.0.0.1:{port}", lambda m, lk: None) as link:
                ids = list(range(1, 31))
                link.send(b.heartbeat())
                link.send(b.accel_setpoint(7, 1, 0, (9.0, 9.0, 9.0)), 7)
                acc = np.array([[float(s), -0.5, 0.25] for s in ids])
                link.send_accel_setpoints(ids, [1] * 30, [100 + s for s in ids], acc, [None] * 30)
                got, sizes = [], []
                while len(got) < 31:
                    data, _ = await pr.got.get()
                    sizes.append(len(data))
                    got += pr.parser.parse_buffer(data)
                assert got[0].get_type() == "HEARTBEAT"
                want = [b.accel_setpoint(s, 1, 100 + s, (float(s), -0.5, 0.25)).fields for s in ids]
                pairs = zip(got[1:], want, strict=True)
                assert [{k: getattr(m, k) for k in w} for m, w in pairs] == want
                assert link.stats.setpoints_dropped == 1 and link.stats.sent == 31
                assert max(sizes) <= MAX_DATAGRAM_BYTES and len(sizes) == 1 + 2  # 18 + 12
                assert link.latency.count == 0  # no telemetry answered: no sample
            tr.close()

    asyncio.run(main())


def test_tcpin_and_tcp_talk_to_each_other() -> None:
    async def main() -> None:
        async with asyncio.timeout(5):
            server_got: asyncio.Queue[Any] = asyncio.Queue()
            client_got: asyncio.Queue[Any] = asyncio.Queue()
            async with Link("tcpin:127.0.0.1:0", lambda m, lk: server_got.put_nowait(m)) as srv:
                assert srv.local_address is not None
                port = srv.local_address[1]
                async with Link(
                    f"tcp:127.0.0.1:{port}", lambda m, lk: client_got.put_nowait(m)
                ) as cli:
                    # Addressed messages wait (bounded) until the connection is up.
                    cli.send(b.set_mode(1, 1, 4), 1)
                    msg = await server_got.get()
                    assert (msg.get_type(), msg.get_srcSystem()) == ("COMMAND_LONG", 255)
                    srv.send(b.request_message(255, 190, 49), 255)
                    reply = await client_got.get()
                    assert reply.get_type() == "COMMAND_LONG" and reply.param1 == 49

    asyncio.run(main())


def test_unopenable_link_is_a_link_error() -> None:
    async def main() -> None:
        async with asyncio.timeout(5):
            async with Link("udpin:127.0.0.1:0", lambda m, lk: None) as first:
                assert first.local_address is not None
                port = first.local_address[1]
                with pytest.raises(LinkError, match=f"udpin:127.0.0.1:{port}"):
                    async with Link(f"udpin:127.0.0.1:{port}", lambda m, lk: None):
                        pass

    asyncio.run(main())


def test_udp_links_ask_for_a_receive_buffer_of_a_swarm_s_burst() -> None:
    """Both UDP link kinds ask for ``UDP_RECEIVE_BUFFER_BYTES``; Linux grants
    twice the request (its bookkeeping), capped at ``net.core.rmem_max``, so
    the socket holds at least the smaller of the two, against 208 KiB by
    default (an overflowing buffer lost start-up answers at N = 750)."""
    try:
        with open("/proc/sys/net/core/rmem_max") as f:
            cap = int(f.read())
    except OSError:
        pytest.skip("no /proc/sys/net/core/rmem_max: not Linux")

    async def main() -> list[int]:
        sizes = []
        for conn in ("udpin:127.0.0.1:0", "udpout:127.0.0.1:9"):
            async with Link(conn, lambda m, lk: None) as link:
                assert link._udp is not None
                sock = link._udp.get_extra_info("socket")
                sizes.append(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
        return sizes

    for size in asyncio.run(main()):
        assert size >= min(UDP_RECEIVE_BUFFER_BYTES, cap)
