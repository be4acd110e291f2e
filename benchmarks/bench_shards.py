"""Link shards over Zenoh (issue 19 item 2): Example 1's six vehicles as two
networks (``blue`` 1-3, ``red`` 1-3) flown in lockstep by one station
process and by ``--shards 2`` (two shard processes, the controller here),
the wall time of each, whether the radii agree, and the bytes that crossed
Zenoh per vehicle per step.

    .venv/bin/python benchmarks/bench_shards.py [--duration 20] [--runs 3]

Not part of the tests; wall-clock figures move with the machine's load.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time

import numpy as np

from gcs_swarm.mission import Mission, parse_mission
from gcs_swarm.runtime import RunSummary, run_mission
from gcs_swarm.runtime.sharded import ShardedRun, run_sharded

_STARTS = ["[2, 1, 2]", "[-1, -1, -1]", "[3, 4, 2]", "[4, 2, 2]", "[3, 3, 3]", "[-2, -2, -2]"]


def _mission(duration: float) -> Mission:
    text = (
        f"mission: {{name: bench-shards, duration: {duration}, rate: 50, end: hold}}\n"
        "emulator: {dynamics: ideal, mode: lockstep, spawn: air}\n"
        "leader: {start: [0, 0, 0], force: [0, 0, 0]}\nnetworks:\n"
    )
    for name, starts in (("blue", _STARTS[:3]), ("red", _STARTS[3:])):
        text += f"  - name: {name}\n    vehicles:\n"
        text += "".join(f"      - {{sysid: {i + 1}, start: {s}}}\n" for i, s in enumerate(starts))
    return parse_mission(text)


async def _one(mission: Mission) -> tuple[float, RunSummary]:
    t0 = time.perf_counter()
    summary = await run_mission(mission, log_dir=None, end_timeout_s=5.0)
    return time.perf_counter() - t0, summary


async def _sharded(mission: Mission) -> tuple[float, RunSummary, ShardedRun]:
    runs: list[ShardedRun] = []
    t0 = time.perf_counter()
    summary = await run_sharded(mission, 2, end_timeout_s=5.0, on_run=runs.append)
    return time.perf_counter() - t0, summary, runs[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="mission time [s]")
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    mission = _mission(args.duration)
    walls: dict[str, list[float]] = {"one process": [], "--shards 2": []}
    flights: list[float] = []
    for _ in range(args.runs):
        w1, one = asyncio.run(_one(mission))
        w2, two, run = asyncio.run(_sharded(mission))
        walls["one process"].append(w1)
        walls["--shards 2"].append(w2)
        r1 = np.array([v.radius_m for v in one.vehicles], dtype=float)
        r2 = np.array([v.radius_m for v in two.vehicles], dtype=float)
        diff = float(np.abs(r1 - r2).max())
        b = run.bytes_per_step
        if run.flight_s is not None:
            flights.append(run.flight_s[1] - run.flight_s[0])
        n = len(mission.vehicles)
        steps = max(b["steps"], 1)
        up, down = b["state"] / steps, b["reply"] / steps
        print(f"steps {one.steps} vs {two.steps}; max |radius difference| {diff:.3g} m; "
              f"fallback steps {run.core.fallbacks}; Zenoh per step: states {up:.0f} B "
              f"({up / n:.1f} B/vehicle), replies {down:.0f} B "
              f"({down / n:.1f} B/vehicle)")  # fmt: skip
    for name, w in walls.items():
        print(f"{name}: wall {statistics.median(w):.2f} s median of {len(w)} "
              f"({', '.join(f'{x:.2f}' for x in w)}) for {args.duration:g} s of mission time "
              "(start-up, flight and ending)")  # fmt: skip
    f = statistics.median(flights)
    print(f"--shards 2, formation flight alone: {f:.2f} s median for {args.duration:g} s "
          f"({args.duration * mission.settings.rate / f:.0f} steps/s)")  # fmt: skip


if __name__ == "__main__":
    main()
