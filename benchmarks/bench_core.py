"""The station's CPU per vehicle per 50 Hz cycle without sockets or an event loop.

Run from the repository root: ``python benchmarks/bench_core.py`` (a few
seconds; ``--counts``, ``--cycles``, ``--repeat``). N vehicles are put in
FLYING by hand (READY at their start points, then ``SwarmCore.start``);
each cycle one unsigned datagram-worth of their LOCAL_POSITION_NED goes
through ``LinkState.receive`` (the telemetry table, ``SwarmCore.receive`` for
anything else, ``SwarmCore.telemetry_written``), then ``control_step`` runs
the law and frames the setpoints (``LinkState.accel_setpoints``). Reported:
receive and step+send per vehicle-cycle [us], the median of ``--repeat``
runs of ``--cycles`` cycles after 50 warm-up cycles (process time, one
process: far less noisy than ``bench_station.py`` on a shared machine, and
without its sockets, asyncio and emulator).
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from _common import pin
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs_swarm.mavlink.inbound import LocalPositionNed
from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mission import parse_mission
from gcs_swarm.runtime import station_config
from gcs_swarm.swarm import LinkState, SetpointBatch, SwarmCore

LINK = "udpin:0.0.0.0:14550"
WARM_UP = 50


def _mission(n: int) -> str:
    side = math.ceil(n ** (1 / 3))
    lines = [
        "mission: {name: bench, duration: 14400, rate: 50, end: hold}",
        "gains: {M: 1, D: 1, k: 9, k_s: 1, k_r: 0.2, alpha: 2, q: 10}",
        "leader: {start: [0, 0, 0], force: [0, 0, 0]}",
        "vehicles:",
    ]
    for i in range(n):
        x, y, z = i % side, (i // side) % side, i // (side * side)
        lines.append(f"  - {{sysid: {i + 1}, start: [{3 * x}, {3 * y}, {3 * z + 5}]}}")
    return "\n".join(lines) + "\n"


def run(n: int, cycles: int) -> tuple[float, float]:
    """(receive, step + send) [us per vehicle-cycle] at ``n`` vehicles."""
    m = parse_mission(_mission(n))
    cfg = station_config(m, {v.sysid: LINK for v in m.vehicles})
    core = SwarmCore(cfg)
    link = LinkState(LINK, unix_clock=lambda: 1.7e9, sysids=list(core.vehicles),
                     telemetry=core.table)  # fmt: skip
    starts = {p.sysid: p.start_m for p in cfg.vehicles}
    for s, vp in core.vehicles.items():
        e, north, up = starts[s]
        vp.phase = Phase.READY
        vp.offset_m = np.zeros(3)
        vp.position = LocalPositionNed(s, 1, 1000, float(north), float(e), -float(up), 0, 0, 0)
    core.start(0.0)
    mavs = {s: mav.MAVLink(None, s, 1) for s in core.vehicles}

    def datagram(t_ms: int) -> bytes:
        out = []
        for s, m2 in mavs.items():
            e, north, up = starts[s]
            msg = m2.local_position_ned_encode(t_ms, north, e, -up, 0.01, 0.0, 0.0)
            out.append(bytes(msg.pack(m2)))
        return b"".join(out)

    grams = [datagram(1020 + 20 * c) for c in range(WARM_UP + cycles)]

    def write(key: str, batch: SetpointBatch | None) -> None:
        if batch is not None:
            link.accel_setpoints(*batch)

    peer = ("127.0.0.1", 5760)
    gc.collect()
    gc.freeze()
    rx = step = 0.0
    now = 0.0
    try:
        for c, data in enumerate(grams):
            now += 0.02
            t0 = time.process_time()
            for msg in link.receive(data, peer, now, datagram=True):
                core.receive(msg, LINK, now, now)
            if link.positions_written:
                core.telemetry_written(now)
            t1 = time.process_time()
            assert core.step_wanted, "every vehicle fresh: a step is due"
            core.control_step(now, write)
            core.lookahead.clear()
            t2 = time.process_time()
            if c >= WARM_UP:
                rx, step = rx + t1 - t0, step + t2 - t1
    finally:
        gc.unfreeze()
    k = cycles * n
    return rx / k * 1e6, step / k * 1e6


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--counts", default="50,250")
    ap.add_argument("--cycles", type=int, default=250)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"station core in process, on {pin(1)}: us per vehicle-cycle, median of "
          f"{args.repeat} x {args.cycles} cycles")  # fmt: skip
    print(f"{'N':>4} {'receive':>8} {'step+send':>9} {'total':>7}")
    for n in (int(c) for c in args.counts.split(",")):
        runs = [run(n, args.cycles) for _ in range(args.repeat)]
        rx = statistics.median(r[0] for r in runs)
        st = statistics.median(r[1] for r in runs)
        total = statistics.median(r[0] + r[1] for r in runs)
        print(f"{n:4d} {rx:8.2f} {st:9.2f} {total:7.2f}", flush=True)


if __name__ == "__main__":
    main()
