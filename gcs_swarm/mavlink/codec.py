"""The MAVLink codec of one peer, and the plain message specs it encodes.

Outbound messages are data (STYLE.md habit 4): a builder returns a
``MessageSpec`` (message name plus field values) and only the codec at the
edge turns it into bytes. One ``Codec`` per peer keeps that peer's sequence
numbers and parser state; it wraps pymavlink's generated ``ardupilotmega``
dialect (``MAVLink(None, sysid, compid)``, ``*_encode`` + ``pack``,
``parse_buffer``), never ``mavutil`` (habit 5).

Bad packets (CRC errors, garbage, truncated frames) are counted and dropped;
messages of ids the dialect does not know are counted and dropped too.
Nothing here does I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as _dialect

__all__ = ["STATION_COMPID", "STATION_SYSID", "Codec", "CodecStats", "MessageSpec"]

STATION_SYSID = 255
"""System id of the ground station (mavlink-protocol.md, Identity)."""
STATION_COMPID = 190
"""Component id of the ground station (MAV_COMP_ID_MISSIONPLANNER)."""

FieldValue = int | float | str | bytes | tuple[int, ...]


@dataclass(frozen=True, eq=True)
class MessageSpec:
    """An outbound message as data: ``name`` is the MAVLink message name
    (``"SET_POSITION_TARGET_LOCAL_NED"``), ``fields`` maps every field name of
    that message to its value, in the message's own units and frame.

    ``kind`` tells the transport which queue policy applies: ``"setpoint"``
    (newest wins, size 1 per vehicle) or ``"message"`` (FIFO, bounded).
    """

    name: str
    fields: Mapping[str, FieldValue]
    kind: str = "message"

    def __getitem__(self, key: str) -> FieldValue:
        return self.fields[key]

    @property
    def target_system(self) -> int | None:
        """The addressed system id, or None for a broadcast message."""
        value = self.fields.get("target_system")
        return None if value is None else int(value)  # type: ignore[arg-type]


@dataclass
class CodecStats:
    """Counters of one codec (monotonic, never reset)."""

    sent: int = 0
    bytes_sent: int = 0
    received: int = 0
    bad_packets: int = 0
    unknown_messages: int = 0


@dataclass
class Codec:
    """Encoder and decoder for one peer, as system ``sysid`` component ``compid``.

    ``encode`` packs a ``MessageSpec`` with this peer's next sequence number.
    ``decode`` parses received bytes and returns pymavlink message objects;
    ``datagram=True`` (UDP) drops any partial frame left at the end of the
    datagram so that one bad datagram cannot corrupt the next.
    """

    sysid: int = STATION_SYSID
    compid: int = STATION_COMPID
    stats: CodecStats = field(default_factory=CodecStats)

    def __post_init__(self) -> None:
        self._mav: Any = _dialect.MAVLink(None, self.sysid, self.compid)
        self._mav.robust_parsing = True

    def encode(self, spec: MessageSpec) -> bytes:
        """Pack ``spec`` into one MAVLink 2 frame and advance the sequence."""
        encoder = getattr(self._mav, spec.name.lower() + "_encode", None)
        if encoder is None:
            raise ValueError(f"unknown MAVLink message {spec.name!r}")
        fields = {
            key: (value.encode("ascii") if isinstance(value, str) else value)
            for key, value in spec.fields.items()
        }
        msg = encoder(**fields)
        buf: bytes = msg.pack(self._mav)
        # pymavlink's MAVLink.send() would write to a file and then advance
        # the sequence; we own the I/O, so advance it here.
        self._mav.seq = (self._mav.seq + 1) % 256
        self.stats.sent += 1
        self.stats.bytes_sent += len(buf)
        return buf

    def decode(self, data: bytes, *, datagram: bool = True) -> list[Any]:
        """Parse ``data``; return the good messages, count and drop the rest."""
        mav = self._mav
        try:
            parsed = mav.parse_buffer(data) or []
        except (_dialect.MAVError, ValueError, IndexError) as err:  # pragma: no cover - robust
            del err
            parsed = []
            self.stats.bad_packets += 1
            self._reset_parser()
        good: list[Any] = []
        for msg in parsed:
            if isinstance(msg, _dialect.MAVLink_bad_data):
                self.stats.bad_packets += 1
            elif isinstance(msg, _dialect.MAVLink_unknown):
                self.stats.unknown_messages += 1
            else:
                good.append(msg)
        if datagram and mav.buf_len() > 0:
            self.stats.bad_packets += 1
            self._reset_parser()
        self.stats.received += len(good)
        return good

    def _reset_parser(self) -> None:
        mav = self._mav
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = _dialect.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False
