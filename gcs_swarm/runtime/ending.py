"""An operator's request to end the mission now, and waiting unless it comes.

The view's Hold, Land and Return buttons (``gcs_swarm.view.live``) do not
command a vehicle themselves: they fill an ``EndRequest``, and
``run_mission`` then stops waiting on the start-up or the flight and ends
every vehicle with that end action through ``Station.end`` (zero
acceleration, then the mode, confirmed by heartbeat), the path the mission's
own ``end`` takes when its duration is over.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Coroutine
from typing import Any

__all__ = ["END_ACTIONS", "EndRequest", "unless_ended"]

END_ACTIONS = ("hold", "land", "rtl")
"""What an operator may ask for: the mission's ``end`` choices (``run.END_MODES``)."""


class EndRequest:
    """The first end action asked for (later ones are refused)."""

    def __init__(self) -> None:
        self.action: str | None = None
        self._asked = asyncio.Event()

    def request(self, action: str) -> bool:
        """Ask to end now with ``action`` (one of ``END_ACTIONS``); False when
        an action was already asked for. ``ValueError`` on another name."""
        if action not in END_ACTIONS:
            names = ", ".join(END_ACTIONS)
            raise ValueError(f"end action: expected one of {names}, got {action!r}")
        if self.action is not None:
            return False
        self.action = action
        self._asked.set()
        return True

    async def wait(self) -> None:
        await self._asked.wait()


async def unless_ended(request: EndRequest | None, work: Coroutine[Any, Any, None]) -> bool:
    """Run ``work`` until it returns (False) or ``request`` is asked (True:
    ``work`` is cancelled). Without a request this is ``await work``."""
    if request is None:
        await work
        return False
    if request.action is not None:
        work.close()
        return True
    task = asyncio.ensure_future(work)
    asked = asyncio.ensure_future(request.wait())
    try:
        await asyncio.wait((task, asked), return_when=asyncio.FIRST_COMPLETED)
    finally:
        for t in (task, asked):
            if not t.done():
                t.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await t
    if task.cancelled():
        return True
    task.result()  # its exception, if it failed
    return False
