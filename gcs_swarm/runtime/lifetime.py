"""The ``async with`` lifetime habit (STYLE.md habit 7) shared by the links
and the station: each owns one ``asyncio.TaskGroup`` of its own tasks; and
the end of the child processes a sharded run started (``reap``)."""

from __future__ import annotations

import asyncio
from collections.abc import Iterable
from types import TracebackType

__all__ = ["close_task_group", "reap"]


async def close_task_group(
    tg: asyncio.TaskGroup,
    tasks: Iterable[asyncio.Task[None]],
    et: type[BaseException] | None,
    ev: BaseException | None,
    tb: TracebackType | None,
) -> None:
    """Cancel ``tasks`` (the lifetime's own) and exit ``tg``. The TaskGroup is
    handed only a cancellation (its bookkeeping needs it), so that an error
    of the ``async with`` body (e.g. StartupError) propagates as itself, not
    wrapped in an ExceptionGroup."""
    for task in tasks:
        task.cancel()
    cancelled = et is not None and issubclass(et, asyncio.CancelledError)
    await tg.__aexit__(*((et, ev, tb) if cancelled else (None, None, None)))


async def reap(processes: list[asyncio.subprocess.Process], wait_s: float) -> None:
    """Wait for the shard processes this run started (they exit once they
    sent their report); one still there after 2 s gets SIGTERM (it ends its
    vehicles, then exits: ``runtime.shard``), after ``wait_s`` more SIGKILL."""
    for grace, stop in ((2.0, "terminate"), (wait_s, "kill"), (None, "")):
        live = [p for p in processes if p.returncode is None]
        if not live:
            return
        try:
            async with asyncio.timeout(grace):
                for proc in live:
                    await proc.wait()
        except TimeoutError:
            for proc in live:
                if proc.returncode is None:
                    getattr(proc, stop)()
