"""MAVLink links over asyncio: UDP and TCP transports behind one ``Link`` class.

Connection strings follow pymavlink's conventions (mavlink-protocol.md,
"Identity and links"): ``udpin:HOST:PORT`` (listen), ``udpout:HOST:PORT``
(send first), ``tcp:HOST:PORT`` (connect, reconnecting), ``tcpin:HOST:PORT``
(listen). Several system ids may share one link: inbound messages carry
their sender's id and each reply goes to the peer that id was last heard
from; broadcasts (the station HEARTBEAT) go to every peer.

One ``Codec`` per peer (sequence numbers and parser state). Outbound policy
(STYLE.md habit 6):
- setpoints: one slot per vehicle, newest wins, overwritten ones counted;
- other messages: FIFO of ``MESSAGE_QUEUE_SIZE``; when full the oldest is
  dropped and counted (commands are resent by the protocol on timeout).
A ``Link`` is an ``async with`` lifetime owning one ``asyncio.TaskGroup``.

Security (issues 9 and 15): a system id is bound to the peer it was first
heard from, for the whole run. Frames carrying that id from another peer
are spoofing: counted in ``LinkStats.spoofed`` and, per system id, in
``rebinds_refused``, dropped, and reported once per vehicle (``on_notice``).
The one exception (``allow_rebind``, the mission's
``signing.allow_rebind``): on a signed link, once the bound peer has been
silent for ``REBIND_S``, a peer whose frames carry a good signature may take
the id over (a vehicle that rebooted onto a new port); this is reported
too. Without signing a vehicle is never handed to a new address. With a
``signing_key`` every codec signs and checks MAVLink 2 signatures.

Listening links (issue 15): a datagram from an unknown address is decoded
by one shared codec and leaves nothing behind; the address gets its own
codec (sequence numbers, parser) and the station's broadcasts (HEARTBEAT)
only once it is bound to one of the link's ``sysids``, so garbage from any
number of ports keeps no state and draws no reply. A peer that no longer
speaks for any system id (rebound away) loses its codec.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
import time
from collections import Counter, deque
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from gcs_swarm.errors import LinkError
from gcs_swarm.mavlink.builders import (
    MAV_FRAME_LOCAL_NED,
    TYPE_MASK_ACCEL,
    TYPE_MASK_VEL_ACCEL,
)
from gcs_swarm.mavlink.codec import Codec, MessageSpec, RawPosition
from gcs_swarm.runtime.endpoints import Endpoint, LatencyRing, LinkStats, parse_connection
from gcs_swarm.runtime.lifetime import close_task_group
from mavwire.datagrams import MAX_DATAGRAM_BYTES, datagram_bounds

__all__ = [
    "MESSAGE_QUEUE_SIZE",
    "Endpoint",
    "LatencyRing",
    "Link",
    "LinkStats",
    "parse_connection",
]

_log = logging.getLogger("gcs_swarm.link")

MESSAGE_QUEUE_SIZE = 256
"""Bound of a link's FIFO of non-setpoint messages."""
REBIND_S = 5.0
"""Silence [s] of a system id's peer after which another, well-signed, peer
may take it over when the link allows rebinding (signed links only)."""
_RECONNECT_S = 1.0

Peer = Any  # a UDP address tuple, or a TCP connection object
OnMessage = Callable[[Any, "Link"], None]
"""Called with each decoded pymavlink message and the link it came on."""
OnPosition = Callable[[list[RawPosition], "Link"], None]
"""Called with runs of unsigned LOCAL_POSITION_NED (decoded without
pymavlink's objects; consecutive ones of a datagram together, in order with
the other messages) and their link, when the owner asks for them apart."""
OnFrame = Callable[[bytes, Literal["in", "out"]], None]
"""Called with every raw frame the link decoded ("in") or sent ("out"), e.g.
a ``.tlog`` writer; bad packets are counted, not passed on."""


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, link: Link) -> None:
        self._link = link

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self._link._on_bytes(data, addr, datagram=True)

    def error_received(self, exc: Exception) -> None:  # e.g. ICMP port unreachable
        _log.debug("%s: %s", self._link.endpoint, exc)


def _name(peer: Peer) -> str:
    if isinstance(peer, tuple) and len(peer) >= 2:
        return f"{peer[0]}:{peer[1]}"
    return "tcp" if isinstance(peer, _Stream) else str(peer)


@dataclass(eq=False)
class _Stream:
    writer: asyncio.StreamWriter


class Link:
    """One MAVLink connection shared by any number of vehicles."""

    def __init__(
        self,
        connection: str,
        on_message: OnMessage,
        *,
        on_frame: OnFrame | None = None,
        on_position: OnPosition | None = None,
        signing_key: bytes | None = None,
        sysids: Collection[int] | None = None,
        allow_rebind: bool = False,
        on_notice: Callable[[str], None] | None = None,
    ) -> None:
        """``on_message`` gets every decoded message, except that with
        ``on_position`` the unsigned LOCAL_POSITION_NED frames go there as
        lists of ``RawPosition`` tuples (the station's hot path).
        ``sysids``: the system ids this link serves (None: any); only they
        bind a peer. ``allow_rebind`` takes effect with a ``signing_key``
        only (module docstring). ``on_notice`` gets one line per refused or
        accepted rebinding of a vehicle (the first refusal only)."""
        self.endpoint = parse_connection(connection)
        self._signing_key = signing_key
        self._sysids = None if sysids is None else frozenset(sysids)
        self._allow_rebind = allow_rebind and signing_key is not None
        self._on_notice = on_notice
        self.rebinds_refused: Counter[int] = Counter()
        """Frames refused per system id because they came from another peer
        than the one the id is bound to."""
        self._stranger: Codec | None = None
        self._sig_streams: dict[tuple[int, int, int], int] = {}
        self._heard: dict[int, float] = {}
        self.stats = LinkStats()
        self.latency = LatencyRing()
        """Telemetry-arrival-to-setpoint-write times of this link's setpoints."""
        self.rx_time_s = 0.0
        """``time.monotonic()`` when the datagram (or stream chunk) being decoded arrived."""
        self._on_message = on_message
        self._on_frame = on_frame
        self._on_position = on_position
        self._codecs: dict[Peer, Codec] = {}
        self._routes: dict[int, Peer] = {}
        self._setpoints: dict[int, MessageSpec] = {}
        self._since: dict[int, float] = {}
        self._messages: deque[tuple[MessageSpec, int | None]] = deque()
        self._wake = asyncio.Event()
        self._udp: asyncio.DatagramTransport | None = None
        self._streams: list[_Stream] = []
        self._server: asyncio.Server | None = None
        self._tg = asyncio.TaskGroup()
        self._tasks: list[asyncio.Task[None]] = []

    # ----------------------------------------------------------- lifetime
    async def __aenter__(self) -> Link:
        await self._tg.__aenter__()
        try:
            await self._open()
        except OSError as err:
            await self._tg.__aexit__(None, None, None)
            raise LinkError(f"{self.endpoint}: {err.strerror or err}") from err
        self._tasks.append(self._tg.create_task(self._writer()))
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        try:
            await close_task_group(self._tg, self._tasks, et, ev, tb)
        finally:
            if self._udp is not None:
                self._udp.close()
            for stream in self._streams:
                stream.writer.close()
            if self._server is not None:
                self._server.close()

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The bound (host, port) of a listening link (``udpin``/``tcpin``)."""
        if self._udp is not None:
            addr = self._udp.get_extra_info("sockname")
            return (str(addr[0]), int(addr[1]))
        if self._server is not None and self._server.sockets:
            addr = self._server.sockets[0].getsockname()
            return (str(addr[0]), int(addr[1]))
        return None

    async def _open(self) -> None:
        ep = self.endpoint
        loop = asyncio.get_running_loop()
        if ep.scheme == "udpin":
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Udp(self), local_addr=(ep.host, ep.port)
            )
            self._udp = transport
        elif ep.scheme == "udpout":
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Udp(self), remote_addr=(ep.host, ep.port)
            )
            self._udp = transport
            self._codecs[(ep.host, ep.port)] = self._codec()
        elif ep.scheme == "tcpin":
            self._server = await asyncio.start_server(self._serve, ep.host, ep.port)
        else:
            self._tasks.append(self._tg.create_task(self._tcp_client()))

    # ------------------------------------------------------------ sending
    def send(
        self, spec: MessageSpec, sysid: int | None = None, *, since_s: float | None = None
    ) -> None:
        """Queue ``spec`` for vehicle ``sysid`` (None: every peer). Never blocks.
        ``since_s``: for a setpoint, when the telemetry it answers arrived
        (``rx_time_s``); its write then adds a sample to ``latency``."""
        if sysid is None and not self._codecs:
            return  # a broadcast (HEARTBEAT) with nobody connected yet goes nowhere
        if spec.kind == "setpoint" and sysid is not None:
            if sysid in self._setpoints:
                self.stats.setpoints_dropped += 1
            self._setpoints[sysid] = spec
            if since_s is not None:
                self._since[sysid] = since_s
        else:
            if len(self._messages) >= MESSAGE_QUEUE_SIZE:
                self._messages.popleft()
                self.stats.messages_dropped += 1
            self._messages.append((spec, sysid))
        self._wake.set()

    def send_accel_setpoints(
        self,
        sysids: Sequence[int],
        compids: Sequence[int],
        time_boot_ms: Sequence[int],
        accel_ned: npt.NDArray[np.float64],
        since_s: Sequence[float | None],
        vel_ned: npt.NDArray[np.float64] | None = None,
    ) -> None:
        """One control step's acceleration setpoints (``builders.accel_setpoint``'s
        message), row k to vehicle ``sysids[k]``, written now (after whatever
        was queued before them). A setpoint still queued for one of these
        vehicles is replaced, and counted as dropped, as ``send`` would.
        ``since_s[k]``: arrival of the telemetry row k answers (latency).
        ``vel_ned``: a velocity setpoint per row [m/s] NED, NaN rows none; a
        row with one goes out with the acceleration as its feed-forward
        (``TYPE_MASK_VEL_ACCEL``, Eq. V1 of docs/setpoints.md)."""
        masks: int | list[int] = TYPE_MASK_ACCEL
        vel: npt.NDArray[np.float64] | None = None
        if vel_ned is not None:
            has = np.asarray(np.isfinite(vel_ned).all(axis=1))
            masks = np.where(has, TYPE_MASK_VEL_ACCEL, TYPE_MASK_ACCEL).tolist()
            vel = np.where(has[:, None], vel_ned, 0.0)
        for sysid in sysids:
            if self._setpoints.pop(sysid, None) is not None:
                self.stats.setpoints_dropped += 1
                self._since.pop(sysid, None)
        self.flush()
        rows: dict[Peer, list[int]] = {}
        for k, sysid in enumerate(sysids):
            peer = self._route(sysid)
            if peer is not None:
                rows.setdefault(peer, []).append(k)
        for peer, idx in rows.items():
            whole = len(idx) == len(sysids)
            try:
                data, size = self._codecs[peer].encode_accel_setpoints(
                    [(sysids[k], compids[k]) for k in idx],
                    time_boot_ms if whole else [time_boot_ms[k] for k in idx],
                    accel_ned if whole else accel_ned[idx],
                    type_mask=masks if isinstance(masks, int) or whole else [masks[k] for k in idx],
                    coordinate_frame=MAV_FRAME_LOCAL_NED,
                    vel_ned=vel if vel is None or whole else vel[idx],
                )
            except (struct.error, OverflowError, ValueError, TypeError) as err:
                self.stats.unencodable += len(idx)
                _log.error("%s: %d setpoints not sent: %s", self.endpoint, len(idx), err)
                continue
            self.stats.sent += len(idx)
            if self._on_frame is not None:
                for j in range(0, len(data), size):
                    self._on_frame(data[j : j + size], "out")
            self._send_frames(peer, data, [size] * len(idx), [since_s[k] for k in idx])

    def flush(self) -> None:
        """Write what is queued now rather than at the writer task's next turn
        (the station calls it once a control step's setpoints are queued).
        Nothing is written while no peer is known: the queues (bounded) wait."""
        if not self._codecs:
            return
        while self._messages:
            spec, sysid = self._messages.popleft()
            self._write(spec, sysid)
        setpoints, self._setpoints = self._setpoints, {}
        since, self._since = self._since, {}
        if setpoints:
            self._write_setpoints(setpoints, since)

    async def _writer(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            self.flush()
            for stream in self._streams:
                with contextlib.suppress(ConnectionError):
                    await stream.writer.drain()

    def _write(self, spec: MessageSpec, sysid: int | None) -> None:
        peers = list(self._codecs) if sysid is None else [self._route(sysid)]
        for peer in peers:
            if peer is None:
                continue
            data = self._encode(peer, spec)
            if data is not None:
                self._transmit(peer, data)

    def _write_setpoints(self, setpoints: dict[int, MessageSpec], since: dict[int, float]) -> None:
        """The setpoints queued in the slots, each peer's frames sent together."""
        frames: dict[Peer, tuple[list[bytes], list[float | None]]] = {}
        for sysid, spec in setpoints.items():
            peer = self._route(sysid)
            if peer is None:
                continue
            data = self._encode(peer, spec)
            if data is not None:
                datas, waits = frames.setdefault(peer, ([], []))
                datas.append(data)
                waits.append(since.get(sysid))
        for peer, (datas, waits) in frames.items():
            self._send_frames(peer, b"".join(datas), [len(d) for d in datas], waits)

    def _send_frames(
        self, peer: Peer, data: bytes, sizes: list[int], since: list[float | None]
    ) -> None:
        """Frames to ``peer`` (back to back in ``data``, ``sizes[k]`` bytes each)
        joined into datagrams of at most ``mavwire.MAX_DATAGRAM_BYTES`` (one
        control step's setpoints to one peer; the emulator's limit too); frame
        k answering a telemetry that arrived at ``since[k]`` adds its latency
        when its datagram is written."""
        first = start = 0
        for stop, end in datagram_bounds(sizes, MAX_DATAGRAM_BYTES):
            self._send_chunk(peer, data[start:end], since[first:stop])
            first, start = stop, end

    def _send_chunk(self, peer: Peer, datagram: bytes, since: list[float | None]) -> None:
        self._transmit(peer, datagram)
        now = time.monotonic()
        for t0 in since:
            if t0 is not None:
                self.latency.add(now - t0)

    def _encode(self, peer: Peer, spec: MessageSpec) -> bytes | None:
        """``spec`` framed by ``peer``'s codec (counted, and passed to
        ``on_frame``), or None if it cannot be framed."""
        try:
            data = self._codecs[peer].encode(spec)
        except (struct.error, OverflowError, ValueError, TypeError) as err:
            # A message that cannot be framed (a value out of its field's
            # range) is counted and dropped; the link and the station go on.
            self.stats.unencodable += 1
            _log.error("%s: %s not sent: %s", self.endpoint, spec.name, err)
            return None
        self.stats.sent += 1
        if self._on_frame is not None:
            self._on_frame(data, "out")
        return data

    def _transmit(self, peer: Peer, data: bytes) -> None:
        if isinstance(peer, _Stream):
            if not peer.writer.is_closing():
                peer.writer.write(data)
        elif self._udp is not None:
            if self.endpoint.scheme == "udpout":
                self._udp.sendto(data)
            else:
                self._udp.sendto(data, peer)

    def _route(self, sysid: int) -> Peer | None:
        peer = self._routes.get(sysid)
        if peer is None and len(self._codecs) == 1:
            peer = next(iter(self._codecs))
        return peer

    # ---------------------------------------------------------- receiving
    def _on_bytes(self, data: bytes, peer: Peer, *, datagram: bool) -> None:
        self.rx_time_s = time.monotonic()
        codec = self._codecs.get(peer)
        if codec is None:
            # An address not bound to any vehicle: the shared decoder, no state
            # kept (``_bound`` gives it a codec once one of its frames binds it).
            if self._stranger is None:
                self._stranger = self._codec()
            codec = self._stranger
        cs = codec.stats
        bad, unknown, rejected = cs.bad_packets, cs.unknown_messages, cs.signature_rejected
        on_position = self._on_position
        msgs = codec.decode(data, datagram=datagram, raw_positions=on_position is not None)
        self.stats.bad_packets += cs.bad_packets - bad
        self.stats.unknown_messages += cs.unknown_messages - unknown
        self.stats.signature_rejected += cs.signature_rejected - rejected
        run: list[RawPosition] = []
        for msg in msgs:
            raw = type(msg) is RawPosition
            if not self._bound(msg.sysid if raw else msg.get_srcSystem(), peer):
                self.stats.spoofed += 1
                continue
            self.stats.received += 1
            if raw:
                if self._on_frame is not None:
                    self._on_frame(msg.frame, "in")
                run.append(msg)
                continue
            if run:
                on_position(run, self)  # type: ignore[misc]
                run = []
            if self._on_frame is not None:
                self._on_frame(bytes(msg.get_msgbuf()), "in")
            self._on_message(msg, self)
        if run:
            on_position(run, self)  # type: ignore[misc]

    def _codec(self) -> Codec:
        key = self._signing_key
        return Codec(signing_key=key, streams=self._sig_streams, unix_s=time.time())

    @property
    def peer_count(self) -> int:
        """Peers this link keeps state for (a codec each)."""
        return len(self._codecs)

    def _bound(self, sysid: int, peer: Peer) -> bool:
        """True if ``peer`` may speak for ``sysid`` (binding it on first contact),
        at the arrival time of the bytes being decoded. A system id the link
        does not serve binds nothing (the station counts and ignores it)."""
        if self._sysids is not None and sysid not in self._sysids:
            return True
        now = self.rx_time_s
        bound = self._routes.get(sysid)
        if bound is not None and bound != peer:
            silent_s = now - self._heard.get(sysid, now)
            if not (self._allow_rebind and silent_s >= REBIND_S):
                self.rebinds_refused[sysid] += 1
                if self.rebinds_refused[sysid] == 1 and self._on_notice is not None:
                    self._on_notice(
                        f"{self.endpoint}: frames of vehicle {sysid} from {_name(peer)} refused: "
                        f"it is bound to {_name(bound)} for the run (silent {silent_s:.1f} s)"
                    )
                return False
            if self._on_notice is not None:
                self._on_notice(
                    f"{self.endpoint}: vehicle {sysid} rebound from {_name(bound)} to "
                    f"{_name(peer)} (signed, silent {silent_s:.1f} s; signing.allow_rebind)"
                )
            self._routes[sysid] = peer
            if bound not in self._routes.values() and not isinstance(bound, _Stream):
                self._codecs.pop(bound, None)  # speaks for nobody now: its state goes
        elif bound is None:
            self._routes[sysid] = peer
        if peer not in self._codecs:
            self._codecs[peer] = self._codec()
            self.stats.peers.add(_name(peer))
            self._wake.set()  # flush what was queued while nobody was connected
        self._heard[sysid] = now
        return True

    async def _read_stream(self, reader: asyncio.StreamReader, stream: _Stream) -> None:
        self._streams.append(stream)
        self._codecs[stream] = self._codec()
        self.stats.peers.add("tcp")
        self._wake.set()  # flush what was queued while nobody was connected
        try:
            while data := await reader.read(65536):
                self._on_bytes(data, stream, datagram=False)
        except ConnectionError as err:
            _log.warning("%s: connection lost: %s", self.endpoint, err)
        finally:
            self._streams.remove(stream)
            self._codecs.pop(stream, None)
            for sysid in [s for s, p in self._routes.items() if p is stream]:
                del self._routes[sysid]
            stream.writer.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        await self._read_stream(reader, _Stream(writer))

    async def _tcp_client(self) -> None:
        ep = self.endpoint
        while True:
            try:
                reader, writer = await asyncio.open_connection(ep.host, ep.port)
            except OSError as err:
                _log.warning("%s: cannot connect (%s); retrying", ep, err.strerror or err)
                self.stats.reconnects += 1
                await asyncio.sleep(_RECONNECT_S)
                continue
            await self._read_stream(reader, _Stream(writer))
            self.stats.reconnects += 1
            await asyncio.sleep(_RECONNECT_S)
