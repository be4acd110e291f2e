"""UDP (and TCP) endpoints of the emulator.

Owns ``Endpoint`` (one bound UDP socket hosting one or several system ids:
the peers it has heard, its outbox, its parser and its two
``impairments.Impairer``; ``core.Port`` is what the core uses of it) and
``TcpPort`` (the same vehicle also served as a MAVLink TCP server, one
client at a time, as SITL serves ``tcp:127.0.0.1:5760``). Sends
go straight to the non-blocking socket (a full socket buffer drops the
datagram and counts it, as a radio would); receives come through asyncio.
Datagrams are batched per peer up to ``mavwire.MAX_DATAGRAM_BYTES`` (the
station's limit too; ``mavwire.datagrams.join_frames``). A TCP client is one more peer of
its endpoint, under the address ``("tcp:HOST", PORT)`` (``TCP_PREFIX``):
everything sent to the endpoint's peers goes to it too, as a byte stream.
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire.datagrams import join_frames
from sim_vehicle import signing
from sim_vehicle.codec import RawSetpoint, decode_setpoint
from sim_vehicle.impairments import Impairer
from sim_vehicle.lane import may_be_stream
from sim_vehicle.stats import LinkStats

__all__ = ["READ_AHEAD", "TCP_PREFIX", "Endpoint", "TcpPort", "bind_udp"]

TCP_PREFIX = "tcp:"
READ_AHEAD = 16
"""Datagrams a shared endpoint takes from its socket at once at most: a
station's step of 250 vehicles' setpoints comes in 13-14. No more: a read
the lane declines (its vehicles' lanes not yet open, a PX4's) goes one
datagram at a time within the same callback, and the clock's steps wait
for it (at 1,500 vehicles, the formation's first setpoints took up to 2.7
ms a datagram on a saturated machine: a read of 28 took 77 ms, 2026-12-06)."""
Addr = tuple[str, int]


@dataclass
class Endpoint(asyncio.DatagramProtocol):
    """One UDP socket serving ``sysids`` (one, or several when shared)."""

    sock: socket.socket
    shared: bool
    uplink: Impairer
    downlink: Impairer
    on_datagram: Callable[[Endpoint, bytes, Addr], None]
    stats: LinkStats
    out: Addr | None = None
    sysids: dict[int, int] = field(default_factory=dict)  # system id -> vehicle key
    peers: dict[Addr, None] = field(default_factory=dict)
    outbox: list[tuple[bytes, int]] = field(default_factory=list)
    transport: asyncio.DatagramTransport | None = None
    signing_key: bytes | None = field(default=None, repr=False)
    silent: bool = False  # radio off: nothing sent, nothing heard (Emulator.set_silent)
    tcp: TcpPort | None = None  # the same vehicle served over TCP too
    on_datagrams: Callable[[Endpoint, list[tuple[bytes, Addr]]], None] | None = None
    """Set on a shared endpoint: a datagram asyncio reads that may be the
    station's stream (``lane.may_be_stream``) comes with those queued behind
    it, up to ``READ_AHEAD`` and the first that may not, so that a network's
    setpoints can be taken at once (``lane.take_stream``)."""

    def __post_init__(self) -> None:
        self.parser = signing.mavlink(0, 0, self.signing_key)
        if self.out is not None:
            self.peers[self.out] = None
        host, port = self.sock.getsockname()[:2]
        self.address: Addr = (str(host), int(port))  # (host, port) this endpoint is bound to

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: Addr) -> None:
        many = self.on_datagrams
        if many is None or not may_be_stream(data):
            self.on_datagram(self, data, addr)
            return
        batch = [(data, addr)]
        recvfrom = self.sock.recvfrom
        while len(batch) < READ_AHEAD:
            try:
                item = recvfrom(65536)  # (data, addr) as asyncio reads them
            except OSError:  # nothing queued (or an ICMP error, which asyncio reports)
                break
            batch.append(item)
            if not may_be_stream(item[0]):
                break  # what follows it waits for the loop's next turn, as before
        many(self, batch)

    def error_received(self, exc: Exception) -> None:
        pass  # ICMP port unreachable from a station that went away: keep serving

    def parse(self, data: bytes, raw: bool = False) -> list[Any]:
        """Decode every frame of a datagram (bad frames are counted and skipped).

        Unsigned: each whole unsigned SET_POSITION_TARGET_LOCAL_NED frame is
        decoded by ``codec.decode_setpoint``; every other run of bytes goes
        through pymavlink's parser, so messages and counters are what that
        parser gives for the whole datagram (a test checks it). ``raw``: the
        setpoints stay ``codec.RawSetpoint`` (their ``message()`` is what
        is returned without it), as the core's 50 Hz lane reads them."""
        if self.signing_key is not None:
            return self._general(data)
        pieces = _split_setpoints(data)
        if not raw:
            pieces = [p if isinstance(p, bytes) else p.message() for p in pieces]
        if not any(isinstance(p, bytes) for p in pieces):
            return pieces  # the hot case: setpoints only
        parser = self.parser
        msgs: list[Any] = []
        for piece in pieces:
            if not isinstance(piece, bytes):
                msgs.append(piece)
                continue
            try:
                msgs.extend(parser.parse_buffer(piece) or [])
            except (mav.MAVError, ValueError, IndexError):
                # the general parser would have dropped the whole datagram: do just that
                self._reset_parser()
                return self._general(data)
        return self._sort(msgs)

    def _general(self, data: bytes) -> list[mav.MAVLink_message]:
        """pymavlink's parser over the whole datagram, with the counters."""
        parser = self.parser
        rejected = parser.signing.reject_count
        try:
            msgs = parser.parse_buffer(data) or []
        except (mav.MAVError, ValueError, IndexError):
            self.stats.bad_frames += 1
            msgs = []
        rejected = parser.signing.reject_count - rejected
        self.stats.signature_rejected += rejected
        self.stats.bad_frames -= rejected  # pymavlink reports them as bad data
        return self._sort(msgs)

    def _sort(self, msgs: list[mav.MAVLink_message]) -> list[mav.MAVLink_message]:
        """Count a truncated tail, bad and unknown frames; return the good messages."""
        if self.parser.buf_len() > 0:  # a truncated frame: never glue it to the next datagram
            self.stats.bad_frames += 1
            self._reset_parser()
        good = []
        for m in msgs:
            if isinstance(m, mav.MAVLink_bad_data):
                self.stats.bad_frames += 1
            elif isinstance(m, mav.MAVLink_unknown):
                self.stats.unknown_frames += 1
            else:
                good.append(m)
        return good

    def _reset_parser(self) -> None:
        parser = self.parser
        parser.buf = bytearray()
        parser.buf_index = 0
        parser.expected_length = mav.HEADER_LEN_V1 + 2
        parser.have_prefix_error = False

    def batch(self, frames: list[tuple[bytes, int]]) -> list[tuple[bytes, list[int]]]:
        """``join_frames``: (frame, key) pairs joined into datagrams."""
        return join_frames(frames)

    def sendto(self, data: bytes, addr: Addr) -> None:
        """Send one datagram now (no impairment here; see ``core.EmulatorCore.transmit``)."""
        if addr[0].startswith(TCP_PREFIX):
            if self.tcp is not None and self.tcp.write(data, addr):
                self.stats.tx_datagrams += 1
            return
        try:
            self.sock.sendto(data, addr)
            self.stats.tx_datagrams += 1
        except BlockingIOError:
            self.stats.tx_dropped_full += 1
        except OSError:
            pass  # the peer vanished (ICMP): UDP keeps no state

    def close(self) -> None:
        """Close the transport (and so the socket), and the TCP port if any."""
        if self.tcp is not None:
            self.tcp.close()
        if self.transport is not None:
            self.transport.close()
        else:
            self.sock.close()


class TcpPort:
    """A MAVLink TCP server for one endpoint: one client at a time (a new one replaces
    the old). Frames from the stream are parsed across reads by a parser of its own;
    ``on_messages(ep, msgs, addr)`` gets them, ``on_peer(ep, addr, up)`` the comings
    and goings."""

    def __init__(
        self,
        ep: Endpoint,
        on_messages: Callable[[Endpoint, list[mav.MAVLink_message], Addr], None],
        on_peer: Callable[[Endpoint, Addr, bool], None],
    ) -> None:
        self.ep = ep
        self.on_messages = on_messages
        self.on_peer = on_peer
        self.server: asyncio.Server | None = None
        self.address: Addr = ("", 0)
        self._client: tuple[Addr, asyncio.Transport] | None = None

    async def start(self, host: str, port: int) -> None:
        """Listen on (host, port); port 0 = ephemeral."""
        loop = asyncio.get_running_loop()
        self.server = await loop.create_server(lambda: _TcpClient(self), host, port)
        h, p = self.server.sockets[0].getsockname()[:2]
        self.address = (str(h), int(p))

    def attach(self, addr: Addr, transport: asyncio.Transport) -> None:
        if self._client is not None:  # one client at a time: the newest wins
            old_addr, old = self._client
            self._client = None
            old.close()
            self.on_peer(self.ep, old_addr, False)
        self._client = (addr, transport)
        self.on_peer(self.ep, addr, True)

    def detach(self, addr: Addr) -> None:
        if self._client is not None and self._client[0] == addr:
            self._client = None
            self.on_peer(self.ep, addr, False)

    def write(self, data: bytes, addr: Addr) -> bool:
        """Write ``data`` to the client ``addr`` if it is still connected."""
        if self._client is None or self._client[0] != addr or self._client[1].is_closing():
            return False
        self._client[1].write(data)
        return True

    def close(self) -> None:
        if self._client is not None:
            self._client[1].close()
            self._client = None
        if self.server is not None:
            self.server.close()


class _TcpClient(asyncio.Protocol):
    """One TCP connection: a stream parser (frames may span reads) feeding its port."""

    def __init__(self, port: TcpPort) -> None:
        self.port = port
        self.parser = signing.mavlink(0, 0, port.ep.signing_key)
        self.addr: Addr = ("", 0)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        peer = transport.get_extra_info("peername") or ("?", 0)
        self.addr = (TCP_PREFIX + str(peer[0]), int(peer[1]))
        self.port.attach(self.addr, transport)  # type: ignore[arg-type]

    def data_received(self, data: bytes) -> None:
        stats = self.port.ep.stats
        rejected = self.parser.signing.reject_count
        try:
            msgs = self.parser.parse_buffer(data) or []
        except (mav.MAVError, ValueError, IndexError):
            stats.bad_frames += 1
            self.parser = signing.mavlink(0, 0, self.port.ep.signing_key)
            return
        rejected = self.parser.signing.reject_count - rejected
        stats.signature_rejected += rejected
        stats.bad_frames -= rejected  # pymavlink reports them as bad data too
        good = []
        for m in msgs:
            if isinstance(m, mav.MAVLink_bad_data):
                stats.bad_frames += 1
            elif isinstance(m, mav.MAVLink_unknown):
                stats.unknown_frames += 1
            else:
                good.append(m)
        self.port.on_messages(self.port.ep, good, self.addr)

    def connection_lost(self, exc: Exception | None) -> None:
        self.port.detach(self.addr)


def bind_udp(host: str, port: int) -> socket.socket:
    """A non-blocking UDP socket bound to (host, port); port 0 = ephemeral."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.setblocking(False)
    return sock


def _split_setpoints(data: bytes) -> list[RawSetpoint | bytes]:
    """Cut a datagram into fast-decoded setpoints and runs of bytes for the general parser.

    Walks whole unsigned MAVLink 2 frames from the start (12 + payload bytes
    each, as pymavlink frames them); a setpoint with a good CRC is decoded,
    every other whole frame joins the current run, and everything from the
    first byte that does not start a whole unsigned MAVLink 2 frame (garbage,
    MAVLink 1, a signed or truncated frame) is one final run. Runs start and
    end on frame boundaries, where pymavlink's parser keeps no state, so it
    decodes each run exactly as it would inside the whole datagram.
    """
    n = len(data)
    out: list[RawSetpoint | bytes] = []
    run = i = 0
    while i + 12 <= n and data[i] == 0xFD and data[i + 2] == 0:
        plen = data[i + 1]
        end = i + 12 + plen
        if end > n:
            break
        sp = decode_setpoint(data, i, plen)
        if sp is not None:
            if run < i:
                out.append(data[run:i])
            out.append(sp)
            run = end
        i = end
    if run < n:
        out.append(data[run:] if run else data)
    return out
