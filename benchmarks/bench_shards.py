"""Link shards over Zenoh (issue 19 item 2): Example 1's six vehicles as two
networks (``blue`` 1-3, ``red`` 1-3) flown in lockstep by one station
process and by ``--shards 2`` (two shard processes, the controller here),
the wall time of each, whether the radii agree, and the bytes that crossed
Zenoh per vehicle per step.

    .venv/bin/python benchmarks/bench_shards.py [--duration 20] [--runs 3]

``--realtime N`` measures capacity instead (issue 19 item 4): N airborne
vehicles as ``--networks K`` networks of N/K (bench_station's swarm), their emulators in
bench_station's child process (pinned to core 0, one emulator per network
on a shared port each, real time), flown by ``run_sharded`` with
each of ``--shards 1,2,4`` link shard processes (the controller in this
process; shards and controller not pinned) for ``--seconds`` of formation
at ``--rate`` Hz. Reported per shard count: controller steps per second
and those taken on the fallback (a shard late), then what each shard
measured over the formation's last 10 s (``runtime.shard.FlightEnd``: the
default 12 s of formation less its first 2): setpoints per vehicle per
second (the rate when every report is answered), the setpoint latency
(telemetry arrival to setpoint write: p50 the median of the shards', p99
and max the largest), the setpoints and the missed vehicle-cycles (reports
taken less setpoints written, bench_station's count), summed. Each network's emulator
keeps its own clock, so their reports arrive at different phases of the
period, as with unsynchronised real vehicles; with ``--step swarm`` a step
waits for every network's (or a period), so the latency includes that
wait; with ``--step network`` (as bench_station's) the controller steps
each shard's batch as it comes, a step per network and period. The
mission options ``--cutoff``, ``--settle``, ``--spread``, ``--phases`` are
bench_station's. "in shm": the share of the samples the controller received
(state batches, beats, reports) that came in Zenoh's shared memory; a
shard's batch does from 51 vehicles on (``gcs_swarm.runtime.zbus``).
``--no-shm`` turns shared memory off for comparison. "emu cpu", "emu
late": the emulator child's CPU [cores] and its steps more than a period
late over the shards' window (bench_station's window protocol).

    .venv/bin/python benchmarks/bench_shards.py --realtime 500 --networks 4 --shards 1,2,4 \
        --step network

Not part of the tests; wall-clock figures move with the machine's load.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import bench_station

from gcs_swarm.errors import StartupError
from gcs_swarm.mission import Mission, parse_mission
from gcs_swarm.runtime import RunSummary, run_mission
from gcs_swarm.runtime.sched import short_slice
from gcs_swarm.runtime.shard import WINDOW_S
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


def _rt_mission(n: int, nets: int, rate: float, duration: float) -> Mission:
    """N vehicles on bench_station's 3 m grid (or its settled sphere, ``--cutoff``)
    as ``nets`` networks of N/nets."""
    bench_station.RATE_HZ, bench_station.GROUP = rate, math.ceil(n / nets)
    return parse_mission(bench_station.mission_yaml(n, networks=True, duration=duration))


def _station_options(args: argparse.Namespace) -> str:
    """bench_station's swarm options from ``args`` (its mission's and its
    emulator child's: ``bench_station.emulator_child``); what they are."""
    st = bench_station
    st.STEP, st.CUTOFF, st.SETTLE_S = args.step, args.cutoff, args.settle
    st.SPREAD, st.PHASES, st.HEARTBEATS = args.spread, args.phases, args.heartbeats
    st.EMULATORS, st.OVERRUN, st.HANDSHAKES = args.emulators, args.overrun, args.handshakes
    st.READY_TIMEOUT_S = rt = args.ready_timeout
    return (f"step {args.step}, cut-off {args.cutoff}, settle {args.settle:g} s, "
            f"spread {args.spread}, phases {args.phases}, heartbeats {args.heartbeats}, "
            f"overrun {args.overrun}, emulator processes {args.emulators}, "
            f"handshakes per network {args.handshakes}, ready timeout "
            f"{'90 (default)' if rt is None else f'{rt:g}'} s")  # fmt: skip


async def _realtime(
    n: int, nets: int, shards: int, rate: float, seconds: float, shm: bool = True
) -> dict[str, float]:
    import logging

    logging.getLogger("gcs_swarm").setLevel(logging.ERROR)
    mission = _rt_mission(n, nets, rate, seconds)  # sets bench_station's rate and group
    emulators, ports = await bench_station.EmulatorChildren.start(n, networks=True)
    try:
        links = {v.key: f"udpout:127.0.0.1:{ports[v.net_index]}" for v in mission.vehicles}
        runs: list[ShardedRun] = []
        watch = asyncio.create_task(_emulator_window(emulators, runs, seconds))
        summary = await run_sharded(mission, shards, links=links, lockstep=False, shm=shm,
                                    end_timeout_s=10.0, on_run=runs.append)  # fmt: skip
        emu = await watch if watch.done() else {}
        watch.cancel()
    finally:
        await emulators.close()
    run = runs[0]
    flight = (run.flight_s[1] - run.flight_s[0]) if run.flight_s is not None else math.nan
    ends = [d["flight_end"] for d in run.done.values()]
    nan = math.nan
    return {
        "outcome_ok": float(summary.outcome == "completed"),
        "steps_per_s": summary.steps / flight,
        "answers_hz": sum(e["setpoints"] or nan for e in ends) / n / WINDOW_S,
        "fallbacks": float(run.core.fallbacks),
        "p50_ms": statistics.median(e["p50_ms"] for e in ends) if ends else nan,
        "p99_ms": max((e["p99_ms"] for e in ends), default=nan),
        "max_ms": max((e["max_ms"] for e in ends), default=nan),
        "setpoints": sum(e["setpoints"] or nan for e in ends),
        "missed": sum(e["missed"] if e["missed"] is not None else nan for e in ends),
        "shm_share": run.bus.shm_in / max(run.bus.samples_in, 1),
        "state_kb": run.bytes_per_step["state"] / max(run.bytes_per_step["batches"], 1) / 1e3,
        "emu_cpu": emu.get("cpu", nan),
        "emu_late": emu.get("late_steps", nan),
    }


async def _emulator_window(
    emulators: bench_station.EmulatorChildren, runs: list[ShardedRun], seconds: float
) -> dict[str, float]:
    """The emulator children's CPU [cores] and late steps over the shards'
    window (``FlightEnd``: the formation's last ``WINDOW_S``, or all of it),
    by bench_station's protocol: a line on their stdin opens the window, the
    next closes it, and each answers ``late_steps=.. cpu=.. rt=..``."""

    async def until(t_s: float) -> None:  # the controller's mission time, polled
        while True:
            if runs and runs[0].core.control.t_s >= t_s:
                return
            await asyncio.sleep(0.05)

    await until(max(0.0, seconds - WINDOW_S))
    emulators.write(b"\n")
    await emulators.drain()
    await until(seconds - 0.1)
    emulators.write(b"\n")
    await emulators.drain()
    return await emulators.figures()


def realtime_main(args: argparse.Namespace) -> None:
    options = _station_options(args)
    shm = "off (--no-shm)" if args.no_shm else "on"
    # As `gcs-swarm run --shards` (runtime.sched); its shards ask for it themselves.
    sliced = "short slice" if short_slice() else "the kernel's slice"
    print(f"link shards in real time: N = {args.realtime} as {args.networks} networks, "
          f"{args.rate:g} Hz, {args.seconds:g} s of formation; emulators on core 0; "
          f"Zenoh shared memory {shm}; {sliced}; {options}")  # fmt: skip
    print(f"{'shards':>6} {'outcome':>8} {'steps/s':>8} {'fallbk':>6} {'ans/veh/s':>9} "
          f"{'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} {'setpts':>8} {'missed':>6} "
          f"{'in shm':>6} {'kB/batch':>8} {'emu cpu':>7} {'emu late':>8}")  # fmt: skip
    for k in (int(x) for x in args.shards.split(",")):
        try:
            r = asyncio.run(_realtime(args.realtime, args.networks, k, args.rate, args.seconds,
                                      shm=not args.no_shm))  # fmt: skip
        except StartupError as err:  # an overloaded machine: say so, go on with the next count
            print(f"{k:6d} {'startup failed':>15}: {str(err)[:160]}", flush=True)
            continue
        ok = "ok" if r["outcome_ok"] else "degraded"
        print(f"{k:6d} {ok:>8} {r['steps_per_s']:8.1f} {r['fallbacks']:6.0f} "
              f"{r['answers_hz']:9.1f} {r['p50_ms']:7.2f} {r['p99_ms']:7.2f} {r['max_ms']:7.2f} "
              f"{r['setpoints']:8.0f} {r['missed']:6.0f} {100 * r['shm_share']:5.0f}% "
              f"{r['state_kb']:8.1f} {r['emu_cpu']:7.2f} {r['emu_late']:8.0f}",
              flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="mission time [s]")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--realtime", type=int, default=None, metavar="N",
                    help="capacity in real time with N vehicles (module docstring)")  # fmt: skip
    ap.add_argument("--networks", type=int, default=4, help="--realtime: networks (default 4)")
    ap.add_argument("--shards", default="1,2,4", help="--realtime: shard counts (default 1,2,4)")
    ap.add_argument("--rate", type=float, default=50.0, help="--realtime: control rate [Hz]")
    ap.add_argument("--seconds", type=float, default=12.0, help="--realtime: formation [s]")
    ap.add_argument("--no-shm", action="store_true",
                    help="--realtime: every batch as bytes over TCP")  # fmt: skip
    bench_station.mission_options(ap)  # --realtime: the swarm as bench_station's
    args = ap.parse_args()
    if args.realtime is not None:
        realtime_main(args)
        return
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
