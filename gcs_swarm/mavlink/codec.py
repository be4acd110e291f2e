"""The MAVLink codec of one peer, and the plain message specs it encodes.

Outbound messages are data (STYLE.md habit 4): a builder returns a
``MessageSpec`` (message name plus field values) and only the codec at the
edge turns it into bytes. One ``Codec`` per peer keeps that peer's sequence
numbers and parser state; it wraps pymavlink's generated ``ardupilotmega``
dialect (``MAVLink(None, sysid, compid)``, ``*_encode`` + ``pack``,
``parse_buffer``), never ``mavutil`` (habit 5).

Bad packets (CRC errors, garbage, truncated frames) are counted and dropped;
messages of ids the dialect does not know are counted and dropped too.

MAVLink 2 signing (issue 9): with a 32-byte ``signing_key`` every frame sent
is signed (pymavlink's ``MAVLink.signing``: ``secret_key``, ``link_id``,
``timestamp`` in 10 us units since 2015-01-01 UTC, ``sign_outgoing``) and a
received frame is accepted only if its signature is good and its timestamp
newer than the last of its stream (link id, system, component): unsigned,
wrongly signed and replayed frames are counted in ``signature_rejected`` and
dropped. Only RADIO_STATUS may come unsigned, as on ArduPilot. The key is
never logged or shown (``repr`` hides it). The signing set-up, the CRC and
the column-wise frame building (``mavwire.FrameBuilder``) are ``mavwire``'s,
shared with the emulator; ``self._mav`` is typed by ``mavwire.protocols``.
Nothing here does I/O.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from itertools import chain
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import ardupilotmega as _dialect

from gcs_swarm.mavlink.events import register as _register_event
from gcs_swarm.mavlink.frame_decode import decode_unsigned as _decode_unsigned
from gcs_swarm.mavlink.raw_frames import RAW_LAYOUTS as _RAW_LAYOUTS
from gcs_swarm.mavlink.raw_frames import RawHeartbeat, RawPosition, RawStatus
from gcs_swarm.mavlink.raw_frames import raw_frame as _raw_frame
from mavwire.framing import FrameBuilder
from mavwire.protocols import MAVLinkInterface, MAVLinkMessage
from mavwire.signing import SIGNING_KEY_BYTES, mavlink

_register_event()  # PX4's EVENT (410) is not in pymavlink's dialect (events.py)

__all__ = [
    "SETPOINT_FIELDS",
    "SIGNING_KEY_BYTES",
    "STATION_COMPID",
    "STATION_SYSID",
    "Codec",
    "CodecStats",
    "MessageSpec",
    "RawHeartbeat",
    "RawPosition",
    "RawStatus",
]

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
    signature_rejected: int = 0


@dataclass
class Codec:
    """Encoder and decoder for one peer, as system ``sysid`` component ``compid``.

    ``encode`` packs a ``MessageSpec`` with this peer's next sequence number.
    ``decode`` parses received bytes and returns pymavlink message objects;
    ``datagram=True`` (UDP) drops any partial frame left at the end of the
    datagram so that one bad datagram cannot corrupt the next.
    ``signing_key`` (32 bytes) turns MAVLink 2 signing on, both ways, with
    timestamps from ``unix_s`` (the Unix time now, required with a key);
    ``streams`` shares the last timestamp of each signed stream (link id,
    system, component) between the codecs of one link, so that a frame
    replayed from another peer is as old as it is from the first.
    """

    sysid: int = STATION_SYSID
    compid: int = STATION_COMPID
    stats: CodecStats = field(default_factory=CodecStats)
    signing_key: bytes | None = field(default=None, repr=False)
    streams: dict[tuple[int, int, int], int] | None = field(default=None, repr=False)
    unix_s: float | None = None

    def __post_init__(self) -> None:
        self._mav: MAVLinkInterface = mavlink(
            self.sysid, self.compid, self.signing_key, unix_s=self.unix_s
        )
        if self.signing_key is not None and self.streams is not None:
            self._mav.signing.stream_timestamps = self.streams

    @property
    def signing(self) -> bool:
        return self.signing_key is not None

    def encode(self, spec: MessageSpec) -> bytes:
        """Pack ``spec`` into one MAVLink 2 frame and advance the sequence.

        Unsigned SET_POSITION_TARGET_LOCAL_NED (the setpoint, 50 Hz per
        vehicle) is packed here with the dialect's struct and CRC, the bytes
        pymavlink's ``pack`` makes, without a message object per setpoint."""
        if spec.name == _SP.msgname and not self._mav.signing.sign_outgoing:
            buf = _pack_setpoint(self._mav, [spec.fields[name] for name in _SP_NAMES])
        else:
            encoder = getattr(self._mav, spec.name.lower() + "_encode", None)
            if encoder is None:
                raise ValueError(f"unknown MAVLink message {spec.name!r}")
            fields = {
                key: (value.encode("ascii") if isinstance(value, str) else value)
                for key, value in spec.fields.items()
            }
            msg: MAVLinkMessage = encoder(**fields)
            buf = msg.pack(self._mav)
        self._advance(1, len(buf))
        return buf

    def encode_setpoint(self, values: tuple[FieldValue, ...]) -> bytes:
        """Like ``encode`` for a SET_POSITION_TARGET_LOCAL_NED given as its
        field values in wire order (``SETPOINT_FIELDS``), with no
        ``MessageSpec``: ``encode_accel_setpoints``'s path for a few frames."""
        if self._mav.signing.sign_outgoing:
            spec = MessageSpec(_SP.msgname, dict(zip(_SP_NAMES, values, strict=True)), "setpoint")
            return self.encode(spec)
        buf = _pack_setpoint(self._mav, values)
        self._advance(1, len(buf))
        return buf

    def encode_accel_setpoints(
        self,
        targets: Sequence[tuple[int, int]],
        time_boot_ms: Sequence[int],
        accel_ned: npt.NDArray[np.float64],
        *,
        type_mask: int | Sequence[int],
        coordinate_frame: int,
        vel_ned: npt.NDArray[np.float64] | None = None,
    ) -> tuple[bytes, int]:
        """Many SET_POSITION_TARGET_LOCAL_NED at once: row k addressed to
        ``targets[k]`` (system, component), acceleration ``accel_ned[k]``
        [m/s^2], velocity ``vel_ned[k]`` [m/s] (None: zero), position and yaw
        fields zero, ``type_mask`` one for all or one per row. Returns the frames
        back to back and the length of one (all the same): exactly what k
        ``encode_setpoint`` calls would give, sequence numbers included.

        One control step's setpoints for a whole formation, built column-wise
        by ``mavwire.FrameBuilder`` (only the CRC frame by frame). A few rows,
        a signing codec (pymavlink signs each frame), a zero
        ``coordinate_frame`` (MAVLink 2 would trim the payload, and the frames
        would differ in length) or an acceleration float32 cannot hold take
        the one-frame path."""
        k = len(targets)
        mav = self._mav
        # The one-frame path takes any value (one float32 cannot hold raises there, as
        # in ``encode``), so whether they fit is asked only of a batch.
        if (
            k < _BATCH_FROM
            or mav.signing.sign_outgoing
            or coordinate_frame == 0
            or not bool(np.all(np.abs(accel_ned) <= _F32_MAX))
            or (vel_ned is not None and not bool(np.all(np.abs(vel_ned) <= _F32_MAX)))
        ):
            zero, frame = (0.0, 0.0, 0.0), coordinate_frame
            vel = [zero] * k if vel_ned is None else vel_ned.tolist()
            masks = [type_mask] * k if isinstance(type_mask, int) else list(type_mask)
            rows = zip(targets, time_boot_ms, vel, accel_ned.tolist(), masks, strict=True)
            if mav.signing.sign_outgoing:
                frames = [
                    self.encode_setpoint(
                        (t & 0xFFFFFFFF, *zero, *v, *a, 0.0, 0.0, m, ts, tc, frame)
                    )
                    for (ts, tc), t, v, a, m in rows
                ]
                return b"".join(frames), (len(frames[0]) if frames else 0)
            # ``encode_setpoint`` unsigned, frame by frame, its counting done once.
            pack, sp_pack, next_seq = _SP_FRAMES.pack, _SP_PACK, mav.seq
            sysid, compid = mav.srcSystem, mav.srcComponent
            frames = []
            try:
                for (ts, tc), t, v, a, m in rows:
                    payload = sp_pack(t & 0xFFFFFFFF, *zero, *v, *a, 0.0, 0.0, m, ts, tc, frame)
                    frames.append(pack(next_seq, sysid, compid, payload))
                    next_seq += 1
            finally:  # the frames packed before one that cannot be are counted, as before
                self._advance(len(frames), sum(map(len, frames)))
            return b"".join(frames), (len(frames[0]) if frames else 0)
        columns: dict[str, npt.ArrayLike] = {
            "time_boot_ms": np.asarray(time_boot_ms, dtype=np.int64) & 0xFFFFFFFF,
            "acc": accel_ned,
            "type_mask": type_mask,
            # (system, component) pairs flattened by fromiter: half the cost of
            # numpy reading a list of tuples; out-of-range ids raise as before
            "target": np.fromiter(chain.from_iterable(targets), np.uint8, 2 * k).reshape(k, 2),
            "coordinate_frame": coordinate_frame,
        }
        if vel_ned is not None:
            columns["vel"] = vel_ned
        seq = mav.seq + np.arange(k)
        batch = _SP_FRAMES.build(seq, mav.srcSystem, mav.srcComponent, columns)
        size = batch.rows.shape[1]  # never trimmed: coordinate_frame, the last byte, is not 0
        self._advance(k, k * size)
        return batch.tobytes(), size

    def _advance(self, frames: int, nbytes: int) -> None:
        """Count ``frames`` sent. pymavlink's MAVLink.send() would write to a
        file and then advance the sequence; we own the I/O, so advance it here."""
        self._mav.seq = (self._mav.seq + frames) % 256
        self.stats.sent += frames
        self.stats.bytes_sent += nbytes

    def decode(
        self, data: bytes, *, datagram: bool = True, raw_positions: bool = False
    ) -> list[Any]:
        """Parse ``data``; return the good messages, count and drop the rest.

        Unsigned datagrams skip pymavlink's byte-by-byte parser: each whole
        unsigned frame goes straight to pymavlink's ``decode`` (its parser's
        own last step); from the first frame that is not whole and
        well-formed on, ``parse_buffer`` as before, so the messages and
        counters are the same. With ``raw_positions`` a LOCAL_POSITION_NED
        frame (50 Hz per vehicle) is instead CRC-checked and unpacked with
        the dialect's own struct into a ``RawPosition`` (the telemetry
        table's input), without a pymavlink object, and a HEARTBEAT
        (1 Hz per vehicle) likewise into a ``RawHeartbeat``, a status
        message (1-2 Hz each) into a ``RawStatus``.
        """
        if not datagram or self.signing_key is not None:
            good = self._parse(data, datagram=datagram)
            self.stats.received += len(good)
            return good
        good = []
        i, n = 0, len(data)
        while i < n:
            if n - i < 12 or data[i] != 0xFD or data[i + 2] != 0:
                break  # MAVLink 1, signed, garbage or truncated: the general parser
            end = i + 12 + data[i + 1]
            if end > n:
                break
            if (
                raw_positions
                and data[i + 8] == 0
                and data[i + 9] == 0
                and (lay := _RAW_LAYOUTS.get(data[i + 7])) is not None
            ):
                raw = _raw_frame(data, i, end, lay)
                if raw is None:
                    break  # bad CRC or length: let the general parser judge (and count)
                good.append(raw)
            else:
                msg = self._decode_frame(data, i, end)
                if msg is None:
                    break  # the general parser judges (and counts) from here
                if msg is not _SKIP:
                    good.append(msg)
            i = end
        if i < n:
            good.extend(self._parse(data[i:], datagram=True))
        self.stats.received += len(good)
        return good

    def message(self, raw: RawPosition | RawHeartbeat | RawStatus) -> Any:
        """The pymavlink message of a raw tuple (``RawPosition``, ``RawHeartbeat``,
        ``RawStatus``) from ``decode``, made by pymavlink's own ``decode`` of
        its frame (for one that goes through a vehicle's protocol rather than
        the telemetry table)."""
        msg = self._decode_frame(raw.frame, 0, len(raw.frame))
        assert msg is not None and msg is not _SKIP  # its CRC and length were checked
        return msg

    def _decode_frame(self, data: bytes, i: int, end: int) -> Any:
        """The whole unsigned MAVLink 2 frame ``data[i:end]`` through pymavlink's
        ``decode`` (what its parser calls once it has framed the bytes, minus
        the byte-by-byte framing): the message, ``_SKIP`` for an unknown id
        (counted), or None if pymavlink would call it bad data. The messages
        ``frame_decode.decode_unsigned`` can make exactly are made there."""
        frame = data[i:end]
        msg = _decode_unsigned(frame)
        if msg is not NotImplemented:
            return msg
        try:
            msg = self._mav.decode(bytearray(frame))
        except (_dialect.MAVError, struct.error, ValueError, IndexError):
            return None
        if isinstance(msg, _dialect.MAVLink_bad_data):
            return None
        if isinstance(msg, _dialect.MAVLink_unknown):
            self.stats.unknown_messages += 1
            return _SKIP
        return msg

    def _parse(self, data: bytes, *, datagram: bool) -> list[Any]:
        """pymavlink's parser; good messages returned, the rest counted."""
        mav = self._mav
        rejected = mav.signing.reject_count
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
        rejected = mav.signing.reject_count - rejected
        if rejected:  # pymavlink reports them as bad data: count them apart
            self.stats.signature_rejected += rejected
            self.stats.bad_packets -= rejected
        return good

    def _reset_parser(self) -> None:
        mav = self._mav
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = _dialect.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False


_SKIP = object()
"""``_decode_frame``'s answer for a frame counted and dropped."""


_SP = _dialect.MAVLink_set_position_target_local_ned_message
_SP_NAMES = tuple(_SP.ordered_fieldnames)
_SP_PACK = _SP.unpacker.pack
_F32_MAX = float(np.finfo(np.float32).max)
_BATCH_FROM = 8
"""From this many frames ``encode_accel_setpoints`` builds column-wise (below
it, numpy's per-call cost is more than packing frame by frame)."""
_SP_PAYLOAD = np.dtype([
    ("time_boot_ms", "<u4"), ("pos", "<f4", (3,)), ("vel", "<f4", (3,)), ("acc", "<f4", (3,)),
    ("yaw", "<f4"), ("yaw_rate", "<f4"), ("type_mask", "<u2"), ("target", "u1", (2,)),
    ("coordinate_frame", "u1"),
])  # fmt: skip
"""SET_POSITION_TARGET_LOCAL_NED's payload in wire order (53 bytes): x, y, z
as ``pos``, vx, vy, vz as ``vel``, afx, afy, afz as ``acc``, target system
and component as ``target``."""
_SP_FRAMES = FrameBuilder(_SP.id, _SP.crc_extra, _SP_PAYLOAD)

SETPOINT_FIELDS: tuple[str, ...] = _SP_NAMES
"""SET_POSITION_TARGET_LOCAL_NED's field names in wire order (``encode_setpoint``)."""


def _pack_setpoint(mav: MAVLinkInterface, values: Sequence[FieldValue]) -> bytes:
    """SET_POSITION_TARGET_LOCAL_NED field ``values`` (wire order) as
    pymavlink's unsigned MAVLink 2 ``pack`` would frame them with ``mav``'s
    ids and sequence."""
    return _SP_FRAMES.pack(mav.seq, mav.srcSystem, mav.srcComponent, _SP_PACK(*values))
