"""Building unsigned MAVLink 2 frames of one message type, many at once.

A ``FrameBuilder`` knows one message's id, CRC_EXTRA and payload layout (a
packed little-endian numpy structured dtype, fields in wire order). Its
``build`` makes N frames from columns in one structured array: header and
payload filled column-wise, MAVLink 2's trailing-zero truncation found per
frame, the CRC computed per frame in C (pymavlink's ``mcrf4xx``) or, without
it, column-wise with numpy (``mavwire.crc.crc_step``). Its ``pack`` makes one
frame from an already packed payload (the few-frames paths, where numpy's
per-call cost is more than the work). Both give exactly the bytes pymavlink's
``MAVLink_message.pack`` gives unsigned (tests/mavwire/test_mw_framing.py)::

    0xFD len incompat=0 compat=0 seq sysid compid msgid(3, LE) payload[len] crc(2, LE)

``len`` is the payload less its trailing zero bytes, at least 1; the CRC
(CRC-16/MCRF4XX) covers bytes 1 .. 9 + len and then CRC_EXTRA. Signed frames
are not built here: a signing peer packs each frame with pymavlink, which
stamps and signs it (``mavwire.signing``). No I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from mavwire.crc import CRC_INIT, MCRF4XX, crc_step, frame_crc, row_crcs

__all__ = ["HEADER_BYTES", "FrameBatch", "FrameBuilder", "frame_payload"]

HEADER_BYTES = 10
"""Bytes of a MAVLink 2 header, magic byte included."""
_MAGIC = 0xFD
_HEADER = [
    ("magic", "u1"), ("len", "u1"), ("incompat", "u1"), ("compat", "u1"), ("seq", "u1"),
    ("sysid", "u1"), ("compid", "u1"), ("msgid", "<u2"), ("msgid_hi", "u1"),
]  # fmt: skip


class FrameBatch(NamedTuple):
    """N frames of one message type: frame i is ``rows[i, :lengths[i]]``
    (``rows`` is (N, the longest frame) uint8, zero after each frame's end);
    ``full`` says no payload was truncated, so every frame has the same
    length and ``rows`` holds them back to back."""

    rows: npt.NDArray[np.uint8]
    lengths: npt.NDArray[np.int64]
    full: bool

    def tobytes(self) -> bytes:
        """The frames back to back, as one stream of bytes."""
        if self.full:
            return self.rows.tobytes()
        keep = np.arange(self.rows.shape[1]) < self.lengths[:, None]
        return self.rows[keep].tobytes()

    def tolist(self) -> list[bytes]:
        """Each frame as its own ``bytes``, in order."""
        if self.full:
            data, size = self.rows.tobytes(), self.rows.shape[1]
            return [data[j : j + size] for j in range(0, len(data), size)]
        return [row[:e].tobytes() for row, e in zip(self.rows, self.lengths.tolist(), strict=True)]


class FrameBuilder:
    """Unsigned MAVLink 2 frames of message ``msgid`` with ``crc_extra``,
    whose payload is ``payload`` (a structured dtype: the message's fields in
    wire order, little-endian, packed; a field may be a sub-array standing
    for several consecutive fields of one type, e.g. ``("pos", "<f4", (3,))``
    for x, y, z). ``frame`` is the whole frame's dtype: the header's fields,
    ``payload``, then ``crc``."""

    __slots__ = (
        "_extra",
        "_header",
        "_id",
        "crc_extra",
        "frame",
        "msgid",
        "payload",
        "payload_bytes",
    )

    def __init__(self, msgid: int, crc_extra: int, payload: np.dtype[Any]) -> None:
        names = payload.names
        if names is None or sum(payload[k].itemsize for k in names) != payload.itemsize:
            raise ValueError("a payload is a packed structured dtype")
        if payload != payload.newbyteorder("<"):
            raise ValueError("MAVLink payloads are little-endian")
        if not 0 <= msgid < 1 << 24 or not 0 <= crc_extra < 256:
            raise ValueError(f"msgid {msgid} or crc_extra {crc_extra} out of range")
        self.msgid, self.crc_extra, self.payload = msgid, crc_extra, payload
        self.payload_bytes: int = payload.itemsize
        self.frame = np.dtype([*_HEADER, ("payload", payload), ("crc", "<u2")])
        header = bytes((_MAGIC, payload.itemsize, 0, 0, 0, 0, 0, msgid & 0xFF, (msgid >> 8) & 0xFF))
        self._header = np.frombuffer(header + bytes((msgid >> 16,)), dtype=np.uint8)
        self._extra = bytes((crc_extra,))
        self._id = bytes((msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16))

    def build(
        self,
        seq: npt.ArrayLike,
        sysid: npt.ArrayLike,
        compid: npt.ArrayLike,
        columns: Mapping[str, npt.ArrayLike],
    ) -> FrameBatch:
        """N frames at once, N the length of ``seq`` (one sequence number per
        frame, taken modulo 256). ``sysid``, ``compid`` (0..255): one per frame
        or one for all; ``columns`` maps payload field names to values, one
        per frame or one for all (a sub-array field takes an (N, k) array); a
        field not named is zero. Values are cast to the field's type as numpy
        casts them (the caller checks ranges)."""
        seq_col = np.asarray(seq, dtype=np.int64) & 0xFF
        n = len(seq_col)
        arr = np.zeros(n, dtype=self.frame)
        size = self.frame.itemsize
        u8 = arr.view(np.uint8).reshape(n, size)
        u8[:, :HEADER_BYTES] = self._header  # magic, len, msgid
        arr["seq"] = seq_col
        arr["sysid"] = sysid
        arr["compid"] = compid
        pay = arr["payload"]
        for name, values in columns.items():
            pay[name] = values
        if 0 not in u8[:, size - 3].tobytes():  # the usual case: no trailing zero to trim
            arr["crc"] = self._crcs(u8, None)
            return FrameBatch(u8, np.full(n, size, dtype=np.int64), True)
        # MAVLink 2 drops trailing zero bytes, keeping at least one
        nz = u8[:, HEADER_BYTES : size - 2] != 0
        last = self.payload_bytes - np.argmax(nz[:, ::-1], axis=1)
        plen = np.where(nz.any(axis=1), last, 1)
        arr["len"] = plen
        end = (HEADER_BYTES + plen).astype(np.int64)
        crc, rows = np.asarray(self._crcs(u8, end)), np.arange(n)
        u8[rows, end] = crc & 0xFF  # the CRC follows the kept payload
        u8[rows, end + 1] = crc >> 8
        return FrameBatch(u8, end + 2, False)

    def _crcs(self, u8: npt.NDArray[np.uint8], end: npt.NDArray[np.int64] | None) -> Any:
        """The CRC of each row ``u8[i, 1:end[i]]`` followed by CRC_EXTRA
        (``end`` None: every row but its last two bytes)."""
        if end is None:
            return row_crcs(u8, self.crc_extra)
        if MCRF4XX is not None:
            crc, extra = MCRF4XX, self._extra
            flat = u8.reshape(-1).data  # a memoryview of the bytes, no copy
            size = u8.shape[1]
            return [
                crc(extra, crc(flat[j + 1 : j + e]))
                for j, e in zip(range(0, len(flat), size), end.tolist(), strict=True)
            ]
        return _column_crc(u8, end, self.crc_extra)

    def pack(self, seq: int, sysid: int, compid: int, payload: bytes) -> bytes:
        """One frame of the packed ``payload`` (``payload_bytes`` long, e.g.
        from ``struct.pack``): what ``build`` gives for one row."""
        return frame_payload(self._id, self._extra, seq, sysid, compid, payload)


def frame_payload(
    msgid: bytes, extra: bytes, seq: int, sysid: int, compid: int, payload: bytes
) -> bytes:
    """The unsigned MAVLink 2 frame of a packed ``payload`` (all its fields,
    e.g. from ``struct.pack``) of the message whose 3-byte id is ``msgid``
    and CRC_EXTRA byte ``extra``: trailing zeros trimmed (one kept), header,
    CRC; the bytes pymavlink's ``pack`` gives."""
    body = payload.rstrip(b"\x00") or b"\x00"
    frame = bytes((len(body), 0, 0, seq & 0xFF, sysid, compid)) + msgid + body
    crc = MCRF4XX  # frame_crc's choice, without its call (the few-frames hot path)
    value = frame_crc(frame, extra) if crc is None else crc(extra, crc(frame))
    return b"\xfd" + frame + value.to_bytes(2, "little")


def _column_crc(
    u8: npt.NDArray[np.uint8], end: npt.NDArray[np.int64], crc_extra: int
) -> npt.NDArray[np.uint32]:
    """The CRC of each row ``u8[i, 1:end[i]]`` followed by ``crc_extra``,
    one numpy step per byte column for all rows at once (without pymavlink's
    C CRC)."""
    n = len(end)
    crc = np.full(n, CRC_INIT, dtype=np.uint32)
    b32 = u8.astype(np.uint32)
    for col in range(1, int(end.max(initial=1))):
        stepped = crc_step(crc, b32[:, col])
        crc = np.where(col < end, stepped, crc)
    out: npt.NDArray[np.uint32] = crc_step(crc, np.full(n, crc_extra, dtype=np.uint32))
    return out
