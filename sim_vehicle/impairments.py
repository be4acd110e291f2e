"""Seeded link impairments: loss, duplicates, delay and jitter. NO I/O.

Owns ``Impairer`` (per datagram of one link direction: lost, delivered once
or twice, each copy after ``delay_s + jitter_s * u``, from a seeded
``numpy.random.Generator``), ``DelayLine`` (the copies on their way, released
by ``now`` in arrival order, ties in the order they were sent) and
``impair``, which does both for one datagram and says what became of it.
Time is the emulator's sim time, so delays are quantised to the physics step
(``config.Impairment``). The asyncio emulator (``core``) and the in-process
harness of the tests (tests/swarm/swarm_harness.py) both impair through here.
"""

from __future__ import annotations

import heapq
import itertools
from typing import Generic, NamedTuple, TypeVar

import numpy as np

from sim_vehicle.config import Impairment

__all__ = ["EPS_S", "DelayLine", "Fate", "Impairer", "impair"]

T = TypeVar("T")
EPS_S = 1e-9
"""A copy due at ``t`` is released at any ``now >= t - EPS_S`` (sim-time rounding)."""


class Impairer:
    """Seeded per-datagram impairment of one link direction."""

    def __init__(self, imp: Impairment, rng: np.random.Generator) -> None:
        self.imp = imp
        self.rng = rng

    def delivery_delays(self) -> list[float]:
        """Delays (s) at which this datagram arrives: [] lost, one entry, or two (duplicated)."""
        imp = self.imp
        if not imp.active:
            return [0.0]
        u = self.rng.random(4)
        if u[0] < imp.loss:
            return []
        first = imp.delay_s + imp.jitter_s * u[1]
        if u[2] < imp.duplicate:
            return [first, imp.delay_s + imp.jitter_s * u[3]]
        return [first]


class DelayLine(Generic[T]):
    """Items due at a sim time, released in (due time, sending order)."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, T]] = []
        self._tie = itertools.count()

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, due_s: float, item: T) -> None:
        """``item`` arrives at sim time ``due_s``."""
        heapq.heappush(self._heap, (due_s, next(self._tie), item))

    def pop_due(self, now: float) -> T | None:
        """The next item due by ``now`` (removed), or None."""
        heap = self._heap
        if heap and heap[0][0] <= now + EPS_S:
            return heapq.heappop(heap)[2]
        return None


class Fate(NamedTuple):
    """What ``impair`` did with one datagram."""

    now: int
    """Copies to hand over at once (no delay)."""
    copies: int
    """Copies in all: 0 lost, 1, or 2 duplicated (those not handed over now wait in the line)."""


_CLEAN = Fate(1, 1)


def impair(impairer: Impairer, line: DelayLine[T], now: float, item: T) -> Fate:
    """Pass ``item`` (a datagram) through ``impairer`` at sim time ``now``: the delayed
    copies go into ``line``; the returned ``Fate`` says how many to hand over now.
    An inactive impairment draws no random number (the stream is kept for later)."""
    if not impairer.imp.active:
        return _CLEAN
    delays = impairer.delivery_delays()
    at_once = 0
    for d in delays:
        if d <= 0.0:
            at_once += 1
        else:
            line.push(now + d, item)
    return Fate(at_once, len(delays))
