"""The operator view's server: the page over HTTP and frames over a WebSocket.

``ViewServer`` is one ``async with`` lifetime on the caller's event loop (the
station's): a ``websockets`` server (HTTP for the page and its two files,
the WebSocket at ``/ws``, on one port) and one push task that builds a frame
(``frames()``, cheap: ``view.snapshot``) at ``rate_hz`` while somebody
watches and offers it to every client. Why ``websockets``: it is one
well-kept dependency that does the handshake, framing, ping and close
correctly on asyncio, and its ``process_request`` hook serves the page on
the same port, so no HTTP server had to be written here.

Rules (docs/operator-view.md):

- bound to 127.0.0.1 unless another host is named;
- every request needs the run's token (``secrets.token_urlsafe``) as
  ``?token=``: a page or a file without it is refused with HTTP 403, and so
  is the WebSocket's opening handshake (the socket is closed);
- each client has a slot for one frame (STYLE.md habit 6: size 1, newest
  wins, drops counted): its own sender task writes it; a client that has not
  drained the last frame when the next is ready loses the older one
  (``dropped``). Nothing here is awaited by the control path: the push task
  only builds a string and fills slots;
- what a client sends is handed to ``on_command`` (a dict, parsed from JSON,
  at most ``_MAX_MESSAGE`` bytes); its answer goes back to that client. The
  live view accepts only the end buttons (``view.live``).
"""

from __future__ import annotations

import asyncio
import contextlib
import email.utils
import http
import json
import logging
import secrets
import socket
import time
from collections import deque
from collections.abc import Callable
from importlib import resources
from types import TracebackType
from typing import Any
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from gcs_swarm.errors import LinkError

__all__ = ["ViewServer", "parse_address"]

_log = logging.getLogger("gcs_swarm.view")

_FILES = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/view.js": ("view.js", "text/javascript; charset=utf-8"),
    "/view.css": ("view.css", "text/css; charset=utf-8"),
}
_CLOSE_S = 1.0
"""How long [s] the pages get to close the WebSocket at the end before their
sockets are cut (a stalled one never would)."""
_RECENT_EVENTS = 300
"""Events a page that opens late is sent first (the frames carry only new ones)."""
_MAX_MESSAGE = 4096
"""Largest message [bytes] a page may send (a button press is ~40)."""

Frames = Callable[[], dict[str, Any]]
OnCommand = Callable[[dict[str, Any]], dict[str, Any]]


def parse_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); the host is 127.0.0.1 unless named
    (``[::1]:8080`` for an IPv6 one). ``ValueError`` with what was expected."""
    host, _, port_s = text.rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_s)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise ValueError(f"expected [HOST:]PORT with a port 0..65535, got {text!r}")
    return host, port


def _static(name: str) -> bytes:
    return (resources.files("gcs_swarm.view") / "static" / name).read_bytes()


class _Client:
    """One page's slot: the newest frame not yet written, and the answers."""

    def __init__(self, ws: ServerConnection) -> None:
        self.ws = ws
        self.frame: str | None = None
        self.answers: list[str] = []
        self.ready = asyncio.Event()
        self.sent = 0
        self.dropped = 0

    def offer(self, text: str) -> None:
        if self.frame is not None:
            self.dropped += 1  # still not drained: the older frame goes
        self.frame = text
        self.ready.set()


class ViewServer:
    """The page and its frames for one run (module docstring)."""

    def __init__(
        self,
        frames: Frames,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        rate_hz: float = 10.0,
        token: str | None = None,
        on_command: OnCommand | None = None,
        hello: dict[str, Any] | None = None,
        write_limit: int = 2**15,
        send_buffer: int | None = 2**16,
    ) -> None:
        """``frames()`` builds one frame (a JSON-able dict); ``hello`` is sent
        to each page first (``mode``: "live" or "replay", and what it needs);
        ``write_limit`` [bytes]: a client's buffer above this is "not drained"
        (websockets' high-water mark); ``send_buffer`` [bytes]: the kernel's
        send buffer per client (SO_SNDBUF; None: the system's, which grows
        to megabytes: a stalled page would then swallow a minute of frames
        before any is dropped)."""
        if not 0.0 < rate_hz <= 60.0:
            raise ValueError(f"rate_hz: expected 0 < rate <= 60, got {rate_hz}")
        self._frames = frames
        self.host, self.port, self.rate_hz = host, port, rate_hz
        self.token = token if token is not None else secrets.token_urlsafe(16)
        self._on_command = on_command
        self._hello = {"type": "hello", **(hello or {"mode": "live"})}
        self._recent: deque[Any] = deque(maxlen=_RECENT_EVENTS)
        self._write_limit = write_limit
        self._send_buffer = send_buffer
        self._clients: set[_Client] = set()
        self._server: Server | None = None
        self._push: asyncio.Task[None] | None = None
        self._files = {path: (_static(name), kind) for path, (name, kind) in _FILES.items()}
        self.frames_built = 0
        self.build_s: deque[float] = deque(maxlen=1000)
        """What building and encoding each recent frame took [s] (on the event loop)."""
        self.refused = 0
        """Requests refused for a wrong or missing token."""
        self._gone_sent = 0
        self._failed = False
        self._stepped: asyncio.Event | None = None
        self._gone_dropped = 0

    @property
    def url(self) -> str:
        """The page's address with the token (printed at start, as Jupyter does)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/?token={self.token}"

    def step_done(self) -> None:
        """The station has just stepped (``Station.on_step``):
        a frame that is due is built once this step's setpoints are out,
        while the loop waits for the next round of telemetry, rather than
        whenever its timer fires (then it could delay a report's answer by
        the frame's cost). Without steps (start-up, ending) frames go on at
        their own pace."""
        if self._stepped is None:
            self._stepped = asyncio.Event()
        self._stepped.set()

    @property
    def clients(self) -> int:
        return len(self._clients)

    @property
    def frames_sent(self) -> int:
        return self._gone_sent + sum(c.sent for c in self._clients)

    @property
    def frames_dropped(self) -> int:
        """Frames replaced before a slow client had taken them (every client, whole run)."""
        return self._gone_dropped + sum(c.dropped for c in self._clients)

    # ------------------------------------------------------------ lifetime
    async def __aenter__(self) -> ViewServer:
        try:
            self._server = await serve(
                self._handler,
                self.host,
                self.port,
                process_request=self._process_request,
                write_limit=self._write_limit,
                max_size=_MAX_MESSAGE,
                max_queue=4,
                close_timeout=_CLOSE_S,
                server_header=None,
            )
        except OSError as err:  # a port in use, a host that does not resolve
            where = f"{self.host}:{self.port}"
            raise LinkError(f"operator view on {where}: {err.strerror or err}") from None
        sock = next(iter(self._server.sockets))
        self.port = int(sock.getsockname()[1])
        self._push = asyncio.get_running_loop().create_task(self._push_frames())
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._push is not None:
            self._push.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._push
            self._push = None
        if self._server is not None:
            self._server.close(close_connections=True)
            try:
                async with asyncio.timeout(_CLOSE_S):
                    await self._server.wait_closed()
            except TimeoutError:
                # A stalled page cannot even take the closing frame: cut it.
                for client in list(self._clients):
                    client.ws.transport.abort()
                await self._server.wait_closed()
            self._server = None

    # ---------------------------------------------------------------- HTTP
    def _process_request(self, conn: ServerConnection, request: Request) -> Response | None:
        parts = urlsplit(request.path)
        given = parse_qs(parts.query).get("token", [""])[0]
        if not secrets.compare_digest(given.encode(), self.token.encode()):
            self.refused += 1
            return conn.respond(http.HTTPStatus.FORBIDDEN, "a valid ?token= is needed\n")
        if parts.path == "/ws":
            return None  # the WebSocket's opening handshake goes on
        found = self._files.get(parts.path)
        if found is None:
            return conn.respond(http.HTTPStatus.NOT_FOUND, "not found\n")
        body, kind = found
        if parts.path == "/":
            body = body.replace(b"__TOKEN__", self.token.encode())
        headers = Headers(
            [
                ("Date", email.utils.formatdate(usegmt=True)),
                ("Connection", "close"),
                ("Content-Length", str(len(body))),
                ("Content-Type", kind),
                ("Cache-Control", "no-store"),
                ("Content-Security-Policy", "default-src 'self'; connect-src 'self' ws: wss:"),
            ]
        )
        return Response(200, "OK", headers, body)

    # ----------------------------------------------------------- WebSocket
    async def _handler(self, ws: ServerConnection) -> None:
        sock = ws.transport.get_extra_info("socket")
        if self._send_buffer is not None and sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self._send_buffer)
        client = _Client(ws)
        client.answers.append(json.dumps({**self._hello, "events": list(self._recent)}))
        client.ready.set()
        self._clients.add(client)
        sender = asyncio.get_running_loop().create_task(self._send(ws, client))
        try:
            async for message in ws:
                answer = self._command(message)
                client.answers.append(json.dumps(answer))
                client.ready.set()
        except ConnectionClosed:
            pass
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
            self._clients.discard(client)
            self._gone_sent += client.sent
            self._gone_dropped += client.dropped

    async def _send(self, ws: ServerConnection, client: _Client) -> None:
        """Write this client's answers, then its newest frame; the only place
        that awaits its socket."""
        with contextlib.suppress(ConnectionClosed):
            while True:
                await client.ready.wait()
                client.ready.clear()
                while client.answers:
                    await ws.send(client.answers.pop(0))
                frame, client.frame = client.frame, None
                if frame is not None:
                    await ws.send(frame)
                    client.sent += 1

    def _command(self, message: str | bytes) -> dict[str, Any]:
        try:
            msg = json.loads(message)
        except (ValueError, UnicodeDecodeError):
            msg = None
        if not isinstance(msg, dict):
            return {"type": "answer", "ok": False, "text": "expected a JSON object"}
        if self._on_command is None:
            return {"type": "answer", "ok": False, "text": "this view takes no commands"}
        return {"type": "answer", **self._on_command(msg)}

    # ---------------------------------------------------------------- push
    async def _push_frames(self) -> None:
        """A frame every 1/rate_hz s while a page is open (none otherwise)."""
        loop = asyncio.get_running_loop()
        period = 1.0 / self.rate_hz
        due = loop.time()
        while True:
            due = max(due + period, loop.time())
            await asyncio.sleep(due - loop.time())
            if not self._clients:
                continue
            if self._stepped is not None:  # just after the next step (``step_done``)
                self._stepped.clear()
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(period):
                        await self._stepped.wait()
            t0 = time.perf_counter()
            try:
                frame = self._frames()
                frame["view"] = {"clients": len(self._clients), "dropped": self.frames_dropped}
                self._recent.extend(frame.get("events", ()))
                text = json.dumps(frame, separators=(",", ":"), allow_nan=False)
            except Exception:  # the view must never take the flight down
                if not self._failed:
                    _log.exception("operator view: a frame could not be built")
                    self._failed = True
                continue
            self.frames_built += 1
            self.build_s.append(time.perf_counter() - t0)
            for client in self._clients:
                client.offer(text)
