"""The MAVLink checksum (CRC-16/MCRF4XX, the X.25 CRC), one frame or many.

A MAVLink 2 frame's CRC covers every byte after the magic byte up to the
CRC itself, followed by the message's CRC_EXTRA byte. ``frame_crc`` gives
the value pymavlink's ``x25crc`` computes; it uses pymavlink's C function
(``MCRF4XX``, from the ``fastcrc`` package, when installed) and falls back
to ``x25crc`` otherwise; ``frame_crcs`` gives it for many whole frames of
one size in one buffer (the decoders' and encoders' batches). ``crc_step``
advances the CRC of many rows by one byte each with numpy (the column-wise
frame encoders), from ``CRC_TABLE``.
No I/O.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import ardupilotmega as _dialect

__all__ = [
    "CRC_INIT",
    "CRC_TABLE",
    "MCRF4XX",
    "ROWS_MIN",
    "crc_step",
    "frame_by_frame_crcs",
    "frame_crc",
    "row_crcs",
    "table_crcs",
]

CRC_INIT = 0xFFFF
"""The CRC's value before the first byte."""

MCRF4XX: Callable[..., int] | None = getattr(_dialect, "mcrf4xx", None)
"""pymavlink's C CRC-16/MCRF4XX, ``MCRF4XX(data, crc=CRC_INIT)``, when the
``fastcrc`` package is installed; None otherwise. Hot loops call it directly."""


def frame_crc(body: bytes | memoryview, extra: bytes) -> int:
    """The MAVLink checksum of ``body`` (a frame without its magic byte and
    CRC) followed by the message's CRC_EXTRA byte ``extra``: the value
    pymavlink's ``x25crc`` computes."""
    if MCRF4XX is not None:
        return MCRF4XX(extra, MCRF4XX(body))
    crc = _dialect.x25crc(bytes(body))
    crc.accumulate(extra)
    return int(crc.crc)


def _crc_table() -> npt.NDArray[np.uint32]:
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        crc = i
        for _ in range(8):
            crc = (crc >> 1) ^ 0x8408 if crc & 1 else crc >> 1  # reflected 0x1021
        table[i] = crc
    return table


CRC_TABLE = _crc_table()
"""CRC-16/MCRF4XX of each byte value from 0: one byte of the CRC is
``(crc >> 8) ^ CRC_TABLE[(crc ^ byte) & 0xFF]``."""
_TABLE16 = CRC_TABLE.astype(np.uint16)
"""``CRC_TABLE`` as uint16 (the position tables' type)."""


def crc_step(crc: npt.NDArray[Any], byte: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """One byte of CRC-16/MCRF4XX for every row at once: ``crc`` (uint32,
    one per frame) after ``byte`` (one per frame)."""
    out: npt.NDArray[Any] = (crc >> 8) ^ CRC_TABLE[(crc ^ byte) & 0xFF]
    return out


ROWS_MIN = 20
"""From this many frames on ``row_crcs`` takes the position tables; fewer
go frame by frame when pymavlink's C CRC is installed. The tables cost
about 4 us a batch plus 0.07 us a frame of 40 bytes, pymavlink's C CRC
0.3 us a frame: the two are about even at 16-20 frames (``bench_codec.py``,
frame by frame against ``table_crcs``, 2026-12-06)."""


def row_crcs(rows: npt.NDArray[np.uint8], extra: int) -> npt.NDArray[np.uint16]:
    """``frame_crc`` of each row of ``rows (N, size)``, a whole frame from
    its magic byte to its CRC (the CRC covers ``row[1:size - 2]``, then the
    CRC_EXTRA byte ``extra``), as uint16: by the position tables (module
    docstring) from ``ROWS_MIN`` rows on, or without pymavlink's C CRC."""
    if len(rows) < ROWS_MIN and MCRF4XX is not None:
        return np.array(frame_by_frame_crcs(rows, extra), dtype=np.uint16)
    return table_crcs(rows, extra)


def frame_by_frame_crcs(rows: npt.NDArray[np.uint8], extra: int) -> list[int]:
    """``row_crcs`` one frame after another (pymavlink's C CRC when
    installed, ``frame_crc`` otherwise): below ``ROWS_MIN`` rows, and
    ``bench_codec.py``'s reference for ``table_crcs``."""
    size, e = rows.shape[1], bytes((extra,))
    flat = np.ascontiguousarray(rows).reshape(-1).data
    crc = MCRF4XX
    if crc is None:
        return [frame_crc(flat[s + 1 : s + size - 2], e) for s in range(0, len(flat), size)]
    return [crc(e, crc(flat[s + 1 : s + size - 2])) for s in range(0, len(flat), size)]


def table_crcs(rows: npt.NDArray[np.uint8], extra: int) -> npt.NDArray[np.uint16]:
    """``row_crcs`` by the position tables whatever the number of rows
    (``bench_codec.py`` times it against pymavlink's C CRC)."""
    size = rows.shape[1]
    tables, index = _position_tables(size - 3)
    out: npt.NDArray[np.uint16] = np.bitwise_xor.reduce(
        tables.take(rows[:, 1 : size - 2] + index), axis=1
    )
    out ^= _zero_crc(size - 3, extra)
    return out


def _advance_zero(crc: npt.NDArray[np.uint16]) -> npt.NDArray[np.uint16]:
    """Each CRC of ``crc`` after one more zero byte (a CRC started from 0)."""
    out: npt.NDArray[np.uint16] = (crc >> 8) ^ _TABLE16[crc & 0xFF]
    return out


@lru_cache(maxsize=64)
def _position_tables(body: int) -> tuple[npt.NDArray[np.uint16], npt.NDArray[np.uint32]]:
    """The position tables ``T_0 .. T_{body-1}`` (module docstring) of a
    ``body``-byte message, flat (``T_j[v]`` at ``256 j + v``), and each
    position's offset ``256 j`` (uint32: a body of 9 + 255 bytes reaches
    67,584, past uint16)."""
    tables = np.empty((body, 256), dtype=np.uint16)
    t = _advance_zero(_TABLE16)  # the extra byte's place after the last
    for j in range(body - 1, -1, -1):
        tables[j] = t
        t = _advance_zero(t)
    return tables.reshape(-1), np.arange(body, dtype=np.uint32) * 256


@lru_cache(maxsize=256)
def _zero_crc(body: int, extra: int) -> int:
    """The CRC of ``body`` zero bytes then ``extra``, from ``CRC_INIT``."""
    return frame_crc(bytes(body), bytes((extra,)))
