"""A UDP tap between the real station and the real emulator that writes
every frame either way into a ``.tlog`` (as a link recorder would): a log
of a run "flown elsewhere", without the station's annotations."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from gcs_swarm.report.tlog import frame_header
from gcs_swarm.runtime.tlog import TlogWriter


def split_frames(data: bytes) -> list[bytes]:
    """The MAVLink frames of one datagram (a trailing partial frame is dropped)."""
    out, pos = [], 0
    while pos < len(data):
        h = frame_header(data, pos)
        if h is None or pos + h.length > len(data):
            break
        out.append(data[pos : pos + h.length])
        pos += h.length
    return out


@dataclass
class TapCounts:
    to_vehicle: int = 0
    to_station: int = 0
    by_msgid: dict[tuple[str, int], int] = field(default_factory=dict)


class _Side(asyncio.DatagramProtocol):
    def __init__(self, on_data: object) -> None:
        self.on_data = on_data
        self.transport: asyncio.DatagramTransport | None = None

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.on_data(data, addr)  # type: ignore[operator]


class Tap:
    """One emulator endpoint behind a local port the station talks to."""

    def __init__(self, vehicle: tuple[str, int], tlog: TlogWriter, counts: TapCounts) -> None:
        self.vehicle, self.tlog, self.counts = vehicle, tlog, counts
        self.station_addr: tuple[str, int] | None = None
        self.front: _Side | None = None
        self.back: _Side | None = None

    async def open(self) -> tuple[str, int]:
        loop = asyncio.get_running_loop()
        transport, self.front = await loop.create_datagram_endpoint(
            lambda: _Side(self._from_station), local_addr=("127.0.0.1", 0)
        )
        self.front.transport = transport
        transport, self.back = await loop.create_datagram_endpoint(
            lambda: _Side(self._from_vehicle), remote_addr=self.vehicle
        )
        self.back.transport = transport
        assert self.front.transport is not None
        host, port = self.front.transport.get_extra_info("sockname")[:2]
        return host, port

    def _log(self, data: bytes, way: str) -> None:
        for frame in split_frames(data):
            self.tlog.write(frame)
            key = (way, frame_header(frame).msgid)  # type: ignore[union-attr]
            self.counts.by_msgid[key] = self.counts.by_msgid.get(key, 0) + 1

    def _from_station(self, data: bytes, addr: tuple[str, int]) -> None:
        self.station_addr = addr
        self._log(data, "out")
        self.counts.to_vehicle += 1
        assert self.back is not None and self.back.transport is not None
        self.back.transport.sendto(data)

    def _from_vehicle(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.station_addr is None:
            return
        self._log(data, "in")
        self.counts.to_station += 1
        assert self.front is not None and self.front.transport is not None
        self.front.transport.sendto(data, self.station_addr)

    def close(self) -> None:
        for side in (self.front, self.back):
            if side is not None and side.transport is not None:
                side.transport.close()
