"""pymavlink's ``MAVLink.decode`` of one whole unsigned MAVLink 2 frame, in fewer steps.

Every message but the flying vehicles' LOCAL_POSITION_NED (HEARTBEAT,
EKF_STATUS_REPORT, GPS_RAW_INT, EXTENDED_SYS_STATE, acknowledgements...)
reaches the station as pymavlink's message object; at N = 250 the
HEARTBEATs of a whole swarm can come in one burst, so the cost of each
decode adds to that step's latency (benchmarks/README.md, station
capacity). ``decode_unsigned`` builds the same object pymavlink's
``decode`` builds (same class, fields, header, ``_msgbuf``, ``_payload``,
``_crc``, ``_signed``) with the work per message type done once: the
payload's field order, whether it has strings, its size. It takes only
what it can do exactly: an unsigned MAVLink 2 frame of a known message
without array fields, with pymavlink's C CRC present; for anything else it
answers ``NotImplemented`` and the caller asks pymavlink. A wrong CRC or a
payload pymavlink cannot make a message of gives None (pymavlink raises).
``tests/mavlink/test_codec_fast_paths.py`` compares both on seeded mixed
datagrams. No I/O.
"""

from __future__ import annotations

import struct
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as _dialect

from mavwire.crc import MCRF4XX

__all__ = ["decode_unsigned"]

_Plan = tuple[Any, struct.Struct, tuple[int, ...] | None, bool, bytes]
"""(message class, payload struct, field order (None: as unpacked), has
strings, CRC_EXTRA byte) of one message id."""

_PLANS: dict[int, _Plan | None] = {}
_HEADER = _dialect.MAVLink_header
_ENABLED = MCRF4XX is not None and not _dialect.MAVLINK_IGNORE_CRC


def _plan(msgid: int) -> _Plan | None:
    """What ``decode_unsigned`` needs of message ``msgid``, or None where it
    leaves the message to pymavlink (unknown id, array fields)."""
    msgtype = _dialect.mavlink_map.get(msgid)
    if msgtype is None or sum(msgtype.lengths) != len(msgtype.lengths):
        return None
    order = tuple(msgtype.orders)
    keep = None if order == tuple(range(len(order))) else order
    strings = "s" in msgtype.unpacker.format
    return msgtype, msgtype.unpacker, keep, strings, bytes((msgtype.crc_extra,))


def decode_unsigned(frame: bytes) -> Any:
    """pymavlink's message of ``frame``: one whole unsigned MAVLink 2 frame
    (magic 0xFD, no signature, length as its header says). None where
    pymavlink would raise (bad CRC, a payload its class refuses);
    ``NotImplemented`` where the caller should ask pymavlink."""
    if not _ENABLED:
        return NotImplemented
    msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16)
    plan = _PLANS.get(msgid, NotImplemented)
    if plan is NotImplemented:
        plan = _PLANS[msgid] = _plan(msgid)
    if plan is None:
        return NotImplemented
    msgtype, unpacker, order, strings, extra = plan
    crc = frame[-2] | (frame[-1] << 8)
    if MCRF4XX(extra, MCRF4XX(frame[1:-2])) != crc:  # type: ignore[misc]
        return None
    size = unpacker.size
    payload = frame[10:-2]
    if len(payload) < size:
        payload += bytes(size - len(payload))  # MAVLink 2 trimmed its trailing zeros
    try:
        t = unpacker.unpack(payload[:size])
    except struct.error:
        return None
    fields: list[Any] = list(t) if order is None else [t[j] for j in order]
    if strings:
        for i, elem in enumerate(fields):
            if isinstance(elem, bytes):
                fields[i] = elem.rstrip(b"\x00")
    try:
        m = msgtype(*fields)
    except Exception:  # pymavlink: "Unable to instantiate MAVLink message"
        return None
    msgbuf = bytearray(frame)
    m._signed = False
    m._msgbuf = msgbuf
    m._payload = msgbuf[6:-2]  # (sic: pymavlink's offset for both versions)
    m._crc = crc
    m._header = _HEADER(msgid, 0, frame[3], frame[1], frame[4], frame[5], frame[6])
    return m
