"""A real station run against the real emulator, every frame logged to a
``.tlog`` by a tap on the links: pymavlink's own log reader reads back every
setpoint and telemetry message, and ``report`` rebuilds the run from the
log and the mission file alone (no station annotations in this log)."""

from __future__ import annotations

import asyncio
import dataclasses
from collections import Counter
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from report_tap import Tap, TapCounts

from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.report import report_from_tlog
from gcs_swarm.report.tlog import read_tlog
from gcs_swarm.runtime import RunSummary, emulator_config, run_mission
from gcs_swarm.runtime.tlog import TlogWriter
from sim_vehicle import Emulator

MISSIONS = Path(__file__).resolve().parents[2] / "config" / "missions"
FLY_S = 4.0  # s of formation flight: enough for ~200 steps, a couple of seconds of wall time


def _mission() -> Mission:
    m = load_mission(MISSIONS / "example1_tetrahedron.yaml")
    return dataclasses.replace(m, settings=dataclasses.replace(m.settings, duration=FLY_S))


@dataclasses.dataclass(frozen=True)
class Logged:
    summary: RunSummary
    tlog: Path
    counts: TapCounts
    lockstep_timeouts: int


async def _fly(tlog_path: Path) -> Logged:
    mission = _mission()
    cfg = dataclasses.replace(emulator_config(mission, airborne=True), clock="lockstep",
                              dynamics="ideal", accel_tau_s=None, speedup=20.0)  # fmt: skip
    counts = TapCounts()
    async with asyncio.timeout(60), Emulator(cfg) as emu, TlogWriter(tlog_path) as tlog:
        taps = {s: Tap(addr, tlog, counts) for s, addr in emu.endpoints.items()}
        links = {}
        for sysid, tap in taps.items():
            host, port = await tap.open()
            links[sysid] = f"udpout:{host}:{port}"
        try:
            summary = await run_mission(mission, links=links, lockstep=True, end_timeout_s=5.0)
        finally:
            for tap in taps.values():
                tap.close()
        timeouts = emu.stats.lockstep_timeouts
    return Logged(summary, tlog_path, counts, timeouts)


@cache
def _logged(tmp: str) -> Logged:
    return asyncio.run(_fly(Path(tmp) / "flight.tlog"))


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> Logged:
    return _logged(str(tmp_path_factory.mktemp("run")))


def test_pymavlink_reads_back_every_frame(logged: Logged) -> None:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(logged.tlog))
    seen: Counter[tuple[str, str]] = Counter()
    stamps = []
    while (msg := conn.recv_match()) is not None:
        if msg.get_type() == "BAD_DATA":
            continue
        way = "out" if msg.get_srcSystem() == 255 else "in"
        seen[(way, msg.get_type())] += 1
        stamps.append(msg._timestamp)
    conn.close()
    by_name = Counter()
    for (way, msgid), n in logged.counts.by_msgid.items():
        by_name[(way, mavutil.mavlink.mavlink_map[msgid].msgname)] += n
    # Every frame the tap saw, by direction and type, and nothing else.
    assert seen == by_name
    # The station's own counter: every frame it sent is in the log.
    assert sum(n for (way, _), n in seen.items() if way == "out") == logged.summary.messages_sent
    assert seen[("out", "SET_POSITION_TARGET_LOCAL_NED")] >= FLY_S * 50 * 4  # 4 vehicles, 50 Hz
    assert seen[("in", "LOCAL_POSITION_NED")] >= FLY_S * 50 * 4
    assert stamps == sorted(stamps)  # timestamps in order, as written
    # Our raw reader agrees with pymavlink's record for record.
    assert sum(1 for _ in read_tlog(logged.tlog)) == sum(seen.values())


def test_report_from_the_log_reproduces_the_run(logged: Logged) -> None:
    assert logged.lockstep_timeouts == 0
    summary, rec = report_from_tlog(logged.tlog, _mission())
    live = logged.summary
    assert summary["log"]["station_annotations"] is False
    # Mission time: the replayed clock is the station's (same telemetry times).
    assert rec.times_s[-1] == pytest.approx(live.mission_time_s, abs=1e-9)
    # Final positions: the same LOCAL_POSITION_NED and origins, same arithmetic.
    final = {int(s): rec.pos_m[-1, j] for j, s in enumerate(rec.ids)
             if not np.isnan(rec.pos_m[-1, j, 0])}  # fmt: skip
    for sysid, p in live.positions().items():
        np.testing.assert_allclose(final[sysid], p, atol=1e-12)
    # The leader re-run with the mission's law in vehicle time: float32 storage.
    np.testing.assert_allclose(rec.leader_pos_m[-1], live.leader_pos_m, atol=1e-5)
    o = summary["overall"]
    assert o["min_separation_m"] == pytest.approx(live.min_separation_m, rel=1e-9)
    assert o["vehicles_final"] == [1, 2, 3, 4]
    # 50 Hz of vehicle time for every vehicle; one setpoint per telemetry.
    assert o["setpoints"]["rate_hz_min"] == pytest.approx(50.0, rel=1e-3)
    assert o["setpoints"]["largest_gap_s"] == pytest.approx(0.02, abs=1e-6)
    assert o["telemetry"]["lost"] == 0 and o["telemetry"]["received"] > 0
