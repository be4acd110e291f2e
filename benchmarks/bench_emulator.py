"""Benchmark of the emulator: vehicles kept in real time, and lockstep speed.

Run from the repository root: ``python benchmarks/bench_emulator.py`` (about a
minute; ``--lockstep-only`` runs part 2 alone, ``--profile FILE`` writes a
cProfile of the emulator side of part 2). The emulator runs in this process
(single-threaded asyncio: at most one core); the ground-station side is a
separate process (this file with ``--sink``) so its cost is not counted. Both
are pinned to different cores when the machine has two.

1. Real time: N airborne vehicles, each on its own UDP endpoint, streaming
   LOCAL_POSITION_NED at 50 Hz (plus 1 Hz HEARTBEAT); ``open`` mode only
   drains telemetry, ``closed`` mode answers every report with an
   acceleration setpoint (so the inbound path is measured too). Reported:
   real-time factor (sim s per wall s), emulator CPU (fraction of one core),
   telemetry delivered (fraction of N x 50 Hz), late steps.
2. Lockstep: N = 6 at 50 Hz, the sink answering each report at once; reported
   as steps per wall second, sim seconds per wall second and the emulator's
   CPU per step. Each vehicle has its own endpoint; with ``--shared`` all six
   share one (``shared_port``, as ``bench_lockstep.py`` runs the real station)
   and the sink answers a datagram of reports with one datagram of setpoints.
3. ``--networks N`` (alone): the emulator's CPU per vehicle-cycle at scale,
   in process and without sockets read: N vehicles as networks of 250 on
   shared endpoints, each network's step and its 250 setpoints in datagrams
   of at most 1,200 bytes (``in_process``), with the deferred lane
   (docs/emulator.md) on and off, alternated twice.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import socket
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import pin
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec

RATE_HZ = 50.0


def sink(ports: list[int], seconds: float, answer: bool) -> None:
    """Ground-station stand-in: one socket, asks every vehicle for 50 Hz reports, drains.

    ``ports`` holds one port per vehicle, or one port and then the vehicle count
    as a negative number (``-n``: n vehicles sharing that port, answered with
    one datagram per datagram of reports)."""
    pin(1)
    if len(ports) == 2 and ports[1] < 0:
        ports = [ports[0]] * -ports[1]
    enc = mav.MAVLink(None, 255, 190)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.bind(("127.0.0.1", 0))
    setpoints: dict[int, bytes] = {}
    for i, port in enumerate(ports):
        sysid = i % 250 + 1  # system ids repeat across endpoints beyond 250 vehicles
        addr = ("127.0.0.1", port)
        if i == 0 or port != ports[i - 1]:
            sock.sendto(enc.heartbeat_encode(6, 8, 0, 0, 0).pack(enc), addr)
        cmd = enc.command_long_encode(sysid, 1, 511, 0, 32, int(1e6 / RATE_HZ), 0, 0, 0, 0, 0)
        sock.sendto(cmd.pack(enc), addr)
        sp = enc.set_position_target_local_ned_encode(
            0, sysid, 1, 1, 3135, 0, 0, 0, 0, 0, 0, 0.1, 0.0, 0.0, 0, 0
        )
        setpoints[sysid] = sp.pack(enc)
    sock.settimeout(0.5)
    count = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            data, addr = sock.recvfrom(65536)
        except TimeoutError:
            continue
        i = 0
        out = []
        while i + 12 <= len(data) and data[i] == 0xFD:  # walk the MAVLink 2 frames
            length, sysid, msgid = data[i + 1], data[i + 5], data[i + 7]
            if msgid == 32:
                count += 1
                out.append(setpoints[sysid])
            i += 12 + length
        if answer and out:
            sock.sendto(b"".join(out), addr)
    print(count, flush=True)


async def realtime(n: int, seconds: float, answer: bool) -> dict[str, float]:
    specs = tuple(
        VehicleSpec(sysid=i % 250 + 1, vid=i + 1, start_ned_m=(0.0, 0.0, -10.0), airborne=True)
        for i in range(n)
    )
    cfg = EmulatorConfig(vehicles=specs, rate_hz=RATE_HZ)
    async with Emulator(cfg) as emu:
        ports = [emu.endpoints[i + 1][1] for i in range(n)]
        warm = 2.0
        proc = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "--sink", str(warm + seconds), "1" if answer else "0",
            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        )  # fmt: skip
        assert proc.stdin is not None and proc.stdout is not None
        proc.stdin.write((" ".join(map(str, ports)) + "\n").encode())
        await proc.stdin.drain()
        proc.stdin.close()
        await asyncio.sleep(warm)
        s0, c0, w0, late0 = emu.step_count, time.process_time(), time.monotonic(), 0
        late0 = emu.stats.late_steps
        await asyncio.sleep(seconds)
        s1, c1, w1 = emu.step_count, time.process_time(), time.monotonic()
        late = emu.stats.late_steps - late0
        out = await proc.stdout.read()
        await proc.wait()
        delivered = int(out.split()[-1]) / (n * RATE_HZ * (warm + seconds))
    wall = w1 - w0
    return {
        "rt_factor": (s1 - s0) / RATE_HZ / wall,
        "cpu": (c1 - c0) / wall,
        "delivered": delivered,
        "late": late,
    }


async def lockstep(n: int, seconds: float, shared: bool) -> dict[str, float]:
    specs = tuple(
        VehicleSpec(sysid=i + 1, start_ned_m=(0.0, 2.0 * i, -10.0), airborne=True) for i in range(n)
    )
    cfg = EmulatorConfig(
        vehicles=specs, rate_hz=RATE_HZ, clock="lockstep", shared_port=0 if shared else None
    )
    async with Emulator(cfg) as emu:
        ports = [emu.endpoints[i + 1][1] for i in range(n)]
        if shared:
            ports = [ports[0], -n]
        proc = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "--sink", str(seconds + 1.0), "1",
            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        )  # fmt: skip
        assert proc.stdin is not None and proc.stdout is not None
        proc.stdin.write((" ".join(map(str, ports)) + "\n").encode())
        await proc.stdin.drain()
        proc.stdin.close()
        await emu.wait_steps(50)
        s0, w0, c0 = emu.step_count, time.monotonic(), time.process_time()
        await asyncio.sleep(seconds)
        s1, w1, c1 = emu.step_count, time.monotonic(), time.process_time()
        timeouts = emu.stats.lockstep_timeouts
        await proc.stdout.read()
        await proc.wait()
    rate = (s1 - s0) / (w1 - w0)
    cpu = (c1 - c0) / (w1 - w0)
    return {"steps_per_s": rate, "speedup": rate / RATE_HZ, "timeouts": timeouts, "cpu": cpu}


def in_process(n: int, cycles: int, defer: bool, columns: bool = False) -> tuple[float, float]:
    """``--networks N``: emulator CPU [us] per vehicle-cycle, (setpoints, step).

    N airborne vehicles as bench_station's networks of 250, each network's
    ``EmulatorCore`` on a shared UDP endpoint (as ``bench_shards --realtime``
    flies them), driven here as its asyncio shell drives it, without the
    clock: a physics step of each network in turn (``core.step``: its
    LOCAL_POSITION_NED sent to a socket drained between steps, not timed),
    then that network's 250 acceleration setpoints in datagrams of at most
    ``MAX_DATAGRAM_BYTES`` (``mavwire.datagrams.join_frames``), each parsed by the
    endpoint and received by the core (``server.Emulator._receive``).
    ``defer``: the deferred lane on or off (``EmulatorCore.defer_stream``);
    ``columns``: a network's datagrams taken together first
    (``lane.take_stream``, as the shell's ``Emulator._on_datagrams`` does),
    each received in turn only if it declines."""
    import random
    from dataclasses import replace

    import bench_station
    import numpy as np

    from gcs_swarm.runtime.run import emulator_config
    from mavwire.datagrams import join_frames
    from sim_vehicle import signing
    from sim_vehicle.core import EmulatorCore
    from sim_vehicle.impairments import Impairer
    from sim_vehicle.lane import take_stream
    from sim_vehicle.link import Endpoint, bind_udp

    whole, sizes = bench_station.load(n, networks=True), bench_station.groups(n)
    gcs_sock = bind_udp("127.0.0.1", 0)
    gcs_sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 24)
    gcs = gcs_sock.getsockname()
    enc = mav.MAVLink(None, srcSystem=255, srcComponent=190)
    rng = random.Random(1)

    def drain() -> None:
        with contextlib.suppress(BlockingIOError):
            while True:
                gcs_sock.recv(65536)

    nets = []
    for j, size in enumerate(sizes):
        cfg = replace(emulator_config(whole, airborne=True, network=j), shared_port=0)
        core = EmulatorCore(cfg)
        core.defer_stream = defer
        up, down = (Impairer(imp, np.random.default_rng(0)) for imp in (cfg.uplink, cfg.downlink))
        ep = Endpoint(sock=bind_udp("127.0.0.1", 0), shared=True, uplink=up,
                      downlink=down, on_datagram=lambda e, d, a: None,
                      stats=core.stats.link)  # fmt: skip
        core.ports.append(ep)
        for spec in cfg.vehicles:
            core.add(spec, ep, True, signing.mavlink(spec.sysid, spec.compid, None))
        core.emit(0.0)
        hello = [enc.heartbeat_encode(6, 8, 0, 0, 4).pack(enc)] + [
            enc.command_long_encode(s, 1, 511, 0, 32, 20000, 0, 0, 0, 0, 0).pack(enc)
            for s in range(1, size + 1)
        ]  # HEARTBEAT, then LOCAL_POSITION_NED at 50 Hz
        for gram in hello:
            core.receive(ep, ep.parse(gram, raw=True), gcs, None)
        nets.append((core, ep, size))
    t_rx = t_step = 0
    for k in range(cycles + 10):
        for core, ep, size in nets:
            a = time.thread_time_ns()
            core.step()
            b = time.thread_time_ns()
            drain()
            frames = [
                enc.set_position_target_local_ned_encode(
                    0, s, 1, 1, 3135, 0, 0, 0, 0, 0, 0, rng.uniform(-1, 1),
                    rng.uniform(-1, 1), rng.uniform(-0.5, 0.5), 0, 0,
                ).pack(enc)
                for s in range(1, size + 1)
            ]  # fmt: skip
            grams = [data for data, _ in join_frames([(f, 0) for f in frames])]
            c = time.thread_time_ns()
            if not (columns and take_stream(core, ep, grams, gcs)):
                for gram in grams:
                    core.receive(ep, ep.parse(gram, raw=True), gcs, None)
            d = time.thread_time_ns()
            if k >= 10:  # the first cycles warm up
                t_step, t_rx = t_step + b - a, t_rx + d - c
    for _, ep, _ in nets:
        ep.sock.close()
    gcs_sock.close()
    return t_rx / 1e3 / (n * cycles), t_step / 1e3 / (n * cycles)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sink", nargs=2, metavar=("SECONDS", "ANSWER"))
    ap.add_argument("--counts", default="100,250,500,750,1000")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--lockstep-only", action="store_true", help="skip the real-time part")
    ap.add_argument(
        "--shared", action="store_true", help="lockstep: one shared endpoint, batched answers"
    )
    ap.add_argument(
        "--profile", metavar="FILE", help="cProfile the lockstep part (emulator side) into FILE"
    )
    ap.add_argument(
        "--networks", type=int, metavar="N", help="in process: CPU per vehicle-cycle at N"
    )
    ap.add_argument("--cycles", type=int, default=200)
    args = ap.parse_args()
    if args.networks:
        pin(0)
        print(f"emulator in process, N = {args.networks} in networks of 250 on shared ports, "
              f"{args.cycles} cycles; CPU us per vehicle-cycle")  # fmt: skip
        modes = (("lane, column-wise", True, True), ("lane, one by one", True, False),
                 ("no lane", False, False))  # fmt: skip
        for name, defer, columns in modes + modes:
            rx, st = in_process(args.networks, args.cycles, defer, columns)
            print(f"{name:>17}: setpoints {rx:.2f}, step and telemetry {st:.2f}, "
                  f"together {rx + st:.2f}", flush=True)  # fmt: skip
        return
    if args.sink:
        ports = [int(p) for p in sys.stdin.readline().split()]
        sink(ports, float(args.sink[0]), args.sink[1] == "1")
        return
    pin(0)
    print(f"emulator benchmark, {RATE_HZ:g} Hz telemetry, one emulator process (one core)")
    print(f"{'mode':>6} {'N':>5} {'rt factor':>9} {'cpu':>6} {'delivered':>9} {'late':>5}")
    for mode in () if args.lockstep_only else ("open", "closed"):
        for n in (int(c) for c in args.counts.split(",")):
            r = asyncio.run(realtime(n, args.seconds, answer=mode == "closed"))
            print(
                f"{mode:>6} {n:5d} {r['rt_factor']:9.3f} {r['cpu']:6.2f} "
                f"{r['delivered']:9.3f} {int(r['late']):5d}",
                flush=True,
            )
    if args.profile:
        import cProfile

        with cProfile.Profile() as prof:
            r = asyncio.run(lockstep(6, args.seconds, args.shared))
        prof.dump_stats(args.profile)
    else:
        r = asyncio.run(lockstep(6, args.seconds, args.shared))
    print(
        f"lockstep N=6{' shared' if args.shared else ''}: {r['steps_per_s']:.0f} steps/s = "
        f"{r['speedup']:.1f}x real time ({int(r['timeouts'])} timeouts, emulator cpu "
        f"{r['cpu']:.2f} = {1e6 * r['cpu'] / r['steps_per_s']:.0f} us/step)"
    )


if __name__ == "__main__":
    main()
