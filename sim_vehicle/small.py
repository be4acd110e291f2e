"""The emulator's one small-N switch. NO I/O.

Below ``SMALL_N`` vehicles (or frames) the hot path runs on plain Python
floats and lists instead of numpy, whose fixed cost per call then outweighs
the work: the physics step (``dynamics_rows.advance_rows`` against the
reference ``dynamics.step``), the CRC of LOCAL_POSITION_NED frames
(``codec``), the schedule's due rows and the lockstep test (``schedule``,
``lockstep``). Both sides of every switch give the same bits (the tests
compare them); only the time they take depends on the side.
"""

from __future__ import annotations

__all__ = ["SMALL_N", "few"]

SMALL_N = 32
"""Below this many vehicles (or frames) the plain-Python side of each switch runs."""


def few(n: int) -> bool:
    """True when ``n`` vehicles (or frames) take the plain-Python side (``n < SMALL_N``)."""
    return n < SMALL_N
