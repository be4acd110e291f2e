"""Joining MAVLink frames into UDP datagrams, one size limit for both ends.

A MAVLink receiver reads UDP as a byte stream, so several whole frames in
one datagram are what it would read from a serial port; a lost datagram
loses all of them, as it would the frames of a lost serial burst. A frame
is never split across datagrams. No I/O.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from itertools import accumulate

__all__ = ["MAX_DATAGRAM_BYTES", "datagram_bounds", "join_frames"]

MAX_DATAGRAM_BYTES = 1200
"""Largest UDP payload [bytes] either end writes when it joins frames. 1200
fits every path without IP fragmentation: IPv6's minimum link MTU (1280,
less 40 + 8 bytes of IPv6 and UDP headers leaves 1232) and the tunnels a
ground station is often reached through (a WireGuard MTU of 1420, IPsec,
PPPoE), where Ethernet's 1472 (1500 less IPv4 and UDP headers) would be
fragmented, and one lost fragment loses the whole datagram. QUIC (RFC 9000,
section 14) chose 1200 for the same reason. 18 setpoints (65 bytes) or 30
LOCAL_POSITION_NED (40 bytes) fit one datagram."""


def datagram_bounds(sizes: Sequence[int], limit: int = MAX_DATAGRAM_BYTES) -> list[tuple[int, int]]:
    """Where frames of ``sizes`` bytes, back to back, are cut into datagrams
    of at most ``limit`` bytes: one ``(stop_frame, stop_byte)`` per datagram,
    in order; datagram j holds frames ``[stop_frame[j-1], stop_frame[j])``,
    bytes ``[stop_byte[j-1], stop_byte[j])`` (from 0 for the first). Greedy:
    a datagram takes frames until the next would pass ``limit``; a frame
    larger than ``limit`` goes alone. No frames, no datagrams."""
    n, total = len(sizes), sum(sizes)
    if total <= limit:  # the usual case: everything in one datagram (or none)
        return [(n, total)] if n else []
    cum = list(accumulate(sizes, initial=0))  # cum[k]: bytes before frame k
    cuts: list[tuple[int, int]] = []
    first = 0
    while first < n:  # the last frame whose end is within limit of this datagram's start
        stop = bisect_right(cum, cum[first] + limit, first + 1) - 1
        stop = max(stop, first + 1)  # a frame larger than limit: alone
        cuts.append((stop, cum[stop]))
        first = stop
    return cuts


def join_frames(frames: list[tuple[bytes, int]]) -> list[tuple[bytes, list[int]]]:
    """Join (frame, key) pairs into datagrams of at most ``MAX_DATAGRAM_BYTES``
    (``datagram_bounds``); each datagram with the nonzero keys of its frames
    (the vehicles whose LOCAL_POSITION_NED it carries)."""
    if not frames:
        return []
    datas, keys = zip(*frames, strict=True)
    bounds = datagram_bounds(list(map(len, datas)), MAX_DATAGRAM_BYTES)
    if len(bounds) == 1:  # the usual case
        return [(b"".join(datas), [k for k in keys if k])]
    data = b"".join(datas)
    out: list[tuple[bytes, list[int]]] = []
    first = start = 0
    for stop, end in bounds:
        out.append((data[start:end], [k for k in keys[first:stop] if k]))
        first, start = stop, end
    return out
