"""What a link is made of besides its I/O: the parsed connection string, the
counters (``swarm.link_state.LinkStats``), and the ring of setpoint
latencies (``gcs_swarm.runtime.links`` uses them; they hold no sockets and
no tasks)."""

from __future__ import annotations

from array import array
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from gcs_swarm.errors import LinkError
from gcs_swarm.swarm.link_state import LinkStats

__all__ = ["Endpoint", "LatencyRing", "LinkStats", "Scheme", "parse_connection"]

Scheme = Literal["udpin", "udpout", "tcp", "tcpin"]


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string."""

    scheme: Scheme
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.scheme}:{self.host}:{self.port}"


def parse_connection(text: str) -> Endpoint:
    """``udpin:HOST:PORT`` and friends -> ``Endpoint``; ``LinkError`` if malformed."""
    parts = text.strip().split(":")
    if len(parts) != 3 or parts[0] not in ("udpin", "udpout", "tcp", "tcpin"):
        raise LinkError(
            f"connection string {text!r}: expected udpin:HOST:PORT, udpout:HOST:PORT, "
            "tcp:HOST:PORT or tcpin:HOST:PORT"
        )
    scheme, host, port_text = parts
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535 or (port == 0 and scheme in ("udpout", "tcp")) or not host:
        raise LinkError(f"connection string {text!r}: bad host or port")
    return Endpoint(scheme, host, port)  # type: ignore[arg-type]


class LatencyRing:
    """The last ``size`` setpoint latencies [s]: from the arrival of the
    telemetry a setpoint answers (``Link.rx_time_s`` when its datagram came
    in, ``time.monotonic`` clock) to that setpoint's write to the socket.
    Fixed memory, one store per setpoint; ``count`` and ``max_s`` cover
    every sample since the start, the percentiles the last ``size``. The
    samples are raw doubles (``array``): nothing the cyclic garbage collector
    traverses (a list of 125,000 floats cost a collection about 1 ms)."""

    def __init__(self, size: int = 16384) -> None:
        self._buf = array("d", bytes(8 * size))
        self._i = 0
        self.count = 0
        self.max_s = 0.0

    def add(self, latency_s: float) -> None:
        self._buf[self._i] = latency_s
        self._i = (self._i + 1) % len(self._buf)
        self.count += 1
        if latency_s > self.max_s:
            self.max_s = latency_s

    def add_since(self, now_s: float, since_s: Sequence[float | None]) -> None:
        """``add(now_s - t0)`` for each ``t0`` of ``since_s`` that is not None,
        in order (one datagram's setpoints, written at ``now_s``)."""
        lat = [now_s - t0 for t0 in since_s if t0 is not None]
        if not lat:
            return
        buf, i, size = self._buf, self._i, len(self._buf)
        if len(lat) >= size:  # more than the ring holds: one at a time
            for x in lat:
                self.add(x)
            return
        end = i + len(lat)
        if end <= size:
            buf[i:end] = array("d", lat)
        else:
            buf[i:] = array("d", lat[: size - i])
            buf[: end - size] = array("d", lat[size - i :])
        self._i = end % size
        self.count += len(lat)
        peak = max(lat)
        if peak > self.max_s:
            self.max_s = peak

    def samples(self) -> list[float]:
        """The retained samples [s], oldest first."""
        if self.count < len(self._buf):
            return self._buf[: self.count].tolist()
        return (self._buf[self._i :] + self._buf[: self._i]).tolist()

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile (0..100, nearest rank) of the retained samples [s]."""
        data = sorted(self.samples())
        if not data:
            return float("nan")
        rank = min(len(data) - 1, max(0, round(q / 100.0 * len(data) + 0.5) - 1))
        return data[rank]
