"""Lockstep speed with the real station in the loop.

Run from the repository root: ``python benchmarks/bench_lockstep.py`` (about
30 s; ``--runs``).

Example 1 (``config/missions/example1_octahedron.yaml``, N = 6, 50 Hz) with
the emulator in lockstep (``clock: lockstep``: step k+1 waits for every
vehicle's answer to step k's telemetry) in a child process pinned to core 0,
and the station here on core 1, vehicles spawned airborne. Reported: control
steps per wall second over a window of the flight (= emulator steps, one
setpoint per telemetry), as a multiple of real time (50 steps/s), and the
emulator's lockstep timeouts (0 = every step was answered). The emulator
alone with a minimal stand-in for the station is ``bench_emulator.py``.

``--product`` times ``gcs-swarm run``'s own path instead: ``run_mission`` on
Example 1 as shipped (the bundled emulator in the station's process and event
loop, each vehicle on its own UDP endpoint, as SITL instances are) and the
same with ``emulator.shared: true`` (one endpoint for all six), alternated, on
one core; reported is the formation's speed, from the station's "formation
started" log line to its "reached the duration" (150 s of mission time).

``--same-core`` pins the emulator to the station's core as well. The loop is
sequential (emulator step, reports, station step, setpoints), so a second
core buys it nothing, while every datagram then has to wake the other side
on another core: on a KVM guest that wake-up costs more than the work
(benchmarks/README.md, "Lockstep speed"). One core is also what ``gcs-swarm
run`` does with sim vehicles (the emulator in the station's own process).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import pin

ROOT = Path(__file__).resolve().parents[1]
MISSION = ROOT / "config" / "missions" / "example1_octahedron.yaml"
RATE_HZ = 50.0


def _mission():  # type: ignore[no-untyped-def]
    from gcs_swarm.mission import load_mission

    m = load_mission(MISSION)
    return replace(m, settings=replace(m.settings, duration=1e6))


async def emulator_main(core: int) -> None:
    from gcs_swarm.runtime.run import emulator_config
    from sim_vehicle import Emulator

    pin(core)
    cfg = replace(emulator_config(_mission(), airborne=True), clock="lockstep", shared_port=0)
    async with Emulator(cfg) as emu:
        print(emu.endpoints[1][1], flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)
        print(emu.stats.lockstep_timeouts, flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


async def one_run(seconds: float, emulator_core: int = 0) -> dict[str, float]:
    import logging

    from gcs_swarm.runtime.run import station_config
    from gcs_swarm.runtime.station import Station

    logging.getLogger("gcs_swarm").setLevel(logging.WARNING)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, __file__, "--emulator", "--emulator-core", str(emulator_core),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stdin is not None
    port = int(await proc.stdout.readline())
    mission = _mission()
    links = {v.sysid: f"udpout:127.0.0.1:{port}" for v in mission.vehicles}
    async with Station(station_config(mission, links, lockstep=True)) as st:
        await st.ready()
        fly = asyncio.create_task(st.fly())
        await asyncio.sleep(1.0)
        s0, w0, c0 = st.control.steps, time.monotonic(), time.process_time()
        await asyncio.sleep(seconds)
        s1, w1, c1 = st.control.steps, time.monotonic(), time.process_time()
        proc.stdin.write(b"stop\n")
        timeouts = int(await proc.stdout.readline())
        fly.cancel()
        await st.end()
    proc.stdin.close()
    await proc.wait()
    rate = (s1 - s0) / (w1 - w0)
    return {
        "steps_per_s": rate,
        "speedup": rate / RATE_HZ,
        "station_cpu": (c1 - c0) / (w1 - w0),
        "timeouts": timeouts,
    }


class _Marks(logging.Handler):
    """The wall times of the station's "formation started" and "reached the
    duration" lines."""

    def __init__(self) -> None:
        super().__init__()
        self.marks: dict[str, float] = {}

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        for key, words in (("start", "formation started"), ("end", "reached the duration")):
            if words in text:
                self.marks[key] = time.monotonic()


def product_run(shared: bool) -> float:
    """``run_mission`` on Example 1 (``shared``: its sim vehicles on one
    endpoint); the formation's speed as a multiple of real time."""
    from gcs_swarm.mission import load_mission
    from gcs_swarm.runtime import run_mission

    m = load_mission(MISSION)  # its own duration, not _mission()'s endless one
    m = replace(m, emulator=replace(m.emulator, shared=shared))
    marks = _Marks()
    log = logging.getLogger("gcs_swarm")
    level, propagate = log.level, log.propagate
    log.addHandler(marks)
    log.setLevel(logging.INFO)
    log.propagate = False
    try:
        summary = asyncio.run(run_mission(m, log_dir=None))
    finally:
        log.removeHandler(marks)
        log.setLevel(level)
        log.propagate = propagate
    return summary.mission_time_s / (marks.marks["end"] - marks.marks["start"])


def product(runs: int) -> None:
    where = pin(1)
    print(f"gcs-swarm run's path, Example 1 (N = 6, lockstep), one process on {where}")
    got: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(runs):
        for shared in (False, True):
            got[shared].append(product_run(shared))
    for shared, xs in got.items():
        name = "emulator.shared: true" if shared else "as shipped (an endpoint per vehicle)"
        print(f"{name}: median {statistics.median(xs):.1f}x real time "
              f"(runs {', '.join(f'{x:.1f}' for x in xs)}; target 50x)")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--emulator", action="store_true")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--same-core", action="store_true", help="the emulator on the station's core")
    ap.add_argument("--product", action="store_true", help="time gcs-swarm run's own path")
    ap.add_argument("--emulator-core", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.emulator:
        asyncio.run(emulator_main(args.emulator_core))
        return
    if args.product:
        product(args.runs)
        return
    where = pin(1)
    emu_core = 1 if args.same_core else 0
    print(f"lockstep, Example 1 (N = 6, 50 Hz), station on {where}, emulator on core {emu_core}")
    rows = []
    for i in range(args.runs):
        r = asyncio.run(one_run(args.seconds, emu_core))
        rows.append(r)
        print(f"run {i + 1}: {r['steps_per_s']:.0f} steps/s = {r['speedup']:.1f}x real time, "
              f"station cpu {r['station_cpu']:.2f}, {r['timeouts']:.0f} timeouts",
              flush=True)  # fmt: skip
    med = statistics.median(r["steps_per_s"] for r in rows)
    lo, hi = min(r["steps_per_s"] for r in rows), max(r["steps_per_s"] for r in rows)
    print(f"median of {len(rows)}: {med:.0f} steps/s = {med / RATE_HZ:.1f}x real time "
          f"(range {lo:.0f}..{hi:.0f}; target 50x = 2500 steps/s)")  # fmt: skip


if __name__ == "__main__":
    main()
