"""The .tlog writer and reader: standard format (8-byte big-endian us, raw
frame), read back by pymavlink's own log reader; bounded buffer, drops
counted, async flushing off the event loop, damaged bytes skipped."""

from __future__ import annotations

import asyncio
import struct
from collections import Counter
from pathlib import Path

import pytest

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import Codec, MessageSpec
from gcs_swarm.report.tlog import TlogStats, frame_header, read_tlog
from gcs_swarm.runtime.tlog import TlogWriter

T0_US = 1_700_000_000_000_000  # 2023-11-14, microseconds since the Unix epoch


def _lpn(t_ms: int) -> MessageSpec:
    return MessageSpec(
        "LOCAL_POSITION_NED",
        {"time_boot_ms": t_ms, "x": 1.5, "y": -2.0, "z": -10.0, "vx": 0.1, "vy": 0.2, "vz": 0.0},
    )


def _traffic(n: int) -> list[tuple[int, bytes, str]]:
    """n rounds of: telemetry from vehicles 1 and 2, a setpoint to each, a
    station heartbeat every 10th round; (t_us, frame, direction)."""
    station, v1, v2 = Codec(), Codec(sysid=1, compid=1), Codec(sysid=2, compid=1)
    out = []
    for k in range(n):
        t = T0_US + k * 20_000
        out.append((t, v1.encode(_lpn(20 * k)), "in"))
        out.append((t + 1, v2.encode(_lpn(20 * k)), "in"))
        out.append((t + 2, station.encode(b.accel_setpoint(1, 1, k, (0.1, 0.2, -0.3))), "out"))
        out.append((t + 3, station.encode(b.accel_setpoint(2, 1, k, (0.0, 0.0, 0.0))), "out"))
        if k % 10 == 0:
            out.append((t + 4, station.encode(b.heartbeat()), "out"))
    return out


def test_round_trip_through_pymavlink(tmp_path: Path) -> None:
    from pymavlink import mavutil

    path = tmp_path / "flight.tlog"
    frames = _traffic(100)
    with TlogWriter(path, flush_bytes=4096) as w:
        for t, frame, _ in frames:
            assert w.write(frame, t_us=t)
    # Our reader: every record, in order, with its time and direction.
    got = list(read_tlog(path))
    assert [(r.t_us, r.frame, r.direction) for r in got] == frames
    # The file is exactly the standard layout: 8-byte big-endian us, then the frame.
    raw = path.read_bytes()
    assert struct.unpack(">Q", raw[:8])[0] == T0_US and raw[8:9] == b"\xfd"
    assert len(raw) == sum(8 + len(f) for _, f, _ in frames)
    # pymavlink's own log reader (mavutil on a .tlog) gets every frame back.
    conn = mavutil.mavlink_connection(str(path))
    seen: Counter[tuple[int, str]] = Counter()
    stamps = []
    while (msg := conn.recv_match()) is not None:
        seen[(msg.get_srcSystem(), msg.get_type())] += 1
        stamps.append(round(msg._timestamp * 1e6))
    conn.close()
    assert seen == {
        (1, "LOCAL_POSITION_NED"): 100,
        (2, "LOCAL_POSITION_NED"): 100,
        (255, "SET_POSITION_TARGET_LOCAL_NED"): 200,
        (255, "HEARTBEAT"): 10,
    }
    # Timestamps survive to the microsecond (float seconds: within 1 us).
    assert all(abs(a - t) <= 1 for a, (t, _, _) in zip(stamps, frames, strict=True))


def test_bounded_buffer_counts_drops_and_keeps_what_fit(tmp_path: Path) -> None:
    frame = Codec().encode(b.heartbeat())
    size = 8 + len(frame)
    w = TlogWriter(tmp_path / "a.tlog", flush_bytes=3 * size, max_buffer_bytes=3 * size)
    assert not w.write(frame)  # not opened: dropped and counted
    assert w.stats.dropped_frames == 1

    # Async: the flusher never runs while we write without yielding, so the
    # bounded buffer fills and the 4th and 5th frames are dropped, not blocked on.
    async def main() -> None:
        async with w:
            results = [w.write(frame, t_us=T0_US + k) for k in range(5)]
            assert results == [True, True, True, False, False]
            await w.flush()  # a worker thread writes the full buffer
            assert w.pending_bytes == 0
            assert w.write(frame, t_us=T0_US + 9)

    asyncio.run(main())
    assert w.stats.dropped_frames == 3 and w.stats.frames == 4
    assert [r.t_us - T0_US for r in read_tlog(w.path)] == [0, 1, 2, 9]
    assert not w.write(frame)  # closed


def test_async_writer_flushes_on_time_and_on_close(tmp_path: Path) -> None:
    path = tmp_path / "b.tlog"
    frame = Codec().encode(b.heartbeat())

    async def main() -> None:
        async with TlogWriter(path, flush_interval_s=0.01) as w:
            w.write(frame, t_us=T0_US)
            # The periodic flush puts it on disk while the run goes on.
            async with asyncio.timeout(5):
                await w.next_flush()
            assert path.stat().st_size == 8 + len(frame)
            for k in range(1, 50):
                w.write(frame, t_us=T0_US + k)

    asyncio.run(main())  # close writes the rest
    assert len(list(read_tlog(path))) == 50


def test_cancelled_run_still_leaves_a_complete_log(tmp_path: Path) -> None:
    path = tmp_path / "c.tlog"
    frame = Codec().encode(b.heartbeat())

    async def body() -> None:
        async with TlogWriter(path, flush_interval_s=10.0) as w:
            for k in range(20):
                w.write(frame, t_us=T0_US + k)
            await asyncio.Event().wait()  # cancelled here

    async def main() -> None:
        task = asyncio.create_task(body())
        await asyncio.sleep(0.01)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(main())
    assert len(list(read_tlog(path))) == 20


def test_reader_skips_damage_and_a_truncated_tail(tmp_path: Path) -> None:
    frames = _traffic(5)
    blob = bytearray()
    for k, (t, f, _) in enumerate(frames):
        blob += struct.pack(">Q", t) + f
        if k == 3:
            blob += b"\x00garbage\x17"  # 9 bytes of junk between records
    blob += struct.pack(">Q", T0_US) + frames[0][1][:7]  # a record cut short
    path = tmp_path / "d.tlog"
    path.write_bytes(bytes(blob))
    stats = TlogStats()
    got = list(read_tlog(path, stats))
    assert [r.frame for r in got] == [f for _, f, _ in frames]
    assert stats.truncated and stats.records == len(frames)
    assert stats.skipped_bytes == 9 + 8 + 7


def test_frame_header_of_v1_and_signed_v2() -> None:
    v2 = Codec(sysid=7, compid=1).encode(_lpn(0))
    h = frame_header(v2)
    assert h is not None and (h.version, h.sysid, h.msgid, h.length) == (2, 7, 32, len(v2))
    assert h.direction == "in"
    v1 = bytes([0xFE, 9, 5, 255, 190, 0]) + bytes(9) + b"\x00\x00"  # HEARTBEAT, MAVLink 1
    h1 = frame_header(v1)
    assert h1 is not None and (h1.version, h1.seq, h1.sysid, h1.length) == (1, 5, 255, 17)
    assert h1.direction == "out"
    signed = bytes([0xFD, 9, 0x01, 0, 0, 255, 155, 250, 0, 0])
    h2 = frame_header(signed)
    assert h2 is not None and h2.length == 12 + 9 + 13 and h2.direction == "note"
    assert frame_header(b"\x00" * 12) is None and frame_header(b"\xfd\x01") is None
