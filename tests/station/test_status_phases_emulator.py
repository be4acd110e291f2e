"""The status streams of one network's vehicles spread over their interval,
against the real emulator in real time over UDP on 127.0.0.1 (the unit
tests: tests/mavlink/test_vehicle_status_phases.py).

An autopilot sends the streams of one interval together, on the phase its
first ask set (ArduPilot's buckets, which the emulator keeps: docs/emulator.md,
"Streams asked for"). The station asks each vehicle's at ``k / n`` of the
interval after its start-up began (``StationConfig.status_phases``), so the
eight vehicles here send their EKF_STATUS_REPORT at eight phases 62.5 ms
apart, where asking all at once would put them in one 20 ms step.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from gcs_swarm.mission import parse_mission
from gcs_swarm.runtime import run_mission

N = 8
INTERVAL_S = 0.5  # the status streams at 2 Hz (ProtocolConfig.status_rate_hz)
STEP_S = 0.02  # the emulator's step at 50 Hz: a bucket goes at the first step due

_MISSION = (
    "mission: {name: status-phases, duration: 3, rate: 50, end: hold}\n"
    "emulator: {dynamics: ideal, mode: realtime, spawn: air}\n"
    "leader: {start: [0, 0, 0], force: [0, 0, 0]}\n"
    "networks:\n  - name: net\n    vehicles:\n"
    + "".join(f"      - {{sysid: {i + 1}, start: [{3 * i}, 0, 0]}}\n" for i in range(N))
)


def _phases(tlog: Path) -> dict[int, float]:
    """Each vehicle's EKF_STATUS_REPORT phase [s] in the 0.5 s interval: the
    circular mean of its arrival times (the log's stamps) modulo the interval."""
    log = mavutil.mavlink_connection(str(tlog))
    stamps: dict[int, list[float]] = {}
    while (msg := log.recv_match(type="EKF_STATUS_REPORT")) is not None:
        stamps.setdefault(msg.get_srcSystem(), []).append(msg._timestamp)
    log.close()
    out = {}
    for sysid, ts in stamps.items():
        assert len(ts) >= 4, (sysid, len(ts))
        angle = np.angle(np.mean(np.exp(2j * np.pi * np.asarray(ts) / INTERVAL_S)))
        out[sysid] = float(angle % (2 * np.pi)) / (2 * np.pi) * INTERVAL_S
    return out


def test_one_networks_status_streams_come_at_phases_spread_over_their_interval(
    tmp_path: Path,
) -> None:
    async def fly() -> None:
        async with asyncio.timeout(90):
            summary = await run_mission(parse_mission(_MISSION), log_dir=tmp_path,
                                        picture=False, end_timeout_s=5.0)  # fmt: skip
        assert summary.outcome == "completed", summary.outcome

    asyncio.run(fly())
    (tlog,) = tmp_path.glob("*/flight-net.tlog")
    phases = _phases(tlog)
    assert sorted(phases) == list(range(1, N + 1))
    ordered = np.sort(np.asarray(list(phases.values())))
    gaps = np.diff(np.append(ordered, ordered[0] + INTERVAL_S))
    # Ideal: eight gaps of 62.5 ms, moved by the emulator's 20 ms steps and the
    # start-ups' own timing. All asked at once, one gap would be about 500 ms
    # and the others under one step. Bounds: no gap over 200 ms (a vehicle
    # would have to be 140 ms off its phase), and at most two vehicles within
    # one step of each other (three would need shifts of 60 ms or more).
    assert gaps.max() < 0.2, np.round(gaps, 3)
    close = np.abs(ordered[:, None] - ordered[None, :])
    close = np.minimum(close, INTERVAL_S - close) < STEP_S - 1e-9
    assert (close.sum(axis=1) - 1).max() <= 1, np.round(ordered, 3)
