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

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import ardupilotmega as _dialect

__all__ = ["CRC_INIT", "CRC_TABLE", "MCRF4XX", "crc_step", "frame_crc", "frame_crcs"]

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


def frame_crcs(
    data: bytes | memoryview, starts: Iterable[int], size: int, extra: bytes
) -> list[int]:
    """``frame_crc`` of each whole frame of ``size`` bytes (magic byte to CRC)
    that starts at one of ``starts`` in ``data``, in that order: the frames'
    bodies read through one memoryview, no copies."""
    view = memoryview(data)
    crc = MCRF4XX
    if crc is None:
        return [frame_crc(view[s + 1 : s + size - 2], extra) for s in starts]
    return [crc(extra, crc(view[s + 1 : s + size - 2])) for s in starts]


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


def crc_step(crc: npt.NDArray[Any], byte: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """One byte of CRC-16/MCRF4XX for every row at once: ``crc`` (uint32,
    one per frame) after ``byte`` (one per frame)."""
    out: npt.NDArray[Any] = (crc >> 8) ^ CRC_TABLE[(crc ^ byte) & 0xFF]
    return out
