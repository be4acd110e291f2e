"""Vectorised MAVLink 2 encoders for LOCAL_POSITION_NED and HEARTBEAT, the streams.

Owns ``encode_local_position_ned``: N frames at once from numpy columns,
through ``mavwire.FrameBuilder`` (the column-wise frame building the station
shares), byte-identical to pymavlink's ``MAVLink_local_position_ned_message.pack``
(tests check it), so the per-vehicle Python cost of the 50 Hz stream is one
slice and one ``sendto``; and ``lpn_frames_small``, the same bytes one frame
at a time with ``struct`` for a handful of vehicles, where numpy's per-call
cost outweighs the work (``small.SMALL_N``); ``encode_heartbeats`` and
``heartbeat_frames_small``, the same for the 1 Hz HEARTBEAT (a network's
at once when they go together). Frame layout (MAVLink 2, unsigned)::

    0xFD len incompat=0 compat=0 seq sysid compid msgid(3, LE) payload[len] crc(2, LE)

``len`` is the payload with trailing zero bytes removed (minimum 1), as
MAVLink 2 requires; the CRC is CRC-16/MCRF4XX over bytes 1..9+len followed by
the message's CRC_EXTRA (185). Signed frames are packed by pymavlink
(``server.py``). Inbound, ``decode_setpoint`` takes the station's 50 Hz
message, SET_POSITION_TARGET_LOCAL_NED, apart without pymavlink's parser or
message object (``RawSetpoint``; ``link.Endpoint.parse``). No I/O.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from operator import attrgetter
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire.crc import frame_crc
from mavwire.framing import FrameBuilder, frame_payload

__all__ = [
    "HEARTBEAT_FIELDS",
    "LPN_CRC_EXTRA",
    "LPN_MSGID",
    "RawSetpoint",
    "decode_setpoint",
    "encode_heartbeats",
    "encode_local_position_ned",
    "heartbeat_frames_small",
    "lpn_frames_small",
    "pack_frame",
    "plain_spec",
]

LPN_MSGID = 32
LPN_CRC_EXTRA = 185
_PAYLOAD = np.dtype([("time_boot_ms", "<u4"), ("pos", "<f4", (3,)), ("vel", "<f4", (3,))])
"""LOCAL_POSITION_NED's payload in wire order (28 bytes): x, y, z as ``pos``,
vx, vy, vz as ``vel``."""
_FRAMES = FrameBuilder(LPN_MSGID, LPN_CRC_EXTRA, _PAYLOAD)

_LPN_PAYLOAD = struct.Struct("<Iffffff")


def encode_local_position_ned(
    time_boot_ms: NDArray[np.int64],
    pos_ned_m: NDArray[np.float64],
    vel_ned_m_s: NDArray[np.float64],
    seq: NDArray[np.int64],
    sysid: NDArray[np.int64],
    compid: NDArray[np.int64],
) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """Encode N LOCAL_POSITION_NED frames. Returns (buffer (N, 40) uint8, frame lengths (N,)).

    Frame i is ``buffer[i, :lengths[i]]``. ``seq`` is the sequence number each
    frame carries (the caller increments its counters).
    """
    columns = {
        "time_boot_ms": np.asarray(time_boot_ms) & 0xFFFFFFFF,
        "pos": pos_ned_m,
        "vel": vel_ned_m_s,
    }
    batch = _FRAMES.build(seq, sysid, compid, columns)
    return batch.rows, batch.lengths


def lpn_frames_small(
    time_boot_ms: Sequence[int],
    pos_ned_m: Sequence[Sequence[float]],
    vel_ned_m_s: Sequence[Sequence[float]],
    seq: Sequence[int],
    sysid: Sequence[int],
    compid: Sequence[int],
) -> list[bytes] | None:
    """The frames of ``encode_local_position_ned``, one ``struct.pack`` each (plain Python
    lists in). None when a value does not fit a float32 (the numpy encoder then decides)."""
    pack, frame = _LPN_PAYLOAD.pack, _FRAMES.pack
    out = []
    try:
        for t, p, v, s, sid, cid in zip(
            time_boot_ms, pos_ned_m, vel_ned_m_s, seq, sysid, compid, strict=True
        ):
            out.append(frame(s, sid, cid, pack(t & 0xFFFFFFFF, p[0], p[1], p[2], v[0], v[1], v[2])))
    except OverflowError:
        return None
    return out


_HB = mav.MAVLink_heartbeat_message
HEARTBEAT_FIELDS: tuple[str, ...] = tuple(_HB.ordered_fieldnames)
"""HEARTBEAT's fields in wire order (pymavlink's; ``encode_heartbeats``' columns)."""
_HB_FRAMES = FrameBuilder(
    _HB.id,
    _HB.crc_extra,
    np.dtype([(HEARTBEAT_FIELDS[0], "<u4")] + [(k, "u1") for k in HEARTBEAT_FIELDS[1:]]),
)
_HB_PAYLOAD: struct.Struct = _HB.unpacker  # pymavlink's own struct of the payload, "<IBBBBB"


def encode_heartbeats(
    seq: NDArray[np.int64],
    sysid: NDArray[np.int64],
    compid: NDArray[np.int64],
    fields: NDArray[np.int64],
) -> list[bytes]:
    """HEARTBEAT frames, one per row, column-wise (``FrameBuilder.build``): row
    i's ``fields[i]`` (``HEARTBEAT_FIELDS`` in order) at ``seq[i]`` from
    ``sysid[i]``/``compid[i]``; the bytes pymavlink's ``pack`` of that message
    gives, unsigned (the emulator's 1 Hz stream, a network's at once)."""
    named = {k: fields[:, j] for j, k in enumerate(HEARTBEAT_FIELDS)}
    return _HB_FRAMES.build(seq, sysid, compid, named).tolist()


def heartbeat_frames_small(
    seq: Sequence[int], sysid: Sequence[int], compid: Sequence[int], fields: Sequence[Sequence[int]]
) -> list[bytes]:
    """The frames of ``encode_heartbeats``, one ``struct.pack`` each (plain
    Python lists in: a few rows)."""
    pack, frame = _HB_PAYLOAD.pack, _HB_FRAMES.pack
    return [frame(s, i, c, pack(*f)) for s, i, c, f in zip(seq, sysid, compid, fields, strict=True)]


_PLAIN: dict[type, tuple[bytes, bytes, Any, Any] | None] = {}
"""Per pymavlink message class: (id bytes, CRC extra byte, its struct's pack,
a getter of its fields in wire order), or None (``pack_frame`` declines)."""


def _plain(cls: type) -> tuple[bytes, bytes, Any, Any] | None:
    """``_PLAIN``'s entry of ``cls``: a dialect message with neither an array
    nor a text field (whose packing pymavlink converts) has one."""
    c: Any = cls
    if c.__module__ != mav.__name__ or any(c.array_lengths) or "char" in c.fieldtypes:
        return None
    names = tuple(c.ordered_fieldnames)
    get: Any = attrgetter(*names)
    if len(names) == 1:  # attrgetter of one name gives the value, not a tuple
        one = get

        def get(m: Any) -> tuple[Any, ...]:
            return (one(m),)

    return c.id.to_bytes(3, "little"), bytes((c.crc_extra,)), c.unpacker.pack, get


def pack_frame(msg: Any, seq: int, sysid: int, compid: int) -> bytes | None:
    """``msg.pack(mav)``'s bytes for an unsigned MAVLink 2 encoder ``mav`` at
    ``seq`` with ``sysid`` and ``compid``: the payload packed by the
    message's own struct from its fields in wire order, framed by
    ``mavwire.framing.frame_payload`` as pymavlink frames it, without
    pymavlink's Python framing (the emulator's status streams: thousands a
    second). None for a message with an array or a text field (the caller
    packs it with pymavlink)."""
    spec = plain_spec(type(msg))
    if spec is None:
        return None
    mid, extra, pack, get = spec
    return frame_payload(mid, extra, seq, sysid, compid, pack(*get(msg)))


def plain_spec(cls: type) -> tuple[bytes, bytes, Any, Any] | None:
    """(3-byte id, CRC_EXTRA byte, its struct's pack, a getter of a message's
    fields in wire order) of pymavlink message class ``cls``, or None for one
    with an array or a text field: what ``pack_frame`` frames with (also
    ``reports.status_frame``)."""
    return _PLAIN[cls] if cls in _PLAIN else _PLAIN.setdefault(cls, _plain(cls))


_SP = mav.MAVLink_set_position_target_local_ned_message
_SP_SIZE = _SP.unpacker.size
_SP_EXTRA = bytes((_SP.crc_extra,))
_SP_UNPACK_FROM = _SP.unpacker.unpack_from


class RawSetpoint:
    """One unsigned SET_POSITION_TARGET_LOCAL_NED as its fields in wire order
    (``f``: time_boot_ms, x, y, z, vx, vy, vz, afx, afy, afz, yaw, yaw_rate,
    type_mask, target_system, target_component, coordinate_frame) and its
    header: what the emulator's 50 Hz lane reads (``core._deliver``), without
    building pymavlink's message. ``message()`` is the message pymavlink's
    parser gives for the same frame, for every other use."""

    __slots__ = ("comp", "f", "plen", "seq", "src", "target_system")

    def __init__(self, f: tuple[Any, ...], plen: int, seq: int, src: int, comp: int) -> None:
        self.f = f
        self.plen = plen
        self.seq = seq
        self.src = src
        self.comp = comp
        self.target_system: int = f[13]

    def get_msgId(self) -> int:
        return 84

    def message(self) -> mav.MAVLink_message:
        f = self.f
        msg = _SP(f[0], f[13], f[14], f[15], f[12], *f[1:12])
        msg._header = mav.MAVLink_header(84, 0, 0, self.plen, self.seq, self.src, self.comp)
        return msg


def decode_setpoint(data: bytes, i: int, plen: int) -> RawSetpoint | None:
    """The setpoint in the whole unsigned MAVLink 2 frame at ``data[i:]`` of
    payload ``plen``, or None when it is another message, longer than the
    struct, or its CRC (CRC-16/MCRF4XX with CRC_EXTRA) is wrong."""
    if data[i + 7] != 84 or data[i + 8] or data[i + 9] or plen > _SP_SIZE:
        return None
    end = i + 10 + plen
    if frame_crc(data[i + 1 : end], _SP_EXTRA) != data[end] | (data[end + 1] << 8):
        return None
    if plen == _SP_SIZE:  # the usual case (coordinate_frame, the last byte, is not 0)
        f = _SP_UNPACK_FROM(data, i + 10)
    else:
        f = _SP.unpacker.unpack(data[i + 10 : end] + bytes(_SP_SIZE - plen))
    return RawSetpoint(f, plen, data[i + 4], data[i + 5], data[i + 6])
