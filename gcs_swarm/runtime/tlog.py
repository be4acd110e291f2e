"""Telemetry logs: the append-only ``.tlog`` writer (the format and the
reader are ``gcs_swarm.report.tlog``).

``TlogWriter`` (station side) never blocks the event loop for long: ``write``
appends to an in-memory buffer bounded by ``max_buffer_bytes`` (a frame that
does not fit is dropped and counted in ``stats.dropped_frames``); the buffer
is handed to a worker thread once it holds ``flush_bytes`` or every
``flush_interval_s``, and the file is flushed after each hand-over. Logging
never ends a flight (issue 15): the first error opening or writing the file
(ENOSPC, EFBIG, EIO...) stops the log; it is kept in ``error``, logged once
as a warning and handed once to ``on_error``; every later frame is dropped
and counted. As an
``async with`` lifetime it owns one ``asyncio.TaskGroup`` (the flusher); a
plain ``with`` (tools, tests, no event loop) writes synchronously at the
same thresholds. Closing writes everything still buffered.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

from gcs_swarm.report.tlog import RECORD_TIMESTAMP

__all__ = ["TlogWriter", "WriterStats"]

_log = logging.getLogger("gcs_swarm.tlog")


# ----------------------------------------------------------------------- writer
@dataclass
class WriterStats:
    """Counters of a ``TlogWriter`` (monotonic)."""

    frames: int = 0
    bytes: int = 0
    dropped_frames: int = 0
    flushes: int = 0
    write_errors: int = 0


class TlogWriter:
    """Append-only ``.tlog`` writer; see the module docstring for the policy.

    ``clock`` returns seconds since the Unix epoch (default ``time.time``);
    ``write(frame, t_us=...)`` may give the timestamp itself.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        flush_bytes: int = 64 * 1024,
        flush_interval_s: float = 1.0,
        max_buffer_bytes: int = 4 * 1024 * 1024,
        clock: Callable[[], float] = time.time,
        on_error: Callable[[str], None] | None = None,
    ) -> None:
        if not 0 < flush_bytes <= max_buffer_bytes:
            raise ValueError("need 0 < flush_bytes <= max_buffer_bytes")
        self.path = Path(path)
        self.flush_bytes = flush_bytes
        self.flush_interval_s = flush_interval_s
        self.max_buffer_bytes = max_buffer_bytes
        self.stats = WriterStats()
        self.error: str | None = None
        """Why logging stopped (the first open or write error), else None."""
        self._on_error = on_error
        self._reported = False
        self._clock = clock
        self._buf = bytearray()
        self._file: BinaryIO | None = None
        self._closed = False
        self._wake: asyncio.Event | None = None
        self._flushed: asyncio.Event | None = None
        self._tg: asyncio.TaskGroup | None = None
        self._task: asyncio.Task[None] | None = None
        self._inflight: asyncio.Future[None] | None = None
        self._io_lock = threading.Lock()  # one writer of the file at a time

    # -------------------------------------------------------------- writing
    def write(self, frame: bytes | bytearray, t_us: int | None = None) -> bool:
        """Append one raw frame; False (and counted) if the buffer is full or
        the writer is closed. Never blocks in an ``async with`` lifetime."""
        need = 8 + len(frame)
        if (
            self._file is None
            or self._closed
            or self.error is not None
            or len(self._buf) + need > self.max_buffer_bytes
        ):
            self.stats.dropped_frames += 1
            return False
        stamp = int(self._clock() * 1e6) if t_us is None else int(t_us)
        self._buf += RECORD_TIMESTAMP.pack(stamp & 0xFFFFFFFFFFFFFFFF)
        self._buf += frame
        self.stats.frames += 1
        self.stats.bytes += need
        if len(self._buf) >= self.flush_bytes:
            if self._wake is not None:
                self._wake.set()
            else:
                self._write_out(self._take())
                self._report()
        return True

    @property
    def pending_bytes(self) -> int:
        """Bytes buffered and not yet handed to the file."""
        return len(self._buf)

    def _take(self) -> bytes:
        chunk, self._buf = bytes(self._buf), bytearray()
        return chunk

    def _write_out(self, chunk: bytes) -> None:
        """Write ``chunk`` and flush the file (runs in a worker thread when async);
        an error stops the log (``_stop``) instead of propagating."""
        if not chunk or self.error is not None:
            return
        with self._io_lock:
            if self._file is None:
                return
            try:
                self._file.write(chunk)
                self._file.flush()
            except OSError as err:
                self._stop(err)
                return
        self.stats.flushes += 1

    def _stop(self, err: OSError) -> None:
        """The first write error: logging stops here, the flight goes on."""
        self.stats.write_errors += 1
        if self.error is None:
            self.error = f"{self.path}: {err.strerror or err}; logging stopped, flying on"
            _log.warning("%s", self.error)
        file, self._file = self._file, None
        if file is not None:
            with contextlib.suppress(OSError):  # its buffer cannot be written either
                file.close()

    def _report(self) -> None:
        """Hand the error to ``on_error`` once (on the caller's thread)."""
        if self.error is not None and not self._reported:
            self._reported = True
            if self._on_error is not None:
                self._on_error(self.error)

    def _open(self) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "ab")
        except OSError as err:
            self._stop(err)

    def _close_file(self) -> None:
        self._write_out(self._take())
        self._closed = True
        file, self._file = self._file, None
        if file is not None:
            try:
                file.close()
            except OSError as err:
                self._stop(err)

    # ------------------------------------------------------- sync lifetime
    def __enter__(self) -> TlogWriter:
        self._open()
        self._report()
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._close_file()
        self._report()

    # ------------------------------------------------------ async lifetime
    async def __aenter__(self) -> TlogWriter:
        await asyncio.to_thread(self._open)
        self._report()
        self._wake = asyncio.Event()
        self._flushed = asyncio.Event()
        self._tg = asyncio.TaskGroup()
        await self._tg.__aenter__()
        self._task = self._tg.create_task(self._flusher())
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._tg is not None and self._task is not None
        self._task.cancel()
        try:
            with contextlib.suppress(asyncio.CancelledError):
                await self._tg.__aexit__(None, None, None)
        finally:
            self._wake = None
            # A chunk still being written goes first, then the rest and the
            # close, off the loop; shielded so that a cancelled run still
            # leaves a complete log.
            if self._inflight is not None:
                await asyncio.shield(self._inflight)
            await asyncio.shield(asyncio.to_thread(self._close_file))
            self._report()

    async def flush(self) -> None:
        """Write everything buffered so far to the file now (in a worker
        thread), e.g. at a phase change; returns once it is on disk."""
        if self._inflight is not None:
            await asyncio.shield(self._inflight)
        chunk = self._take()
        if chunk:
            self._inflight = asyncio.ensure_future(asyncio.to_thread(self._write_out, chunk))
            await asyncio.shield(self._inflight)
            self._inflight = None
            self._report()

    async def next_flush(self) -> None:
        """Wait until the background flusher has written its next chunk."""
        if self._flushed is None:
            raise RuntimeError("the writer is not running in an async with block")
        self._flushed.clear()
        await self._flushed.wait()

    async def _flusher(self) -> None:
        assert self._wake is not None
        while True:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(self.flush_interval_s):
                    await self._wake.wait()
            self._wake.clear()
            chunk = self._take()
            if chunk:
                # Shielded: a cancellation must not abandon a chunk half-way
                # (``__aexit__`` awaits it before the close).
                self._inflight = asyncio.ensure_future(asyncio.to_thread(self._write_out, chunk))
                await asyncio.shield(self._inflight)
                self._inflight = None
                self._report()
                assert self._flushed is not None
                self._flushed.set()
