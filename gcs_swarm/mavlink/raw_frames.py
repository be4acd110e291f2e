"""MAVLink 2 frames of the messages a flying vehicle streams, decoded
without pymavlink's message objects (``codec.Codec.decode(...,
raw_positions=True)``): LOCAL_POSITION_NED (50 Hz per vehicle) into a
``RawPosition``, HEARTBEAT into a ``RawHeartbeat``, the status messages of
``inbound.STATUS_FIELDS`` into a ``RawStatus``, for the telemetry table
(mavlink/telemetry_table.py). The frame's CRC is checked with the dialect's
CRC extra and the payload unpacked with the dialect's own struct. No I/O.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from operator import itemgetter
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import ardupilotmega as _dialect

from gcs_swarm.mavlink.inbound import STATUS_FIELDS
from mavwire.crc import MCRF4XX as _MCRF4XX
from mavwire.crc import frame_crc as _frame_crc
from mavwire.crc import row_crcs as _row_crcs

__all__ = [
    "LPN_PAYLOAD",
    "RAW_LAYOUTS",
    "FrameBatch",
    "RawHeartbeat",
    "RawPosition",
    "RawStatus",
    "frame_batch",
    "raw_frame",
]


class RawPosition(NamedTuple):
    """An unsigned LOCAL_POSITION_NED frame decoded without pymavlink's
    message objects (``Codec.decode(..., raw_positions=True)``): the hot
    inbound message, 50 Hz per vehicle, for the link state to write into the
    telemetry table (swarm/link_state.py, mavlink/telemetry_table.py);
    ``Codec.message`` makes pymavlink's message of one the table does not
    take. ``values`` are the payload's fields in wire order:
    (time_boot_ms, x, y, z, vx, vy, vz)."""

    sysid: int
    compid: int
    seq: int
    frame: bytes
    values: tuple[Any, ...]


class RawHeartbeat(NamedTuple):
    """An unsigned HEARTBEAT frame decoded without pymavlink's message
    objects (``Codec.decode(..., raw_positions=True)``), as a ``RawPosition``
    is: for the telemetry table to recognise a flying vehicle's unchanged
    HEARTBEAT (``TelemetryTable.unchanged``); ``Codec.message`` makes
    pymavlink's message of one the table does not take. ``values`` are the
    payload's fields in wire order: (custom_mode, type, autopilot,
    base_mode, system_status, mavlink_version)."""

    sysid: int
    compid: int
    seq: int
    frame: bytes
    values: tuple[int, ...]


class RawStatus(NamedTuple):
    """An unsigned frame of a status message a flying vehicle streams at 1-2
    Hz (``inbound.STATUS_FIELDS``: SYS_STATUS, GPS_RAW_INT,
    EKF_STATUS_REPORT, ESTIMATOR_STATUS, EXTENDED_SYS_STATE), decoded as a
    ``RawHeartbeat`` is: for the telemetry table to recognise one that would
    change nothing (``TelemetryTable.unchanged``). ``values`` are the fields
    ``STATUS_FIELDS`` names for its id (``frame[7]``), in that order."""

    sysid: int
    compid: int
    seq: int
    frame: bytes
    values: tuple[int, ...]


_LPN = _dialect.MAVLink_local_position_ned_message
_LPN_ID0: int = _LPN.id  # a 24-bit id: (32, 0, 0) on the wire
_HB = _dialect.MAVLink_heartbeat_message
_HB_ID0: int = _HB.id  # (0, 0, 0) on the wire


class _RawLayout(NamedTuple):
    """What ``raw_frame`` needs of one message type: its payload size, CRC
    extra, struct unpackers, the zeros MAVLink 2 trimmed off a payload of
    ``n`` bytes (``pad[n]``), and the tuple type it makes."""

    size: int
    extra: bytes
    unpack: Any
    unpack_from: Any
    pad: list[bytes]
    kind: type


def _layout(msg: Any, kind: type, names: tuple[str, ...] = ()) -> _RawLayout:
    """``msg``'s layout; with ``names``, its values are those fields only."""
    size: int = msg.unpacker.size
    unpack, unpack_from = msg.unpacker.unpack, msg.unpacker.unpack_from
    if names:  # wire order = ordered_fieldnames: none of these messages has an array
        assert not any(msg.array_lengths), msg.msgname
        pick = itemgetter(*(msg.ordered_fieldnames.index(f) for f in names), -1)
        unpack = _picking(pick, unpack)
        unpack_from = _picking(pick, unpack_from)
    return _RawLayout(size, bytes((msg.crc_extra,)), unpack, unpack_from,
                      [bytes(size - n) for n in range(size + 1)], kind)  # fmt: skip


def _picking(pick: Any, unpack: Any) -> Any:
    """``unpack`` giving only ``pick``'s fields (its last item, a filler that
    keeps a one-field pick a tuple, left off)."""
    return lambda *args: pick(unpack(*args))[:-1]


_CRC = _MCRF4XX
_tuple_new = tuple.__new__
"""``RawPosition`` made from a tuple in C (the NamedTuple's ``__new__`` is a
Python function)."""


def raw_frame(data: bytes, i: int, end: int, lay: _RawLayout) -> Any:
    """The unsigned MAVLink 2 frame ``data[i:end]`` of ``lay``'s message as
    its raw tuple (``RawPosition``, ``RawHeartbeat``), or None if its length
    or CRC is wrong.

    LOCAL_POSITION_NED comes at 50 Hz per vehicle, so written for speed:
    one slice for the frame, one for the CRC's body, the payload unpacked in
    place (or once padded, when MAVLink 2 trimmed its trailing zeros), the
    tuple made in C."""
    size, extra, unpack, unpack_from, pad, kind = lay
    plen = end - i - 12
    if not 0 < plen <= size:
        return None
    frame = data[i:end]
    crc = _frame_crc(frame[1:-2], extra) if _CRC is None else _CRC(extra, _CRC(frame[1:-2]))
    if crc != frame[-2] | (frame[-1] << 8):
        return None
    values = unpack_from(frame, 10) if plen == size else unpack(frame[10:-2] + pad[plen])
    return _tuple_new(kind, (frame[5], frame[6], frame[4], frame, values))


RAW_LAYOUTS = {_LPN_ID0: _layout(_LPN, RawPosition), _HB_ID0: _layout(_HB, RawHeartbeat)}
RAW_LAYOUTS.update((i, _layout(_dialect.mavlink_map[i], RawStatus, names))
                    for i, (_, names) in STATUS_FIELDS.items())  # fmt: skip
"""The messages ``decode`` takes raw, by their id's first byte (every id fits in it)."""


LPN_PAYLOAD = np.dtype([("time_boot_ms", "<u4"), ("ned", "<f4", (6,))])
"""LOCAL_POSITION_NED's payload in wire order: time_boot_ms [ms], x, y, z [m],
vx, vy, vz [m/s] NED (28 bytes; the telemetry table's row)."""
_LPN_LAY = RAW_LAYOUTS[_LPN_ID0]
assert _LPN_LAY.size == LPN_PAYLOAD.itemsize
_LPN_SIZE = 12 + LPN_PAYLOAD.itemsize
"""A whole (untrimmed) unsigned LOCAL_POSITION_NED frame [bytes]: 40."""
_LPN_EXTRA = _LPN_LAY.extra[0]
"""LOCAL_POSITION_NED's CRC_EXTRA byte, as an int (``row_crcs``' argument)."""
_LPN_FRAME = np.dtype([("head", "u1", (10,)), ("payload", LPN_PAYLOAD), ("crc", "<u2")])
_AT = np.arange(_LPN_SIZE, dtype=np.intp)
_CHECKED = np.array([0, 2, 8, 9], dtype=np.intp)
_UNSIGNED = np.array([0xFD, 0, 0, 0], dtype=np.uint8)
"""``Codec.decode``'s test of a frame's header bytes 0, 2, 8 and 9: the
MAVLink 2 magic, no incompatibility flag (unsigned), an id of one byte."""


class FrameBatch(NamedTuple):
    """The first datagrams of a ``frame_batch`` call, joined (``blob``):
    every frame's ``starts``/``ends`` in it and its header ``head (F, 10)``,
    in order; the LOCAL_POSITION_NED frames (``lpn``, indices of frames) by
    column, ``payload (L,)`` of ``LPN_PAYLOAD`` (a trimmed one's zeros put
    back); every other frame as ``raw_frame`` decodes it, a ``RawHeartbeat``
    or a ``RawStatus`` (``others``: (index, tuple)); and where each
    datagram ends (``cuts``: the frames before its end; ``len(cuts)``
    datagrams); ``sysids`` every frame's system id (``head``'s column 5) as
    ints, read once for the batch's every run."""

    blob: bytes
    starts: list[int]
    ends: list[int]
    head: npt.NDArray[np.uint8]
    sysids: list[int]
    lpn: list[int]
    payload: npt.NDArray[Any]
    others: list[tuple[int, Any]]
    cuts: list[int]


def frame_batch(grams: Sequence[bytes]) -> FrameBatch | None:
    """The first datagrams of ``grams`` frame by frame as
    ``Codec.decode(raw_positions=True)`` reads them, as far as each of their
    frames is a whole unsigned MAVLink 2 frame with a good CRC that
    ``raw_frame`` takes (a LOCAL_POSITION_NED, a HEARTBEAT or a status
    message); None when the first datagram is not (then decode it). The
    frames are found by their length bytes alone and their headers checked
    as columns (``Codec.decode``'s test: the magic, no incompatibility flag,
    an id of one byte); the untrimmed reports go column-wise (one gather,
    their CRCs at once, ``mavwire.crc.row_crcs``), every other
    frame through ``raw_frame``."""
    blob = b"".join(grams)
    starts: list[int] = []
    cuts: list[int] = []
    i = 0
    for g in grams:
        end_g = i + len(g)
        while end_g - i >= 12:
            starts.append(i)
            i += 12 + blob[i + 1]
        if i != end_g:  # a frame past its datagram's end, or a tail too short for one
            del starts[cuts[-1] if cuts else 0 :]
            break
        cuts.append(len(starts))
    if not cuts:
        return None
    u = np.frombuffer(blob, dtype=np.uint8)
    at = np.array(starts, dtype=np.intp)
    head = u[at[:, None] + _AT[:10]]
    ok = (head[:, _CHECKED] == _UNSIGNED).all(axis=1)
    is_whole = ok & (head[:, 7] == _LPN_ID0) & (head[:, 1] == LPN_PAYLOAD.itemsize)
    ends = (at + 12 + head[:, 1]).tolist()
    bad = len(starts)  # the first frame that cannot go
    others: list[tuple[int, Any]] = []
    part: list[tuple[int, Any]] = []
    okay, msgids = ok.tolist(), head[:, 7].tolist()
    for j in np.flatnonzero(~is_whole).tolist():
        lay = RAW_LAYOUTS.get(msgids[j]) if okay[j] else None
        raw = None if lay is None else raw_frame(blob, starts[j], ends[j], lay)
        if raw is None:  # a bad frame, or another message (its protocol's)
            bad = j
            break
        (part if lay is _LPN_LAY else others).append((j, raw))
    lpn = np.flatnonzero(is_whole | (head[:, 7] == _LPN_ID0)).tolist()
    whole = np.flatnonzero(is_whole).tolist()
    if whole:
        rows = u[at[whole][:, None] + _AT]
        frames = rows.view(_LPN_FRAME)[:, 0]
        wrong = np.flatnonzero(_row_crcs(rows, _LPN_EXTRA) != frames["crc"])
        if len(wrong):
            bad = min(bad, whole[int(wrong[0])])
    if bad < len(starts):  # the datagrams before the bad frame's
        keep = bisect_right(cuts, bad)
        return None if keep == 0 else frame_batch(grams[:keep])
    if part:
        payload = np.zeros(len(lpn), dtype=LPN_PAYLOAD)
        payload[np.searchsorted(lpn, whole)] = frames["payload"] if whole else payload[:0]
        for j, raw in part:  # a trimmed report: raw_frame's values, the zeros put back
            values = raw[4]
            payload[bisect_right(lpn, j) - 1] = (values[0], values[1:])
    else:
        payload = frames["payload"] if whole else np.zeros(0, dtype=LPN_PAYLOAD)
    return FrameBatch(blob, starts, ends, head, head[:, 5].tolist(), lpn, payload, others, cuts)
