"""The emulator's counters. NO I/O.

Owns ``LinkStats`` (over every endpoint: datagrams, impairment losses and
duplicates, parse errors) and ``EmulatorStats`` (steps, lockstep timeouts,
late real-time steps, and the link's).
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["EmulatorStats", "LinkStats"]


@dataclass
class LinkStats:
    """Counters over every endpoint of an emulator."""

    rx_datagrams: int = 0
    tx_datagrams: int = 0
    rx_lost: int = 0
    tx_lost: int = 0
    duplicated: int = 0
    tx_dropped_full: int = 0
    bad_frames: int = 0
    unknown_frames: int = 0
    signature_rejected: int = 0
    rx_stream_batched: int = 0
    """Datagrams of the station's acceleration stream taken column-wise
    (``lane.take_stream``), of ``rx_datagrams``."""


@dataclass
class EmulatorStats:
    """Counters: steps taken, lockstep timeouts, late real-time steps, the
    steps taken as physics alone in an overrun (``server.Emulator``), link
    counters."""

    steps: int = 0
    lockstep_timeouts: int = 0
    late_steps: int = 0
    overrun_steps: int = 0
    link: LinkStats = field(default_factory=LinkStats)
