"""The ``async with`` lifetime habit (STYLE.md habit 7) shared by the links
and the station: each owns one ``asyncio.TaskGroup`` of its own tasks."""

from __future__ import annotations

import asyncio
from collections.abc import Iterable
from types import TracebackType

__all__ = ["close_task_group"]


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
