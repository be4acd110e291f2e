"""Baseline: a station written the way most users write one today.

Run from the repository root: ``python benchmarks/bench_baseline.py`` (about
40 s for N = 50, 100, 250).

One pymavlink ``mavutil.mavlink_connection("udpout:...")`` per vehicle, a loop
over the connections with ``recv_match(type="LOCAL_POSITION_NED",
blocking=False)``, and for every report one acceleration setpoint
(``set_position_target_local_ned_send``, type_mask 3135), no law (a constant
setpoint: this is the I/O floor of that style, so the comparison favours it).
The emulator (real time, N airborne vehicles in GUIDED, one UDP endpoint each,
as SITL instances) runs in a child process pinned to core 0, the baseline here
on core 1. Reported over a window: setpoints/s, telemetry/s, missed
vehicle-cycles (N x 50 x window - setpoints), CPU (cores) and CPU per setpoint
[us], to compare with ``bench_station.py``'s ``us/veh``.
"""

from __future__ import annotations

import argparse
import asyncio
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import pin

RATE_HZ = 50


async def emulator_main(n: int) -> None:
    from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec

    pin(0)
    specs = tuple(
        VehicleSpec(sysid=i + 1, start_ned_m=(3.0 * (i % 16), 3.0 * (i // 16), -10.0),
                    airborne=True)
        for i in range(n)
    )  # fmt: skip
    async with Emulator(EmulatorConfig(vehicles=specs, rate_hz=RATE_HZ)) as emu:
        print(" ".join(str(emu.endpoints[i + 1][1]) for i in range(n)), flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


def baseline(n: int, seconds: float) -> dict[str, float]:
    from pymavlink import mavutil

    proc = subprocess.Popen(
        [sys.executable, __file__, "--emulator", str(n)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stdin is not None
    ports = [int(p) for p in proc.stdout.readline().split()]
    conns = []
    for i, port in enumerate(ports):
        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                       source_component=190, dialect="ardupilotmega")  # fmt: skip
        m.mav.heartbeat_send(6, 8, 0, 0, 0)
        m.mav.command_long_send(i + 1, 1, 511, 0, 32, int(1e6 / RATE_HZ), 0, 0, 0, 0, 0)
        conns.append((i + 1, m))
    sent = rx = 0
    warm_end = time.monotonic() + 1.5
    c0 = w0 = 0.0
    end = warm_end + seconds
    started = False
    while True:
        now = time.monotonic()
        if not started and now >= warm_end:
            started, sent, rx, c0, w0 = True, 0, 0, time.process_time(), now
        if now >= end:
            break
        for sysid, m in conns:
            msg = m.recv_match(type="LOCAL_POSITION_NED", blocking=False)
            while msg is not None:
                rx += 1
                m.mav.set_position_target_local_ned_send(
                    msg.time_boot_ms, sysid, 1, 1, 3135, 0, 0, 0, 0, 0, 0, 0.1, 0.0, 0.0, 0, 0
                )
                sent += 1
                msg = m.recv_match(type="LOCAL_POSITION_NED", blocking=False)
    c1, w1 = time.process_time(), time.monotonic()
    proc.stdin.close()
    proc.wait()
    for _, m in conns:
        m.close()
    wall = w1 - w0
    return {
        "setpoints_per_s": sent / wall,
        "rx_per_s": rx / wall,
        "missed": max(0.0, n * RATE_HZ * wall - sent),
        "cpu": (c1 - c0) / wall,
        "us_per_setpoint": (c1 - c0) / max(sent, 1) * 1e6,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--emulator", type=int)
    ap.add_argument("--counts", default="50,100,250")
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()
    if args.emulator:
        asyncio.run(emulator_main(args.emulator))
        return
    where = pin(1)
    print(f"mavutil baseline (one connection per vehicle, recv_match loop), {RATE_HZ} Hz, "
          f"baseline on {where}, emulator on core 0, {args.seconds:g} s window")  # fmt: skip
    print(f"{'N':>4} {'setpt/s':>8} {'telem/s':>8} {'missed':>7} {'cpu':>5} {'us/setpt':>8}")
    for n in (int(c) for c in args.counts.split(",")):
        r = baseline(n, args.seconds)
        print(f"{n:4d} {r['setpoints_per_s']:8.0f} {r['rx_per_s']:8.0f} {r['missed']:7.0f} "
              f"{r['cpu']:5.2f} {r['us_per_setpoint']:8.1f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
