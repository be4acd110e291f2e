"""Vectorised MAVLink 2 encoder for LOCAL_POSITION_NED, the one hot-path message.

Owns ``encode_local_position_ned``: builds N frames at once with numpy,
byte-identical to pymavlink's ``MAVLink_local_position_ned_message.pack``
(a test checks it), so the per-vehicle Python cost of the 50 Hz stream is one
slice and one ``sendto``; and ``lpn_frames_small``, the same bytes one frame
at a time with ``struct`` for a handful of vehicles, where numpy's per-call
cost outweighs the work (``small.SMALL_N``). Frame layout (MAVLink 2, unsigned)::

    0xFD len incompat=0 compat=0 seq sysid compid msgid(3, LE) payload[len] crc(2, LE)

``len`` is the payload with trailing zero bytes removed (minimum 1), as
MAVLink 2 requires; the CRC is CRC-16/MCRF4XX over bytes 1..9+len followed by
the message's CRC_EXTRA (185), ``mavwire.crc``'s (shared with the station). No I/O.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from mavwire.crc import CRC_INIT, crc_step, frame_crc
from sim_vehicle.small import few

__all__ = ["LPN_CRC_EXTRA", "LPN_MSGID", "encode_local_position_ned", "lpn_frames_small"]

LPN_MSGID = 32
LPN_CRC_EXTRA = 185
_PAYLOAD = 28
_HDR = 10
_PAY_DTYPE = np.dtype(
    [
        ("t", "<u4"),
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("vx", "<f4"),
        ("vy", "<f4"),
        ("vz", "<f4"),
    ]
)


_LPN_PAYLOAD = struct.Struct("<Iffffff")
_LPN_EXTRA = bytes((LPN_CRC_EXTRA,))


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
    n = len(seq)
    pay = np.empty(n, dtype=_PAY_DTYPE)
    pay["t"] = np.asarray(time_boot_ms) & 0xFFFFFFFF
    pay["x"], pay["y"], pay["z"] = pos_ned_m[:, 0], pos_ned_m[:, 1], pos_ned_m[:, 2]
    pay["vx"], pay["vy"], pay["vz"] = vel_ned_m_s[:, 0], vel_ned_m_s[:, 1], vel_ned_m_s[:, 2]
    pb = pay.view(np.uint8).reshape(n, _PAYLOAD)
    nz = pb != 0
    # payload length after trimming trailing zeros (at least 1)
    last = _PAYLOAD - np.argmax(nz[:, ::-1], axis=1)
    plen = np.where(nz.any(axis=1), last, 1).astype(np.int64)
    buf = np.zeros((n, _HDR + _PAYLOAD + 2), dtype=np.uint8)
    buf[:, 0] = 0xFD
    buf[:, 1] = plen
    buf[:, 4] = np.asarray(seq) & 0xFF
    buf[:, 5] = sysid
    buf[:, 6] = compid
    buf[:, 7] = LPN_MSGID
    buf[:, _HDR : _HDR + _PAYLOAD] = pb
    buf[:, _HDR : _HDR + _PAYLOAD][~(np.arange(_PAYLOAD)[None, :] < plen[:, None])] = 0
    end = _HDR + plen
    rows = np.arange(n)
    if few(n):  # the CRC per frame over bytes: a numpy step per byte costs more
        for i, e in enumerate(end.tolist()):
            crc_i = frame_crc(buf[i, 1:e].tobytes(), _LPN_EXTRA)
            buf[i, e] = crc_i & 0xFF
            buf[i, e + 1] = crc_i >> 8
        return buf, end + 2
    crc = np.full(n, CRC_INIT, dtype=np.uint32)
    b32 = buf.astype(np.uint32)
    for j in range(1, _HDR):
        crc = crc_step(crc, b32[:, j])
    for j in range(_PAYLOAD):
        col = _HDR + j
        crc = np.where(j < plen, crc_step(crc, b32[:, col]), crc)
    crc = crc_step(crc, np.full(n, LPN_CRC_EXTRA, dtype=np.uint32))
    buf[rows, end] = crc & 0xFF
    buf[rows, end + 1] = crc >> 8
    return buf, end + 2


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
    pack = _LPN_PAYLOAD.pack
    out = []
    try:
        for t, p, v, s, sid, cid in zip(
            time_boot_ms, pos_ned_m, vel_ned_m_s, seq, sysid, compid, strict=True
        ):
            payload = pack(t & 0xFFFFFFFF, p[0], p[1], p[2], v[0], v[1], v[2]).rstrip(b"\x00")
            body = bytes((len(payload) or 1, 0, 0, s & 0xFF, sid, cid, LPN_MSGID, 0, 0))
            body += payload or b"\x00"
            out.append(b"\xfd" + body + frame_crc(body, _LPN_EXTRA).to_bytes(2, "little"))
    except OverflowError:
        return None
    return out
