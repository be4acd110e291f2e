"""The setpoint gap the plane look-ahead causes at an avoidance switch.

Run from the repository root: ``python benchmarks/bench_lookahead.py`` (about
30 s per run; ``--runs`` to repeat).

Scenario 3 (``config/missions/scenario3_obstacle.yaml``: four vehicles meet a
box; ``plane: auto`` starts a look-ahead job when the avoidance episode
starts, run in a worker thread by the station) flown in real time at 50 Hz,
the emulator in a child process pinned to core 0 and the station here on
core 1, vehicles spawned airborne, the mission shortened to 24 s (the episode
starts at about t = 17 s). Every setpoint the station writes is time-stamped
(``on_frame``); reported per run: the largest interval between two
consecutive setpoints to the same vehicle in the 1 s after the episode start,
and over the whole flight, in control periods (target <= 1.5), with the
look-ahead's own duration from the station's log.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import re
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import pin

ROOT = Path(__file__).resolve().parents[1]
MISSION = ROOT / "config" / "missions" / "scenario3_obstacle.yaml"
PERIOD_S = 0.02
SPTLN = 84


def _mission():  # type: ignore[no-untyped-def]
    from gcs_swarm.mission import load_mission

    m = load_mission(MISSION)
    return replace(m, settings=replace(m.settings, duration=24.0))


async def emulator_main() -> None:
    from gcs_swarm.runtime.run import emulator_config
    from sim_vehicle import Emulator

    pin(0)
    cfg = replace(emulator_config(_mission(), airborne=True), shared_port=0)
    async with Emulator(cfg) as emu:
        print(emu.endpoints[1][1], flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


async def one_run() -> dict[str, float]:
    from gcs_swarm.runtime.run import station_config
    from gcs_swarm.runtime.station import Station

    proc = await asyncio.create_subprocess_exec(
        sys.executable, __file__, "--emulator",
        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stdin is not None
    port = int(await proc.stdout.readline())
    mission = _mission()
    writes: dict[int, list[float]] = {}

    def on_frame(data: bytes, direction: str) -> None:
        if direction == "out" and data[0] == 0xFD and data[7] == SPTLN and len(data) > 60:
            writes.setdefault(data[60], []).append(time.monotonic())

    links = {v.sysid: f"udpout:127.0.0.1:{port}" for v in mission.vehicles}
    episode_at = lookahead_ms = float("nan")
    async with Station(station_config(mission, links), on_frame=on_frame) as st:
        await st.ready()
        fly = asyncio.create_task(st.fly())
        while not fly.done():
            await asyncio.sleep(0.005)
            if episode_at != episode_at and any("avoidance episode 1 starts" in x for x in st.log):
                episode_at = time.monotonic()
        await st.end()
        for line in st.log:
            m = re.search(r"look-ahead for episode 1: .*\((\d+) ms in a worker", line)
            if m:
                lookahead_ms = float(m.group(1))
    proc.stdin.close()
    await proc.wait()
    gaps_all, gaps_switch = [], []
    for ts in writes.values():
        # The last setpoint is the end's zero acceleration, after the flight.
        for a, b in itertools.pairwise(ts[:-1]):
            gaps_all.append(b - a)
            if episode_at - 0.1 <= b <= episode_at + 1.0:
                gaps_switch.append(b - a)
    return {
        "switch_max_periods": max(gaps_switch, default=float("nan")) / PERIOD_S,
        "flight_max_periods": max(gaps_all, default=float("nan")) / PERIOD_S,
        "lookahead_ms": lookahead_ms,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--emulator", action="store_true")
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    if args.emulator:
        asyncio.run(emulator_main())
        return
    where = pin(1)
    print(f"look-ahead gap, Scenario 3 in real time, station on {where}, emulator on core 0")
    rows = []
    for i in range(args.runs):
        r = asyncio.run(one_run())
        rows.append(r)
        print(f"run {i + 1}: largest setpoint gap around the switch "
              f"{r['switch_max_periods']:.2f} periods, whole flight "
              f"{r['flight_max_periods']:.2f} periods; look-ahead {r['lookahead_ms']:.0f} ms",
              flush=True)  # fmt: skip
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    print(f"median of {len(rows)}: switch {med['switch_max_periods']:.2f} periods "
          f"(target <= 1.5), flight {med['flight_max_periods']:.2f}, "
          f"look-ahead {med['lookahead_ms']:.0f} ms")  # fmt: skip


if __name__ == "__main__":
    main()
