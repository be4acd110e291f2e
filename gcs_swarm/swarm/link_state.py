"""One MAVLink link's policy without I/O: binding, spoofing, queues, joining, counters.

``LinkState`` is what the asyncio ``runtime.links.Link`` used to hold, with
its sockets taken out (STYLE.md habit 1): bytes go in with the peer they
came from and their arrival time (``receive``); what to write comes out as
``(peer, datagram, since)`` triples (``datagrams_to_send``,
``accel_setpoints``) for the transport to send. A peer is any hashable the
transport chooses (a UDP address tuple, a TCP connection object); stream
peers are announced with ``connect``/``disconnect``.

Several system ids may share one link: inbound messages carry their
sender's id and each reply goes to the peer that id was last heard from;
broadcasts (the station HEARTBEAT) go to every peer. One ``Codec`` per peer
(sequence numbers and parser state). Outbound policy (STYLE.md habit 6):
- setpoints: one slot per vehicle, newest wins, overwritten ones counted;
- other messages: FIFO of ``MESSAGE_QUEUE_SIZE``; when full the oldest is
  dropped and counted (commands are resent by the protocol on timeout).

Security (issues 9 and 15): a system id is bound to the peer it was first
heard from, for the whole run. Frames carrying that id from another peer
are spoofing: counted in ``LinkStats.spoofed`` and, per system id, in
``rebinds_refused``, dropped, and reported once per vehicle (``on_notice``).
The one exception (``allow_rebind``): on a signed link, once the bound peer
has been silent for ``REBIND_S``, a peer whose frames carry a good signature
may take the id over (a vehicle that rebooted onto a new port); this is
reported too. Without signing a vehicle is never handed to a new address.

Listening links (issue 15): a datagram from an unknown address is decoded
by one shared codec and leaves nothing behind; the address gets its own
codec only once it is bound to one of the link's ``sysids``, so garbage from
any number of ports keeps no state and draws no reply. A peer that no
longer speaks for any system id (rebound away) loses its codec.

Flying telemetry (issue 16): with a ``telemetry`` table, an unsigned
LOCAL_POSITION_NED of a vehicle the link serves, from its bound peer, goes
straight into that vehicle's row (``TelemetryTable.write``) when the row
takes it (the vehicle is FLYING, the report plausible and newer), and so
does an unsigned HEARTBEAT or status message the row recognises as the one
its FLYING protocol last handled (``TelemetryTable.unchanged``: only the
vehicle's liveness time moves); anything else comes out of ``receive`` as the
message pymavlink's own decoder makes of the frame, in order. A vehicle's
report or HEARTBEAT after another message of it in the same datagram comes
out as a message too, so that what the protocol hears keeps the datagram's
order (a HEARTBEAT may end its flight). ``receive_batch`` (swarm/link_batch.py)
takes many datagrams of one peer at once while they hold nothing else.
Datagram joining: one control step's frames to one peer go out joined into
datagrams of at most ``mavwire.MAX_DATAGRAM_BYTES``.
"""

from __future__ import annotations

import logging
import struct
from collections import Counter, deque
from collections.abc import Callable, Collection, Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from gcs_swarm.mavlink.builders import MAV_FRAME_LOCAL_NED, TYPE_MASK_ACCEL, TYPE_MASK_VEL_ACCEL
from gcs_swarm.mavlink.builders import MSG_ID_LOCAL_POSITION_NED as LPN_ID
from gcs_swarm.mavlink.codec import Codec, MessageSpec, RawHeartbeat, RawPosition, RawStatus
from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.swarm.link_batch import _LinkBatch
from mavwire.datagrams import MAX_DATAGRAM_BYTES, datagram_bounds

__all__ = ["MESSAGE_QUEUE_SIZE", "REBIND_S", "LinkState", "LinkStats", "Write"]

_log = logging.getLogger("gcs_swarm.link")

MESSAGE_QUEUE_SIZE = 256
"""Bound of a link's FIFO of non-setpoint messages."""
REBIND_S = 5.0
"""Silence [s] of a system id's peer after which another, well-signed, peer
may take it over when the link allows rebinding (signed links only)."""

Peer = Hashable
"""A UDP address tuple, or a transport's connection object."""
Write = tuple[Any, bytes, list[float | None]]
"""(peer, datagram, arrival times [s] of the telemetry its setpoints answer)."""
OnFrame = Callable[[bytes, Literal["in", "out"]], None]
"""Called with every raw frame decoded ("in") or framed to send ("out")."""


@dataclass
class LinkStats:
    """Counters of one link (monotonic)."""

    received: int = 0
    sent: int = 0
    bad_packets: int = 0
    unknown_messages: int = 0
    setpoints_dropped: int = 0
    messages_dropped: int = 0
    reconnects: int = 0
    spoofed: int = 0
    signature_rejected: int = 0
    unencodable: int = 0
    reports_superseded: int = 0  # not flying, dropped unread: a newer one followed (receive)
    frames_batched: int = 0  # of ``received``, taken many datagrams at once (receive_batch)
    peers: set[str] = field(default_factory=set)


class LinkState(_LinkBatch):
    """The policy of one MAVLink link shared by any number of vehicles."""

    def __init__(
        self,
        name: str,
        *,
        unix_clock: Callable[[], float],
        signing_key: bytes | None = None,
        sysids: Collection[int] | None = None,
        allow_rebind: bool = False,
        telemetry: TelemetryTable | None = None,
        on_frame: OnFrame | None = None,
        on_notice: Callable[[str], None] | None = None,
        base: int = 0,
    ) -> None:
        """``name``: the link's connection string (for notices and the log).
        ``base``: what the vehicles' keys add to their system ids on this
        link's network (``mission.vehicle_key``: network index * 256); the
        link speaks system ids on the wire and keys to everyone else
        (``sysids``, ``send``, ``accel_setpoints``, the telemetry rows).
        ``unix_clock``: the Unix time now (signing timestamps of new codecs).
        ``sysids``: the system ids this link serves (None: any); only they
        bind a peer. ``allow_rebind`` takes effect with a ``signing_key``
        only. ``telemetry``: the table flying vehicles' reports are written
        to (module docstring); it needs ``sysids``.
        ``on_notice`` gets one line per refused (the first) or accepted
        rebinding of a vehicle."""
        self.name = name
        self._unix_clock = unix_clock
        self._signing_key = signing_key
        self.base = base
        self._sysids = None if sysids is None else frozenset(s - base for s in sysids)
        self._allow_rebind = allow_rebind and signing_key is not None
        self._table = telemetry
        slot = {} if telemetry is None or self._sysids is None else telemetry.slot
        self._rows = {s: slot[s + base] for s in self._sysids or () if s + base in slot}
        """Table row of each system id this link serves."""
        self.positions_written = 0
        """Reports the last ``receive`` wrote into the table."""
        self._on_frame = on_frame
        self._on_notice = on_notice
        self.stats = LinkStats()
        self.rebinds_refused: Counter[int] = Counter()
        """Frames refused per system id because they came from another peer
        than the one the id is bound to."""
        self.rx_time_s = 0.0
        """Arrival time [s] of the bytes being decoded (``receive``'s ``now``)."""
        self.peer_added = False
        """Set when a peer got its codec (something queued may now go out);
        the transport clears it."""
        self._stranger: Codec | None = None
        self._sig_streams: dict[tuple[int, int, int], int] = {}
        self._heard: dict[int, float] = {}
        self._codecs: dict[Any, Codec] = {}
        self._held: set[Any] = set()
        self._routes: dict[int, Any] = {}
        self._setpoints: dict[int, MessageSpec] = {}
        self._since: dict[int, float] = {}
        self._messages: deque[tuple[MessageSpec, int | None]] = deque()
        self._rows_cache: tuple[tuple[int, ...], dict[Any, list[int]]] | None = None
        """``_peer_rows``' last answer, dropped when a route or a codec changes."""

    # -------------------------------------------------------------- peers
    def connect(self, peer: Peer, *, stream: bool = False) -> None:
        """A peer known without having spoken: a ``udpout`` address, or a
        stream connection (which keeps its codec until ``disconnect``)."""
        self._codecs[peer] = self._codec()
        self._rows_cache = None
        if stream:
            self._held.add(peer)
            self.stats.peers.add("tcp")
            self.peer_added = True

    def disconnect(self, peer: Peer) -> None:
        """A stream connection closed: its codec and its system ids' routes go."""
        self._held.discard(peer)
        self._codecs.pop(peer, None)
        self._rows_cache = None
        for sysid in [s for s, p in self._routes.items() if p == peer]:
            del self._routes[sysid]

    @property
    def peer_count(self) -> int:
        """Peers this link keeps state for (a codec each)."""
        return len(self._codecs)

    def route(self, sysid: int) -> Any | None:
        """The peer ``sysid`` answers to (the only one if it was never heard)."""
        peer = self._routes.get(sysid)
        if peer is None and len(self._codecs) == 1:
            peer = next(iter(self._codecs))
        return peer

    def peer_name(self, peer: Peer) -> str:
        if isinstance(peer, tuple) and len(peer) >= 2:
            return f"{peer[0]}:{peer[1]}"
        return "tcp" if peer in self._held else str(peer)

    # ---------------------------------------------------------- receiving
    def receive(self, data: bytes, peer: Peer, now: float, *, datagram: bool,
                decoded: tuple[Codec, list[Any]] | None = None,
                superseded: Collection[int] = ()) -> list[Any]:  # fmt: skip
        """Decode ``data`` from ``peer`` (arrived at ``now``) and keep what
        its peer may say: pymavlink messages, in order; flying vehicles'
        reports the telemetry table took are not among them (counted in
        ``positions_written``). ``decoded``: ``decode``'s answer for ``data``
        (read ahead); ``superseded``: the ids of its ``RawPosition`` that a
        newer report of the same vehicle follows: dropped unless it flies
        (still told to ``on_inbound``: received, not lost)."""
        self.rx_time_s = now
        self.positions_written = 0
        codec, msgs = self.decode(data, peer, datagram) if decoded is None else decoded
        table, stats = self._table, self.stats
        owners = None if table is None else table.owners
        inbound = None if table is None else table.on_inbound
        on_frame = self._on_frame
        out: list[Any] = []
        rows = self._rows
        spoke: set[int] = set()
        """System ids with a message already out of this datagram."""
        written = received = 0
        route, heard = self._routes.get, self._heard
        write = None if table is None else table.write
        said = None if table is None else table.unchanged
        for msg in msgs:
            kind = type(msg)
            raw = kind is RawPosition or kind is RawHeartbeat or kind is RawStatus
            sysid = msg[0] if raw else msg.get_srcSystem()
            if route(sysid) == peer:
                heard[sysid] = now  # ``_bound``'s answer for a peer already bound to it
            elif not self._bound(sysid, peer, now):
                stats.spoofed += 1
                continue
            received += 1
            if raw:
                _, compid, seq, frame, values = msg
                if on_frame is not None:
                    on_frame(frame, "in")
                k = rows.get(sysid)
                if k is not None and write is not None and sysid not in spoke:
                    if kind is RawPosition:
                        if write(k, compid, seq, values, now, now):
                            written += 1
                            continue
                    elif said is not None and said(k, compid, seq, frame[7], values, now):
                        continue  # a flying vehicle's unchanged HEARTBEAT or status: heard
                if superseded and id(msg) in superseded and (k is None or owners is None
                                                             or owners[k] is None):  # fmt: skip
                    stats.reports_superseded += 1
                    if inbound is not None:
                        inbound(sysid + self.base, compid, seq, LPN_ID)
                    continue
                msg = codec.message(msg)  # pymavlink's own decoder, off the hot path
            elif on_frame is not None:
                on_frame(bytes(msg.get_msgbuf()), "in")
            spoke.add(sysid)
            out.append(msg)
        stats.received += received
        self.positions_written = written
        return out

    def decode(self, data: bytes, peer: Peer, datagram: bool = True) -> tuple[Codec, list[Any]]:
        """(codec, frames) of ``data`` from ``peer``; ``knows(peer)``: its own codec."""
        codec = self._codecs.get(peer)
        if codec is None:  # not bound: the shared decoder, no state kept (``_bound``)
            if self._stranger is None:
                self._stranger = self._codec()
            codec = self._stranger
        cs, stats = codec.stats, self.stats
        bad, unknown, rejected = cs.bad_packets, cs.unknown_messages, cs.signature_rejected
        msgs = codec.decode(data, datagram=datagram, raw_positions=self._table is not None)
        stats.bad_packets += cs.bad_packets - bad
        stats.unknown_messages += cs.unknown_messages - unknown
        stats.signature_rejected += cs.signature_rejected - rejected
        return codec, msgs

    def knows(self, peer: Peer) -> bool:
        """``peer`` is bound to a vehicle (has a codec of its own)."""
        return peer in self._codecs

    def _bound(self, sysid: int, peer: Peer, now: float) -> bool:
        """True if ``peer`` may speak for ``sysid`` (binding it on first contact)
        at ``now``. A system id the link does not serve binds nothing (the
        station counts and ignores it)."""
        if self._sysids is not None and sysid not in self._sysids:
            return True
        bound = self._routes.get(sysid)
        if bound is not None and bound != peer:
            silent_s = now - self._heard.get(sysid, now)
            if not (self._allow_rebind and silent_s >= REBIND_S):
                self.rebinds_refused[sysid] += 1
                if self.rebinds_refused[sysid] == 1 and self._on_notice is not None:
                    self._on_notice(
                        f"{self.name}: frames of vehicle {sysid} from {self.peer_name(peer)} "
                        f"refused: it is bound to {self.peer_name(bound)} for the run "
                        f"(silent {silent_s:.1f} s)"
                    )
                return False
            if self._on_notice is not None:
                self._on_notice(
                    f"{self.name}: vehicle {sysid} rebound from {self.peer_name(bound)} to "
                    f"{self.peer_name(peer)} (signed, silent {silent_s:.1f} s; "
                    "signing.allow_rebind)"
                )
            self._routes[sysid] = peer
            self._rows_cache = None
            if bound not in self._routes.values() and bound not in self._held:
                self._codecs.pop(bound, None)  # speaks for nobody now: its state goes
                self._rows_cache = None
        elif bound is None:
            self._routes[sysid] = peer
            self._rows_cache = None
        if peer not in self._codecs:
            self._codecs[peer] = self._codec()
            self._rows_cache = None
            self.stats.peers.add(self.peer_name(peer))
            self.peer_added = True  # what was queued while nobody was connected may go
        self._heard[sysid] = now
        return True

    def _codec(self) -> Codec:
        key = self._signing_key
        return Codec(signing_key=key, streams=self._sig_streams, unix_s=self._unix_clock())

    # ------------------------------------------------------------ sending
    def send(
        self, spec: MessageSpec, sysid: int | None = None, since_s: float | None = None
    ) -> bool:
        """Queue ``spec`` for vehicle ``sysid`` (None: every peer); False if
        it went nowhere (a broadcast with nobody connected yet). ``since_s``:
        for a setpoint, when the telemetry it answers arrived."""
        if self.base and sysid is not None:
            sysid -= self.base
            spec = _on_wire(spec, self.base)
        if sysid is None and not self._codecs:
            return False
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
        return True

    def datagrams_to_send(self) -> list[Write]:
        """Everything queued, framed: messages first (FIFO), then the setpoint
        slots, each peer's setpoints joined. Nothing while no peer is known:
        the (bounded) queues wait."""
        if not self._codecs:
            return []
        out: list[Write] = []
        while self._messages:
            spec, sysid = self._messages.popleft()
            peers = list(self._codecs) if sysid is None else [self.route(sysid)]
            for peer in peers:
                if peer is None:
                    continue
                data = self._encode(peer, spec)
                if data is not None:
                    out.append((peer, data, []))
        setpoints, self._setpoints = self._setpoints, {}
        since, self._since = self._since, {}
        if setpoints:
            frames: dict[Any, tuple[list[bytes], list[float | None]]] = {}
            for sysid, spec in setpoints.items():
                peer = self.route(sysid)
                if peer is None:
                    continue
                data = self._encode(peer, spec)
                if data is not None:
                    datas, waits = frames.setdefault(peer, ([], []))
                    datas.append(data)
                    waits.append(since.get(sysid))
            for peer, (datas, waits) in frames.items():
                self._join(out, peer, b"".join(datas), [len(d) for d in datas], waits)
        return out

    def accel_setpoints(
        self,
        sysids: Sequence[int],
        compids: Sequence[int],
        time_boot_ms: Sequence[int],
        accel_ned: npt.NDArray[np.float64],
        since_s: Sequence[float | None],
        vel_ned: npt.NDArray[np.float64] | None = None,
    ) -> list[Write]:
        """One control step's acceleration setpoints, row k to ``sysids[k]``,
        after whatever was queued (returned first, as ``datagrams_to_send``).
        A setpoint still queued for one of these vehicles is replaced and
        counted as dropped. ``since_s[k]``: arrival of the telemetry row k
        answers. ``vel_ned``: a velocity setpoint per row [m/s] NED, NaN rows
        none; a row with one goes out with the acceleration as its
        feed-forward (``TYPE_MASK_VEL_ACCEL``, Eq. V1 of docs/setpoints.md)."""
        masks: int | list[int] = TYPE_MASK_ACCEL
        vel: npt.NDArray[np.float64] | None = None
        if vel_ned is not None:
            has = np.asarray(np.isfinite(vel_ned).all(axis=1))
            masks = np.where(has, TYPE_MASK_VEL_ACCEL, TYPE_MASK_ACCEL).tolist()
            vel = np.where(has[:, None], vel_ned, 0.0)
        if self.base:
            sysids = [s - self.base for s in sysids]
        queued = self._setpoints
        if queued:
            for sysid in sysids:
                if queued.pop(sysid, None) is not None:
                    self.stats.setpoints_dropped += 1
                    self._since.pop(sysid, None)
        out = self.datagrams_to_send()
        for peer, idx in self._peer_rows(sysids).items():
            whole = len(idx) == len(sysids)
            try:
                data, size = self._codecs[peer].encode_accel_setpoints(
                    list(zip(sysids, compids, strict=True))
                    if whole
                    else [(sysids[k], compids[k]) for k in idx],
                    time_boot_ms if whole else [time_boot_ms[k] for k in idx],
                    accel_ned if whole else accel_ned[idx],
                    type_mask=masks if isinstance(masks, int) or whole else [masks[k] for k in idx],
                    coordinate_frame=MAV_FRAME_LOCAL_NED,
                    vel_ned=vel if vel is None or whole else vel[idx],
                )
            except (struct.error, OverflowError, ValueError, TypeError) as err:
                self.stats.unencodable += len(idx)
                _log.error("%s: %d setpoints not sent: %s", self.name, len(idx), err)
                continue
            self.stats.sent += len(idx)
            if self._on_frame is not None:
                for j in range(0, len(data), size):
                    self._on_frame(data[j : j + size], "out")
            self._join(out, peer, data, [size] * len(idx),
                       list(since_s) if whole else [since_s[k] for k in idx])  # fmt: skip
        return out

    def _peer_rows(self, sysids: Sequence[int]) -> dict[Any, list[int]]:
        """The rows of ``sysids`` each peer gets (``route``), kept for the
        next step with the same vehicles until a route or a codec changes
        (``_routes_changed``): the same vehicles every 20 ms."""
        key = tuple(sysids)
        cached = self._rows_cache
        if cached is not None and cached[0] == key:
            return cached[1]
        rows: dict[Any, list[int]] = {}
        for k, sysid in enumerate(key):
            peer = self.route(sysid)
            if peer is not None:
                rows.setdefault(peer, []).append(k)
        self._rows_cache = (key, rows)
        return rows

    def _join(
        self,
        out: list[Write],
        peer: Any,
        data: bytes,
        sizes: list[int],
        since: list[float | None],
    ) -> None:
        """Frames to ``peer`` (back to back in ``data``, ``sizes[k]`` bytes each)
        joined into datagrams of at most ``mavwire.MAX_DATAGRAM_BYTES`` (the
        emulator's limit too), appended to ``out``."""
        first = start = 0
        for stop, end in datagram_bounds(sizes, MAX_DATAGRAM_BYTES):
            out.append((peer, data[start:end], since[first:stop]))
            first, start = stop, end

    def _encode(self, peer: Any, spec: MessageSpec) -> bytes | None:
        """``spec`` framed by ``peer``'s codec (counted, and passed to
        ``on_frame``), or None if it cannot be framed."""
        try:
            data = self._codecs[peer].encode(spec)
        except (struct.error, OverflowError, ValueError, TypeError) as err:
            # A message that cannot be framed (a value out of its field's
            # range) is counted and dropped; the link and the station go on.
            self.stats.unencodable += 1
            _log.error("%s: %s not sent: %s", self.name, spec.name, err)
            return None
        self.stats.sent += 1
        if self._on_frame is not None:
            self._on_frame(data, "out")
        return data


def _on_wire(spec: MessageSpec, base: int) -> MessageSpec:
    """``spec`` addressed by system id: its ``target_system`` (a vehicle's
    key, from the station) less the network's ``base``."""
    target = spec.fields.get("target_system")
    if not isinstance(target, int) or target < base:
        return spec
    return MessageSpec(spec.name, {**spec.fields, "target_system": target - base}, spec.kind)
