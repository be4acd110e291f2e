"""CPU-bound pure jobs (the plane look-ahead) in a worker thread, without
stalling the setpoint stream.

A worker thread holding the GIL delays the event loop each time the loop
gets it back: after every socket call (which releases it) the loop thread
waits up to the interpreter's switch interval (5 ms by default) before
the worker is made to drop it. A control step makes several such calls,
so at the avoidance switch, with the look-ahead (~0.15-0.25 s of Python)
running beside the loop, one setpoint interval stretched to 1.5-1.7
periods at 50 Hz (``benchmarks/bench_lookahead.py``, target <= 1.5).
While at least one such job runs, the switch interval is
``JOB_SWITCH_INTERVAL_S`` (0.5 ms) and the previous value is put back
when the last one ends (benchmarks/README.md, "Look-ahead gap"). The
setting is the interpreter's, so it changes for the whole process while
a job runs, then is restored.
"""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol, TypeVar

if TYPE_CHECKING:
    from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult

__all__ = ["JOB_SWITCH_INTERVAL_S", "run_cpu_job", "run_lookahead"]

T = TypeVar("T")

JOB_SWITCH_INTERVAL_S = 0.0005
"""The interpreter's switch interval [s] while a CPU-bound job runs in a
worker thread (``sys.setswitchinterval``)."""

_running = 0
_saved = 0.0


async def run_cpu_job(job: Callable[[], T]) -> T:
    """``job()`` in a worker thread (``asyncio.to_thread``), the switch
    interval shortened meanwhile (module docstring)."""
    global _running, _saved
    if _running == 0:
        _saved = sys.getswitchinterval()
        if _saved > JOB_SWITCH_INTERVAL_S:  # a shorter one is left alone
            sys.setswitchinterval(JOB_SWITCH_INTERVAL_S)
    _running += 1
    try:
        return await asyncio.to_thread(job)
    finally:
        _running -= 1
        if _running == 0 and _saved > JOB_SWITCH_INTERVAL_S:
            sys.setswitchinterval(_saved)


class _Resolving(Protocol):
    """What takes a look-ahead's result: ``SwarmCore`` and ``ControllerCore``."""

    def resolve_lookahead(
        self, job: LookaheadJob, result: LookaheadResult, took_s: float
    ) -> None: ...


async def run_lookahead(core: _Resolving, job: LookaheadJob, now: Callable[[], float]) -> None:
    """The plane look-ahead ``job`` off the step (``run_cpu_job``: the setpoints
    keep flowing), its result handed to ``core`` with the time it took [s] on
    the shell's clock ``now``."""
    t0 = now()
    result = await run_cpu_job(job)
    core.resolve_lookahead(job, result, now() - t0)
