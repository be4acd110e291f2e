"""Zenoh as the shards' transport: one session, publishers and subscribers
handed to the asyncio loop (docs/architecture.md, "Scaled out: shards").

``Bus`` is one ``async with`` lifetime around ``zenoh.open`` (STYLE.md
habit 7). It is configured explicitly and never from the environment: peer
mode, multicast and gossip scouting off, so a session meets only the
endpoints it is given (``listen`` on the controller, ``connect`` on a
shard): ``tcp/127.0.0.1:<port>`` on one machine, ``quic/HOST:PORT`` (or
``tls/HOST:PORT``) between machines. Zenoh calls a subscriber back on its
own threads; each sample is passed to the loop with ``call_soon_threadsafe``,
so every handler runs on the loop, in arrival order per key.

``quic/`` and ``tls/`` need ``TlsFiles``: a CA, and this side's certificate
and private key (PEM). Both are always mutual TLS (Zenoh's ``enable_mtls``):
the controller accepts only a shard whose certificate the CA signed, and a
shard accepts only a controller whose certificate the CA signed (or a public
root that Zenoh also trusts, webpki's) and names the host it connects to
(``verify_name_on_connect``). A peer that fails either check never joins the
session: its messages are not received, and no error is raised or printed on
either side (Zenoh retries the connection in the background), so a shard
gives up after its hello timeout and a controller after its own, each with
``Bus.hint``: what to check. ``tcp/`` and ``udp/`` are neither encrypted nor
authenticated: for one machine (127.0.0.1) or a network trusted as a cable.

Shared memory (``shm``, on by default): between two sessions on one host,
Zenoh puts a payload of ``SHM_THRESHOLD_BYTES`` or more into a
``SHM_POOL_BYTES`` pool in ``/dev/shm`` and sends a reference over the TCP
link instead of the bytes. A state batch is 24 + 60 bytes per vehicle, so a
shard's batch crosses in shared memory from 51 vehicles on (a reply, 24 +
28 per vehicle, from 109). The pool is set up when the session opens
(Zenoh's "init" mode); the first few large payloads of a new link may
still cross as bytes. ``shm_in`` counts the samples that came in shared
memory (docs/architecture.md, "Shared memory and congestion").
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import zenoh

from gcs_swarm.errors import LinkError, UsageError

__all__ = [
    "ENDPOINT_RE",
    "OPEN_TIMEOUT_MS",
    "PREFIX",
    "TLS_SCHEMES",
    "Bus",
    "TlsFiles",
    "check_endpoint",
    "check_tls",
    "free_endpoint",
]

_log = logging.getLogger("gcs_swarm.zbus")

PREFIX = "gcs_swarm/shards"
"""Every key of a sharded run starts here."""

ENDPOINT_RE = re.compile(r"^(tcp|quic|tls|udp)/(\[[0-9A-Fa-f:]+\]|[A-Za-z0-9._-]+):(\d{1,5})$")
"""A Zenoh locator the shards accept: ``tcp/HOST:PORT`` (``quic/``, ``tls/``, ``udp/``)."""

TLS_SCHEMES = ("quic", "tls")
"""The endpoints that need ``TlsFiles`` (and that no others may have)."""

TLS_OPTIONS = ("--tls-ca", "--tls-cert", "--tls-key")
"""The command line's names of ``TlsFiles``' three fields, in their order."""

OPEN_TIMEOUT_MS = 3000
"""How long Zenoh may take to open a link, its TLS and its own handshakes
included [ms] (``transport/unicast/open_timeout``; Zenoh's default 10 s):
0.1 s measured on 127.0.0.1, a few round trips between hosts. It also bounds
a shard's exit once its controller has gone: the shard's session is then
reconnecting, a QUIC attempt at a closed port is not refused as a TCP one
is (it times out), and closing the session waits for it (measured: 10 s)."""

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

PICK_ATTEMPTS = 5
"""How many ports ``Bus.on_free_port`` tries before it gives up (each a
fresh pick of the OS; one taken in between is a rare race, five in a row
is a machine out of ports)."""

Handler = Callable[[str, bytes], None]


def check_endpoint(text: str, option: str = "--connect") -> str:
    """``text`` if it is a locator ``ENDPOINT_RE`` accepts; ``UsageError``
    naming ``option`` otherwise."""
    m = ENDPOINT_RE.match(text)
    if m is None or not 0 < int(m.group(3)) < 65536:
        raise UsageError(
            f"{option} {text!r}: expected a Zenoh endpoint tcp/HOST:PORT (or quic/, tls/, udp/),"
            " e.g. tcp/127.0.0.1:7447"
        )
    return text


def free_endpoint(scheme: str = "tcp") -> str:
    """``SCHEME/127.0.0.1:<port>`` on a port free now (the OS's pick; a UDP
    port for ``quic/``, which runs over UDP, a TCP port otherwise). Another
    socket may take it before Zenoh binds it: ``Bus.on_free_port`` then
    picks again."""
    kind = socket.SOCK_DGRAM if scheme == "quic" else socket.SOCK_STREAM
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"{scheme}/127.0.0.1:{port}"


@dataclass(frozen=True)
class TlsFiles:
    """One side's TLS files (PEM) for a ``quic/`` or ``tls/`` endpoint: ``ca``
    the certificate authority that signed the other side's certificate,
    ``cert`` and ``key`` this side's certificate and private key (module
    docstring: always mutual TLS)."""

    ca: Path
    cert: Path
    key: Path


def _needs_tls(endpoint: str) -> bool:
    return endpoint.split("/", 1)[0] in TLS_SCHEMES


_PEM = {"--tls-ca": b"-----BEGIN CERTIFICATE-----", "--tls-cert": b"-----BEGIN CERTIFICATE-----",
        "--tls-key": b"PRIVATE KEY-----"}  # fmt: skip


def _pem_file(option: str, path: str) -> Path:
    """``path`` made absolute (Zenoh reads it later, wherever it runs) once
    it reads as a PEM file of ``option``'s kind; one-line ``UsageError``
    naming the option and the file otherwise."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise UsageError(f"{option} {path}: no such file") from None
    except OSError as err:
        raise UsageError(f"{option} {path}: cannot read it: {err.strerror or err}") from None
    if _PEM[option] not in data:
        what = "private key" if option == "--tls-key" else "certificate"
        raise UsageError(f"{option} {path}: not a PEM {what} (no {_PEM[option].decode()!r})")
    return Path(path).absolute()


def check_tls(
    endpoint: str | None, option: str, ca: str | None, cert: str | None, key: str | None
) -> TlsFiles | None:
    """The ``--tls-ca/--tls-cert/--tls-key`` options for ``option endpoint``
    (``--listen`` or ``--connect``; ``endpoint`` as ``check_endpoint`` passed
    it, None when the option was not given): ``TlsFiles`` for ``quic/`` and
    ``tls/``, which need all three; None for the others, which take none.
    One-line ``UsageError`` naming the option and the file otherwise."""
    given = {o: v for o, v in zip(TLS_OPTIONS, (ca, cert, key), strict=True) if v is not None}
    if endpoint is None or not _needs_tls(endpoint):
        if given:
            first, path = next(iter(given.items()))
            here = f"not {endpoint}" if endpoint else f"and no {option} is given"
            raise UsageError(f"{first} {path}: only with a quic/ or tls/ {option} endpoint,"
                             f" {here}")  # fmt: skip
        return None
    missing = [o for o in TLS_OPTIONS if o not in given]
    if missing:
        raise UsageError(
            f"{option} {endpoint}: quic/ and tls/ are mutual TLS and need --tls-ca, --tls-cert"
            f" and --tls-key; missing {', '.join(missing)} (docs/architecture.md)"
        )
    ca_p, cert_p, key_p = (_pem_file(o, given[o]) for o in TLS_OPTIONS)
    return TlsFiles(ca=ca_p, cert=cert_p, key=key_p)


def _config(
    listen: Sequence[str], connect: Sequence[str], tls: TlsFiles | None, shm: bool = True
) -> zenoh.Config:
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
    cfg.insert_json5("transport/unicast/open_timeout", str(OPEN_TIMEOUT_MS))
    if tls is not None:
        # Zenoh 1.10's keys (its DEFAULT_CONFIG.json5, transport/link/tls). The
        # same certificate serves a listener (the controller) and a connector
        # (a shard); enable_mtls makes a listener demand the connector's, which
        # it checks against root_ca_certificate alone. An expiring certificate
        # does not cut a link in flight: it is refused at the next connection.
        for name, value in (
            ("root_ca_certificate", str(tls.ca)),
            ("listen_certificate", str(tls.cert)),
            ("listen_private_key", str(tls.key)),
            ("connect_certificate", str(tls.cert)),
            ("connect_private_key", str(tls.key)),
            ("enable_mtls", True),
            ("verify_name_on_connect", True),
            ("close_link_on_expiration", False),
        ):
            cfg.insert_json5(f"transport/link/tls/{name}", json.dumps(value))
    return cfg


class Bus:
    """One Zenoh session (module docstring)."""

    def __init__(
        self,
        *,
        listen: Sequence[str] = (),
        connect: Sequence[str] = (),
        tls: TlsFiles | None = None,
        shm: bool = True,
    ) -> None:
        self.listen = tuple(listen)
        self.connect = tuple(connect)
        secure = [e for e in self.listen + self.connect if _needs_tls(e)]
        if secure and tls is None:
            raise UsageError(f"{secure[0]}: quic/ and tls/ endpoints need TLS files (TlsFiles)")
        if tls is not None and not secure:
            raise UsageError("TLS files are for quic/ and tls/ endpoints only")
        self.tls = tls
        self.shm = shm
        self._pick: Callable[[], str] | None = None
        self._session: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._subs: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self.bytes_out = 0
        self.bytes_in = 0
        self.samples_in = 0
        self.shm_in = 0
        """Samples in, and those of them that came in shared memory (module docstring)."""

    @classmethod
    def on_free_port(
        cls,
        scheme: str = "tcp",
        *,
        tls: TlsFiles | None = None,
        shm: bool = True,
        pick: Callable[[str], str] = free_endpoint,
    ) -> Bus:
        """A session listening on a free 127.0.0.1 port of ``scheme``
        (``pick(scheme)``, ``free_endpoint`` by default; ``listen[0]`` once
        entered): a port taken between the pick and Zenoh's bind is picked
        again, up to ``PICK_ATTEMPTS`` times."""
        bus = cls(listen=[pick(scheme)], tls=tls, shm=shm)
        bus._pick = lambda: pick(scheme)
        return bus

    async def __aenter__(self) -> Bus:
        self._loop = asyncio.get_running_loop()
        attempt = 1
        while True:
            cfg = _config(self.listen, self.connect, self.tls, self.shm)
            try:
                self._session = await asyncio.to_thread(zenoh.open, cfg)
                return self
            except Exception as err:  # zenoh.ZError: the locator did not open
                where = ", ".join(self.listen + self.connect)
                if self._pick is None or "in use" not in str(err) or attempt == PICK_ATTEMPTS:
                    raise LinkError(f"zenoh session on {where}: {err}") from None
                _log.info("%s was taken before zenoh bound it; picking another port", where)
                self.listen = (self._pick(),)
                attempt += 1

    def hint(self) -> str:
        """What a timed-out handshake may mean on this bus: with TLS, a peer
        refused for its certificate (module docstring); "" without."""
        if self.tls is None:
            return ""
        return (" (TLS: is each side's certificate signed by the other side's --tls-ca,"
                " and does the controller's name the host the shards connect to?)")  # fmt: skip

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
            try:
                await asyncio.to_thread(session.close)
            except zenoh.ZError as err:  # seen: "close operation timed out" (QUIC reconnecting)
                _log.warning("zenoh session on %s did not close cleanly: %s",
                             ", ".join(self.listen + self.connect), err)  # fmt: skip

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
        ``droppable`` (a step's batch in real time: a newer one follows
        within a step) is dropped after Zenoh waits 1 ms (50 ms for a
        fragmented one), so a slow peer never stalls this loop. Otherwise
        (handshakes, beats, ends, reports, view frames, lockstep batches)
        the put waits for room: measured
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
