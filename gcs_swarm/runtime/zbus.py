"""Zenoh as the shards' transport: one session, publishers and subscribers
handed to the asyncio loop (docs/architecture.md, "Scaled out: shards").

``Bus`` is one ``async with`` lifetime around ``zenoh.open`` (STYLE.md
habit 7). It is configured explicitly and never from the environment: peer
mode, multicast and gossip scouting off, so a session meets only the
endpoints it is given (``listen`` on the controller, ``connect`` on a
shard): ``tcp/127.0.0.1:<port>`` on one machine, ``tcp/HOST:PORT`` or
``quic/HOST:PORT`` between machines. Zenoh calls a subscriber back on its
own threads; each sample is passed to the loop with ``call_soon_threadsafe``,
so every handler runs on the loop, in arrival order per key.
"""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Any

import zenoh

from gcs_swarm.errors import LinkError, UsageError

__all__ = ["ENDPOINT_RE", "PREFIX", "Bus", "check_endpoint"]

PREFIX = "gcs_swarm/shards"
"""Every key of a sharded run starts here."""

ENDPOINT_RE = re.compile(r"^(tcp|quic|udp)/(\[[0-9A-Fa-f:]+\]|[A-Za-z0-9._-]+):(\d{1,5})$")
"""A Zenoh locator the shards accept: ``tcp/HOST:PORT`` (``quic/``, ``udp/``)."""

Handler = Callable[[str, bytes], None]


def check_endpoint(text: str, option: str = "--connect") -> str:
    """``text`` if it is a locator ``ENDPOINT_RE`` accepts; ``UsageError``
    naming ``option`` otherwise."""
    m = ENDPOINT_RE.match(text)
    if m is None or not 0 < int(m.group(3)) < 65536:
        raise UsageError(
            f"{option} {text!r}: expected a Zenoh endpoint tcp/HOST:PORT (or quic/, udp/),"
            " e.g. tcp/127.0.0.1:7447"
        )
    return text


def _config(listen: Sequence[str], connect: Sequence[str]) -> zenoh.Config:
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("scouting/gossip/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(list(listen)))
    cfg.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return cfg


class Bus:
    """One Zenoh session (module docstring)."""

    def __init__(self, *, listen: Sequence[str] = (), connect: Sequence[str] = ()) -> None:
        self.listen = tuple(listen)
        self.connect = tuple(connect)
        self._session: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._subs: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self.bytes_out = 0
        self.bytes_in = 0

    async def __aenter__(self) -> Bus:
        self._loop = asyncio.get_running_loop()
        cfg = _config(self.listen, self.connect)
        where = ", ".join(self.listen + self.connect)
        try:
            self._session = await asyncio.to_thread(zenoh.open, cfg)
        except Exception as err:  # zenoh.ZError: the locator did not open
            raise LinkError(f"zenoh session on {where}: {err}") from None
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        session, self._session = self._session, None
        for sub in self._subs:
            sub.undeclare()
        self._subs.clear()
        for pub in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()
        if session is not None:
            await asyncio.to_thread(session.close)

    def subscribe(self, key: str, handler: Handler) -> None:
        """``handler(key, payload)`` on the loop for every sample under ``key``."""
        loop = self._loop
        assert loop is not None and self._session is not None

        def on_sample(sample: Any) -> None:  # a Zenoh thread
            data = sample.payload.to_bytes()
            try:
                loop.call_soon_threadsafe(self._deliver, handler, str(sample.key_expr), data)
            except RuntimeError:  # the loop closed while Zenoh still delivered
                pass

        self._subs.append(self._session.declare_subscriber(f"{PREFIX}/{key}", on_sample))

    def _deliver(self, handler: Handler, key: str, data: bytes) -> None:
        self.bytes_in += len(data)
        handler(key[len(PREFIX) + 1 :], data)

    def put(self, key: str, data: bytes) -> None:
        """Publish ``data`` at ``key`` now (express: not held for batching)."""
        if self._session is None:
            return
        pub = self._pubs.get(key)
        if pub is None:
            pub = self._session.declare_publisher(f"{PREFIX}/{key}", express=True)
            self._pubs[key] = pub
        self.bytes_out += len(data)
        pub.put(data)

    def put_json(self, key: str, obj: dict[str, Any]) -> None:
        self.put(key, json.dumps(obj).encode())
