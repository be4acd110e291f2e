"""Telemetry logs: the ``.tlog`` format and its reader (the writer, which
needs a thread and the event loop, is ``gcs_swarm.runtime.tlog``).

The ``.tlog`` format (written by MAVProxy and Mission Planner, read by
pymavlink's ``mavlogdump.py`` and MAVExplorer) is a plain sequence of records,
each an 8-byte big-endian unsigned timestamp in microseconds since the Unix
epoch followed by one raw MAVLink frame (v1 ``0xFE`` or v2 ``0xFD``, with its
signature if signed). There is no file header and no direction flag.

``read_tlog`` yields ``TlogRecord(t_us, frame, direction)``. Direction comes
from the frame's source: system 255 is the station (mavlink-protocol.md,
"Identity"), so its frames are ``"out"``, except those of component 155
(MAV_COMP_ID_LOG), the station's own annotations written to the log only and
never sent (``"note"``, see ``gcs_swarm.report.notes``); every other source
is ``"in"``. Damaged records are skipped by scanning for the next plausible
one (counted in ``TlogStats.skipped_bytes``).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from gcs_swarm.mavlink.codec import STATION_SYSID
from gcs_swarm.report.notes import LOG_COMPID

__all__ = [
    "RECORD_TIMESTAMP",
    "Direction",
    "FrameHeader",
    "TlogRecord",
    "TlogStats",
    "frame_header",
    "read_tlog",
]

RECORD_TIMESTAMP = struct.Struct(">Q")
"""A record's timestamp: big-endian unsigned microseconds since the Unix epoch."""
_V1, _V2 = 0xFE, 0xFD
_SIGNED = 0x01  # MAVLink 2 incompat flag: 13-byte signature follows the CRC
_MAX_SKEW_US = 3 * 24 * 3600 * 10**6  # as pymavlink: a timestamp this far off is garbage

Direction = Literal["in", "out", "note"]


@dataclass(frozen=True, slots=True)
class FrameHeader:
    """The header fields of one raw MAVLink frame; ``length`` is the whole
    frame in bytes (header, payload, CRC and signature)."""

    version: int
    length: int
    seq: int
    sysid: int
    compid: int
    msgid: int

    @property
    def direction(self) -> Direction:
        if self.sysid != STATION_SYSID:
            return "in"
        return "note" if self.compid == LOG_COMPID else "out"


def frame_header(buf: bytes | bytearray | memoryview, offset: int = 0) -> FrameHeader | None:
    """Parse the frame header at ``offset``; None if it is not a complete
    MAVLink 1 or 2 header (the payload is not checked)."""
    n = len(buf) - offset
    if n < 6:
        return None
    magic = buf[offset]
    plen = buf[offset + 1]
    if magic == _V2:
        if n < 10:
            return None
        sig = 13 if buf[offset + 2] & _SIGNED else 0
        msgid = buf[offset + 7] | buf[offset + 8] << 8 | buf[offset + 9] << 16
        seq, sysid, compid = buf[offset + 4], buf[offset + 5], buf[offset + 6]
        return FrameHeader(2, 12 + plen + sig, seq, sysid, compid, msgid)
    if magic == _V1:
        seq, sysid, compid = buf[offset + 2], buf[offset + 3], buf[offset + 4]
        return FrameHeader(1, 8 + plen, seq, sysid, compid, buf[offset + 5])
    return None


# ----------------------------------------------------------------------- reader
@dataclass(frozen=True, slots=True)
class TlogRecord:
    """One record: timestamp [us since the Unix epoch], the raw frame and its
    direction as seen by the station (see the module docstring)."""

    t_us: int
    frame: bytes
    header: FrameHeader

    @property
    def direction(self) -> Direction:
        return self.header.direction


@dataclass
class TlogStats:
    """What ``read_tlog`` skipped: bytes of damaged records and a truncated tail."""

    records: int = 0
    skipped_bytes: int = 0
    truncated: bool = False


def read_tlog(path: str | os.PathLike[str], stats: TlogStats | None = None) -> Iterator[TlogRecord]:
    """Yield every record of a ``.tlog`` file in order (the CRC is not checked
    here; the decoder does that). A record whose timestamp is more than three
    days from the previous one, or whose frame does not start with a MAVLink
    magic byte, is damaged: bytes are skipped one at a time until a plausible
    record starts (counted in ``stats`` when given), as pymavlink does."""
    st = stats if stats is not None else TlogStats()
    data = Path(path).read_bytes()
    pos, end = 0, len(data)
    last_t: int | None = None
    while pos + 8 < end:
        (t_us,) = RECORD_TIMESTAMP.unpack_from(data, pos)
        hdr = frame_header(data, pos + 8)
        if hdr is None or (last_t is not None and abs(t_us - last_t) > _MAX_SKEW_US):
            pos += 1
            st.skipped_bytes += 1
            continue
        stop = pos + 8 + hdr.length
        if stop > end:
            break
        st.records += 1
        last_t = t_us
        yield TlogRecord(t_us, data[pos + 8 : stop], hdr)
        pos = stop
    if pos < end:
        st.truncated = True
        st.skipped_bytes += end - pos
