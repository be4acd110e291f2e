"""MAVLink links over asyncio: UDP and TCP transports behind one ``Link`` class.

Connection strings follow pymavlink's conventions (mavlink-protocol.md,
"Identity and links"): ``udpin:HOST:PORT`` (listen), ``udpout:HOST:PORT``
(send first), ``tcp:HOST:PORT`` (connect, reconnecting), ``tcpin:HOST:PORT``
(listen). A ``Link`` is an ``async with`` lifetime owning one
``asyncio.TaskGroup``: the sockets, the writer task and the clock. Its
policy, without I/O, is ``gcs_swarm.swarm.link_state.LinkState``: peer
binding and the spoofing rule (issues 9 and 15), the queues (setpoints:
newest wins; messages: a bounded FIFO), datagram joining and the counters.
Bytes go in with their arrival time (``time.monotonic``); what the state
hands back is written to the socket, and each setpoint's latency taken.

A UDP link reads what is queued in its socket behind the datagram asyncio
hands it (up to ``READ_AHEAD``) and gives the state the lot: a report of a
vehicle that is not flying (start-up, ending) that a newer report of the
same vehicle follows in it is dropped unread (``LinkState.receive``,
``superseded``). A station that fell behind its telemetry (a loaded
machine) so reads the backlog at a fraction of the cost instead of
answering seconds-old reports one by one while the command answers and
HEARTBEATs behind them wait past their timeouts (measured, 1000 vehicles
on 2 cores, 2026-12-03: reports read 10-17 s after they were sent, no end
mode confirmed in 10 s). Flying vehicles' reports all go into the table
(cheap: newest wins there); nothing changes while the station keeps up.
What it reads together from one bound peer (a network's shared endpoint)
goes first to ``LinkState.receive_batches``, which takes at once the
datagrams that hold only flying vehicles' reports and unchanged status
(swarm/link_batch.py), and hands each one it declines (one holding a
report of a vehicle that is not flying) back alone, going on past it; the
rest as above.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import time
from collections import Counter
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs_swarm.errors import LinkError
from gcs_swarm.mavlink.codec import MessageSpec, RawPosition
from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.runtime.endpoints import Endpoint, LatencyRing, LinkStats, parse_connection
from gcs_swarm.runtime.lifetime import close_task_group
from gcs_swarm.swarm.link_state import (
    MESSAGE_QUEUE_SIZE,
    REBIND_S,
    LinkState,
    OnFrame,
    Write,
)

__all__ = [
    "BATCH_BYTES",
    "MESSAGE_QUEUE_SIZE",
    "READ_AHEAD",
    "REBIND_S",
    "UDP_RECEIVE_BUFFER_BYTES",
    "Endpoint",
    "LatencyRing",
    "Link",
    "LinkStats",
    "parse_connection",
]

_log = logging.getLogger("gcs_swarm.link")

UDP_RECEIVE_BUFFER_BYTES = 4 << 20
"""The receive buffer asked for a UDP link's socket [bytes] (the kernel caps
it at ``net.core.rmem_max``). Linux's default, 208 KiB, holds about a
tenth of a second of 250 vehicles' telemetry at 50 Hz; while the station
readied 750 vehicles at once it overflowed (``ss -m``: 3,300 datagrams
dropped per link in a minute, 2026-12-03), losing the answers the start-up
waits for. The emulator asks for 1 MiB for the same reason."""

READ_AHEAD = 64
"""Datagrams a UDP link takes from its socket at once at most (module
docstring): 64 datagrams of a shared endpoint are about 1,800 reports, seven
of each of 250 vehicles; the loop's other work waits no longer than that."""

BATCH_BYTES = 1280
"""Datagrams of one peer of at least this many bytes together (32
LOCAL_POSITION_NED frames) are first offered to ``LinkState.receive_batch``
(module docstring): its array work costs about 40 us a read, after which a
frame costs 0.9 us instead of 2.1-2.3 (measured in process: a read of 30
frames 73-81 us against 70-78 one by one, of 35 frames 78-83 against
82-91, of 70 frames 110-123 against 156-169)."""

_RECONNECT_S = 1.0

OnMessage = Callable[[Any, "Link"], None]
"""Called with each decoded pymavlink message and the link it came on."""
OnTelemetry = Callable[["Link"], None]
"""Called after a datagram (or stream chunk) whose flying vehicles' reports
went into the telemetry table, with the link."""


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, link: Link) -> None:
        self._link = link

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self._link._on_datagrams(data, addr)

    def error_received(self, exc: Exception) -> None:  # e.g. ICMP port unreachable
        _log.debug("%s: %s", self._link.endpoint, exc)


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
        telemetry: TelemetryTable | None = None,
        on_telemetry: OnTelemetry | None = None,
        signing_key: bytes | None = None,
        sysids: Collection[int] | None = None,
        allow_rebind: bool = False,
        on_notice: Callable[[str], None] | None = None,
        base: int = 0,
    ) -> None:
        """``on_message`` gets every decoded message, except the flying
        vehicles' reports written into ``telemetry`` (``LinkState``); after a
        datagram that wrote some, ``on_telemetry`` is called (the station's
        hot path).
        ``sysids``: the system ids this link serves (None: any); only they
        bind a peer. ``allow_rebind`` takes effect with a ``signing_key``
        only (``LinkState``). ``on_notice`` gets one line per refused or
        accepted rebinding of a vehicle (the first refusal only). ``base``:
        the keys of this link's network less its system ids (``LinkState``;
        ``sysids`` and what is sent are keys)."""
        self.connection = connection
        """The connection string as given (the swarm core's name of the link)."""
        self.endpoint = parse_connection(connection)
        self.state = LinkState(
            str(self.endpoint),
            unix_clock=time.time,
            signing_key=signing_key,
            sysids=sysids,
            allow_rebind=allow_rebind,
            telemetry=telemetry,
            on_frame=on_frame,
            on_notice=on_notice,
            base=base,
        )
        self.latency = LatencyRing()
        """Telemetry-arrival-to-setpoint-write times of this link's setpoints."""
        self._on_message = on_message
        self._on_telemetry = on_telemetry
        self._wake = asyncio.Event()
        self._udp: asyncio.DatagramTransport | None = None
        self._ahead: socket.socket | None = None
        """The UDP socket (a duplicate of asyncio's) read ahead (``READ_AHEAD``)."""
        self._streams: list[_Stream] = []
        self._server: asyncio.Server | None = None
        self._tg = asyncio.TaskGroup()
        self._tasks: list[asyncio.Task[None]] = []

    @property
    def stats(self) -> LinkStats:
        return self.state.stats

    @property
    def rebinds_refused(self) -> Counter[int]:
        """Frames refused per system id because they came from another peer
        than the one the id is bound to."""
        return self.state.rebinds_refused

    @property
    def rx_time_s(self) -> float:
        """``time.monotonic()`` when the datagram (or stream chunk) being decoded arrived."""
        return self.state.rx_time_s

    @property
    def peer_count(self) -> int:
        """Peers this link keeps state for (a codec each)."""
        return self.state.peer_count

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
            if self._ahead is not None:
                self._ahead.close()
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
            self.state.connect((ep.host, ep.port))
        elif ep.scheme == "tcpin":
            self._server = await asyncio.start_server(self._serve, ep.host, ep.port)
        else:
            self._tasks.append(self._tg.create_task(self._tcp_client()))
        if self._udp is not None:
            sock = self._udp.get_extra_info("socket")
            with contextlib.suppress(OSError):  # a platform that refuses keeps its default
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RECEIVE_BUFFER_BYTES)
            self._ahead = sock.dup()  # non-blocking as asyncio's: the same socket

    # ------------------------------------------------------------ sending
    def send(
        self, spec: MessageSpec, sysid: int | None = None, *, since_s: float | None = None
    ) -> None:
        """Queue ``spec`` for vehicle ``sysid`` (None: every peer). Never blocks.
        ``since_s``: for a setpoint, when the telemetry it answers arrived
        (``rx_time_s``); its write then adds a sample to ``latency``."""
        if self.state.send(spec, sysid, since_s):
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
        """One control step's acceleration setpoints (``LinkState.accel_setpoints``),
        written now, after whatever was queued before them."""
        self._write(
            self.state.accel_setpoints(sysids, compids, time_boot_ms, accel_ned, since_s, vel_ned)
        )

    def flush(self) -> None:
        """Write what is queued now rather than at the writer task's next turn
        (the station calls it once a control step's setpoints are queued).
        Nothing is written while no peer is known: the queues (bounded) wait."""
        self._write(self.state.datagrams_to_send())

    async def _writer(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            self.flush()
            for stream in self._streams:
                with contextlib.suppress(ConnectionError):
                    await stream.writer.drain()

    def _write(self, writes: list[Write]) -> None:
        """Each datagram to its peer; a setpoint's latency is taken at its write."""
        udp, out = self._udp, self.endpoint.scheme == "udpout"
        latency = self.latency
        for peer, data, since in writes:
            if isinstance(peer, _Stream):
                if not peer.writer.is_closing():
                    peer.writer.write(data)
            elif udp is not None:
                if out:
                    udp.sendto(data)
                else:
                    udp.sendto(data, peer)
            if since:
                latency.add_since(time.monotonic(), since)

    # ---------------------------------------------------------- receiving
    def _on_datagrams(self, data: bytes, addr: Any) -> None:
        """The datagram asyncio read, then those queued behind it (module
        docstring): from one bound peer they are decoded first, and the
        reports a newer one of the same vehicle follows are marked
        ``superseded``; each datagram then goes to the state in order. All
        of them arrived when they were read: one time for the lot (the
        setpoints' latency counts the decoding of the datagrams before a
        report's). Those of at least ``BATCH_BYTES`` together go first to
        ``LinkState.receive_batches``, which takes as many as it can at
        once, handing back here each datagram it declines, alone."""
        batch = [(data, addr)]
        ahead = self._ahead
        while ahead is not None and len(batch) < READ_AHEAD:
            try:
                batch.append(ahead.recvfrom(65536))
            except OSError:  # nothing queued (or an ICMP error: asyncio's to report)
                break
        now = time.monotonic()  # one arrival time for what was read together
        state = self.state
        if not state.knows(addr) or any(a != addr for _, a in batch):
            for item, peer in batch:
                self._on_bytes(item, peer, datagram=True, now=now)
            return
        if sum(len(item) for item, _ in batch) >= BATCH_BYTES:
            on_telemetry = self._on_telemetry

            def alone(item: bytes) -> None:  # a datagram the batch declined
                self._on_bytes(item, addr, datagram=True, now=now)

            def took() -> None:
                if on_telemetry is not None:
                    on_telemetry(self)

            del batch[: state.receive_batches([item for item, _ in batch], addr, now, alone, took)]
        if len(batch) <= 1:
            for item, peer in batch:
                self._on_bytes(item, peer, datagram=True, now=now)
            return
        decoded = [state.decode(item, addr) for item, _ in batch]
        newest: dict[int, int] = {}
        for _, msgs in decoded:
            for m in msgs:
                if type(m) is RawPosition:
                    newest[m.sysid] = id(m)
        superseded = {
            id(m)
            for _, msgs in decoded
            for m in msgs
            if type(m) is RawPosition and newest[m.sysid] != id(m)
        }
        for (item, _), pre in zip(batch, decoded, strict=True):
            self._on_bytes(item, addr, datagram=True, decoded=pre, superseded=superseded, now=now)

    def _on_bytes(
        self,
        data: bytes,
        peer: Any,
        *,
        datagram: bool,
        decoded: tuple[Any, list[Any]] | None = None,
        superseded: Collection[int] = (),
        now: float | None = None,
    ) -> None:
        """``data`` from ``peer`` through the state, arrived at ``now`` [s]
        (``time.monotonic``; None: now)."""
        state = self.state
        now = time.monotonic() if now is None else now
        items = state.receive(data, peer, now, datagram=datagram,
                              decoded=decoded, superseded=superseded)  # fmt: skip
        if state.peer_added:
            state.peer_added = False
            self._wake.set()  # flush what was queued while nobody was connected
        on_message = self._on_message
        for item in items:
            on_message(item, self)
        if state.positions_written and self._on_telemetry is not None:
            self._on_telemetry(self)

    async def _read_stream(self, reader: asyncio.StreamReader, stream: _Stream) -> None:
        self._streams.append(stream)
        self.state.connect(stream, stream=True)
        self.state.peer_added = False
        self._wake.set()  # flush what was queued while nobody was connected
        try:
            while data := await reader.read(65536):
                self._on_bytes(data, stream, datagram=False)
        except ConnectionError as err:
            _log.warning("%s: connection lost: %s", self.endpoint, err)
        finally:
            self._streams.remove(stream)
            self.state.disconnect(stream)
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
