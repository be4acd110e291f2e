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

Shared memory (``shm``, on by default): between two sessions on one host,
Zenoh puts a payload of ``SHM_THRESHOLD_BYTES`` or more into a
``SHM_POOL_BYTES`` pool in ``/dev/shm`` and sends a reference over the TCP
link instead of the bytes. A state batch is 24 + 60 bytes per vehicle, so a
shard's batch crosses in shared memory from 51 vehicles on (a reply, 24 +
28 per vehicle, from 109). The pool is set up at the first large payload
(Zenoh's lazy mode), so the first few cross as bytes. ``shm_in`` counts the
samples that came in shared memory (docs/architecture.md, "What crosses
the wire").
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

SHM_THRESHOLD_BYTES = 3072
"""Payloads of this size or larger cross in shared memory between local sessions
(Zenoh 1.10's own default, written here so the run does not depend on it)."""

SHM_POOL_BYTES = 16 * 1024 * 1024
"""Each publishing session's shared-memory pool [bytes] (Zenoh 1.10's default):
about 4 steps of 1,500 vehicles' state batches would fill a tenth of it."""

BLOCK_WAIT_S = 1.0
"""How long a control message waits for room on a congested link before
Zenoh closes the link [s]: the stale timeout, after which the other side
has ended its vehicles anyway (docs/architecture.md, "Shared memory and
congestion"); Zenoh's own default is 5 s, a 5 s stall of this loop."""

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


def _config(listen: Sequence[str], connect: Sequence[str], shm: bool = True) -> zenoh.Config:
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("scouting/gossip/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(list(listen)))
    cfg.insert_json5("connect/endpoints", json.dumps(list(connect)))
    cfg.insert_json5("transport/shared_memory/enabled", json.dumps(shm))
    opt = "transport/shared_memory/transport_optimization"
    cfg.insert_json5(f"{opt}/enabled", json.dumps(shm))
    cfg.insert_json5(f"{opt}/message_size_threshold", str(SHM_THRESHOLD_BYTES))
    cfg.insert_json5(f"{opt}/pool_size", str(SHM_POOL_BYTES))
    cfg.insert_json5("transport/shared_memory/mode", json.dumps("init"))
    block = "transport/link/tx/queue/congestion_control/block/wait_before_close"
    cfg.insert_json5(block, str(round(BLOCK_WAIT_S * 1e6)))  # [us]
    return cfg


class Bus:
    """One Zenoh session (module docstring)."""

    def __init__(
        self, *, listen: Sequence[str] = (), connect: Sequence[str] = (), shm: bool = True
    ) -> None:
        self.listen = tuple(listen)
        self.connect = tuple(connect)
        self.shm = shm
        self._session: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._subs: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self.bytes_out = 0
        self.bytes_in = 0
        self.samples_in = 0
        self.shm_in = 0
        """Samples in, and those of them that came in shared memory (module docstring)."""

    async def __aenter__(self) -> Bus:
        self._loop = asyncio.get_running_loop()
        cfg = _config(self.listen, self.connect, self.shm)
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
            payload = sample.payload
            shm = payload.as_shm() is not None
            data = payload.to_bytes()
            try:
                loop.call_soon_threadsafe(self._deliver, handler, str(sample.key_expr), data, shm)
            except RuntimeError:  # the loop closed while Zenoh still delivered
                pass

        self._subs.append(self._session.declare_subscriber(f"{PREFIX}/{key}", on_sample))

    def _deliver(self, handler: Handler, key: str, data: bytes, shm: bool) -> None:
        self.bytes_in += len(data)
        self.samples_in += 1
        self.shm_in += shm
        handler(key[len(PREFIX) + 1 :], data)

    def put(self, key: str, data: bytes, *, droppable: bool = False) -> None:
        """Publish ``data`` at ``key`` now (express: not held for batching).

        A key's first put sets its policy when the link is congested (its
        queue, 2 batches of 64 KiB, full: the peer does not read fast enough).
        ``droppable`` (a step's batch, a view frame: a newer one follows
        within a step) is dropped after Zenoh waits 1 ms (50 ms for a
        fragmented one), so a slow peer never stalls this loop. Otherwise
        (handshakes, beats, ends, reports) the put waits for room: measured
        on 127.0.0.1, behind a burst of fifty 84 kB batches, 1-49 of the
        batches were dropped and no control message was
        (tests/station/test_zbus.py)."""
        if self._session is None:
            return
        pub = self._pubs.get(key)
        if pub is None:
            cc = zenoh.CongestionControl
            congestion = cc.DROP if droppable else cc.BLOCK
            pub = self._session.declare_publisher(
                f"{PREFIX}/{key}", express=True, congestion_control=congestion
            )
            self._pubs[key] = pub
        self.bytes_out += len(data)
        pub.put(data)

    def put_json(self, key: str, obj: dict[str, Any], *, droppable: bool = False) -> None:
        self.put(key, json.dumps(obj).encode(), droppable=droppable)
