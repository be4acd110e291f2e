"""A network's shared endpoint over real UDP on 127.0.0.1, in lockstep:
the station takes what it reads of it many datagrams at a time
(``LinkState.receive_batch``) and flies exactly the flight it flies taking
every datagram one by one (``runtime.links.BATCH_BYTES`` out of reach):
the same positions bit for bit, the same steps, the same counters. The
in-process twin (tests/swarm/test_receive_batch.py) checks the state after
every batch of hostile traffic; this one the link's real socket path."""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from gcs_swarm.mavlink.codec import STATION_SYSID
from gcs_swarm.mission import parse_mission
from gcs_swarm.runtime import RunSummary, run_mission
from gcs_swarm.runtime import links as links_module

N = 40
DURATION_S = 4.0


def _mission(leave: int | None = None) -> str:
    side = math.ceil(N ** (1 / 3))
    lines = [
        f"mission: {{name: batch-udp, duration: {DURATION_S}, rate: 50, end: hold}}",
        "emulator: {dynamics: ideal, mode: lockstep, spawn: air, shared: true}",
        "gains: {M: 1, D: 1, k: 9, k_s: 1, k_r: 0.2, alpha: 2, q: 10}",
        "leader: {start: [0, 0, 0], force: [0, 0, 0]}",
        "vehicles:",
    ]
    for i in range(N):
        x, y, z = i % side, (i // side) % side, i // (side * side)
        start = f"[{3 * x - 4.5}, {3 * y - 4.5}, {3 * z - 4.5}]"
        lines.append(f"  - {{sysid: {i + 1}, start: {start}}}")
    if leave is not None:
        lines.append(f"events: [{{t: 1.0, leave: {leave}}}]")
    return "\n".join(lines) + "\n"


def _fly(log_dir: Path, leave: int | None = None) -> tuple[RunSummary, Any, int]:
    """The run's summary, its one link's counters and the station's
    HEARTBEATs in its tlog (under ``log_dir``)."""
    stations: list[Any] = []
    folders: list[Path] = []

    @contextlib.asynccontextmanager
    async def keep(station: Any, request: Any, recorder: Any) -> AsyncIterator[None]:
        stations.append(station)  # the operator-view hook: the running station
        yield

    async def main() -> RunSummary:
        async with asyncio.timeout(120):
            return await run_mission(parse_mission(_mission(leave)), picture=False,
                                     end_timeout_s=5.0, view=keep, log_dir=log_dir,
                                     on_folder=lambda f: folders.append(f.path))  # fmt: skip

    summary = asyncio.run(main())
    (link,) = stations[0].links.values()
    log = mavutil.mavlink_connection(str(folders[0] / "flight.tlog"))
    beats = 0
    try:
        while (m := log.recv_match(type="HEARTBEAT")) is not None:
            beats += m.get_srcSystem() == STATION_SYSID
    finally:
        log.close()
    return summary, link.stats, beats


@pytest.mark.parametrize(("leave", "share"), [(None, 0.5), (17, 0.25)], ids=["all", "one-leaves"])
def test_batches_of_a_shared_endpoint_fly_the_flight_of_one_datagram_at_a_time(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, leave: int | None, share: float
) -> None:
    """With ``leave``, that vehicle leaves 1 s into the formation and goes on
    reporting: its datagram of each period goes one by one, the others'
    still in batches (``LinkState.receive_batches``)."""
    batched, stats, beats = _fly(tmp_path / "batched", leave)
    monkeypatch.setattr(links_module, "BATCH_BYTES", 1 << 40)
    single, single_stats, single_beats = _fly(tmp_path / "single", leave)
    assert batched.outcome == single.outcome == "completed"
    # Most of the flight's frames went in batches (measured: 75 %; the start-up's answers
    # and each vehicle's first messages in flight go one by one), none
    # without them. With vehicle 17 gone from 1 s: 34 % (16.6 % before its
    # datagram went alone and the batch on after it, 2026-12-07).
    assert stats.frames_batched > share * stats.received, (stats.frames_batched, stats.received)
    assert single_stats.frames_batched == 0
    assert batched.steps == single.steps > 0.9 * 50 * DURATION_S
    assert [v.position_m for v in batched.vehicles] == [v.position_m for v in single.vehicles]
    assert batched.min_separation_m == single.min_separation_m
    assert batched.mission_time_s == single.mission_time_s
    for name in ("bad_packets", "setpoints_dropped", "spoofed"):
        assert getattr(stats, name) == getattr(single_stats, name), name
    # What the station sent, but its own HEARTBEATs: those go at 1 Hz of the
    # wall clock, not of the lockstep flight, so a flight that takes longer
    # on a loaded machine sends one more (measured: 10,322 against 10,321
    # under two test workers and a busy loop on two cores, 2026-12-07).
    assert beats > 0 and single_beats > 0  # the tlog was read
    assert stats.sent - beats == single_stats.sent - single_beats, (beats, single_beats)
    # ``received`` also counts what comes while the run ends: the lockstep
    # emulator may send one more round of reports (one per vehicle) after
    # the mission's last step, and whether the station reads it before its
    # link closes is a race with the ending, in either mode (measured: 4 of
    # 30 flights batched and 2 of 30 one datagram at a time got it; their
    # tlogs differ from the others' by those 40 LOCAL_POSITION_NED alone, at
    # time_boot_ms 5,040 after the last step's 5,020; CI failed once on it).
    # The flights' own reports are the same.
    assert stats.received - single_stats.received in (-N, 0, N), "received"
