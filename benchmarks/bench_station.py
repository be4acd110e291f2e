"""Station capacity: N vehicles at 50 Hz in real time, station and emulator apart.

Run from the repository root: ``python benchmarks/bench_station.py`` (about
90 s for N = 50, 100, 250, 500; ``--counts`` and ``--seconds`` to change;
``--view HZ`` opens the operator view on each station, read by a page in
its own process, to compare the figures with and without it; ``--record``
gives each station the flight recorder of a logged run; ``--rate HZ`` flies
at another control rate; ``--networks`` flies N > 250 as one mission of
several networks on one ``Station``, as ``gcs-swarm run`` does, instead of
one station per group). With ``--networks`` the station's step waits for
every network's reports: each network's emulator keeps its own clock, so
the first network's reports wait for the others' (their phase offset, a
few ms here, as unsynchronised real vehicles would make them wait), and the
latency includes that wait; the CPU per vehicle-cycle does not.
``--step network`` flies the mission's ``step: network`` instead: a step
per network as soon as its reports are in (docs/formation-law.md section
3b), so a report no longer waits for the other networks'. ``--cutoff F``
starts on the equilibrium sphere with the repulsion cut at F d_nn, and
``--settle S`` from where that cut-off law settles it after S s.

The emulator runs in a child process (this file with ``--emulator``) pinned
to core 0, the station in this process pinned to core 1 (when the machine has
two cores). Vehicles start airborne in GUIDED (``spawn: air``), all on one
shared UDP endpoint per group of at most 250 (MAVLink system ids are 8 bits
and the station keys vehicles by system id, so N = 500 is two groups, each
with its own ``Station`` on the same event loop, i.e. the same core). Each
station readies its vehicles, then flies the formation law (Example 1 gains,
leader at rest, vehicles on a 3 m grid) answering every LOCAL_POSITION_NED.
The groups are readied one after the other (the second while the first
flies): readying 500 at once lost command answers on this machine. A failed
start-up is printed and retried (at most three times per N).

The window opens one second into the flight, and then only once the station
has caught up with its telemetry: a station readying many vehicles falls
behind their 50 Hz reports (every one of a vehicle not yet flying goes
through its protocol), the kernel queues them in the links' sockets (4 MiB
each: about 11 MB held for 1,500 vehicles, read in ``/proc/net/udp``,
2026-12-06), and its first seconds of flight answer that backlog, up to
twice the reports a second, most of them superseded by a newer one before
the step. ``caught_up`` waits (at most ``CATCH_UP_TIMEOUT_S``) until the
reports taken over half a second are at most 5 % above N x 50 a second,
and the table says how long that took ("catch s") and how many reports above
N x 50 a second the station took meanwhile ("backlog"). A station that
cannot keep up at all never takes more than N x 50 a second: its window
opens at once and shows it.

Measured over that window:
- setpoints/s written by the station and telemetry/s received;
- latency from a telemetry datagram's arrival to its setpoint's write
  (``Link.latency``, measured inside the station) p50 / p99 / max;
- missed: reports accepted that got no setpoint (a newer report of the same
  vehicle came before the step), and control steps short of 50 x window
  ("miss st", within one step of the window's edges);
- station CPU: process time / wall time (one core = 1.0), and the station's
  cost per vehicle per cycle (CPU time / setpoints) as a ratio to the
  pymavlink codec floor of ``bench_codec.py`` (measured again here).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import pin

from gcs_swarm.runtime.sched import default_slice, short_slice

GROUP = 250
"""Vehicles per network or station group (``--group``; the emulator child is told it too)."""
RATE_HZ = 50.0
"""The control rate [Hz] (``--rate``; the emulator child is told it too)."""
CUTOFF: float | None = None
"""``--cutoff F``: the vehicles start on their equilibrium sphere (``bench_law.
sphere_swarm``, d_nn its mean neighbour distance) and the law's repulsion
is cut off at F d_nn (Eq. 9c); None: the 3 m grid and the exact law."""
SETTLE_S = 0.0
"""``--settle S`` (with ``--cutoff``): the start is where the cut-off law
settles the sphere after S seconds in the in-process integrator (RK4, 0.02
s), a formation holding its shape, instead of the exact law's sphere, which
the cut-off law shrinks into a ball (formation-law.md section 3a)."""
SPREAD = False
"""``--spread``: network j's emulator takes its first step j/G of a period
after network 0's (``EmulatorConfig.start_at_s``, G networks), so their
reports fall evenly over the period; by default each starts its clock as
it is set up, one after the other, a few ms apart (their phases bunched)."""
HEARTBEATS = "together"
"""``--heartbeats spread``: each emulated vehicle sends its HEARTBEAT at its
own phase of the second (``EmulatorConfig.heartbeats``), as a fleet booted
one by one does; by default all of an emulator's in one step, as a SITL
swarm started by one script does."""
OVERRUN = "catch_up"
"""``--overrun skip``: an emulator held behind the wall clock takes the steps
it missed as physics alone and sends each stream once (``EmulatorConfig.overrun``),
as real autopilots whose loop overran; by default each missed step sends
its reports, as SITL's clock catches up, so a late emulator hands the station
reports of one vehicle microseconds apart, all but the last of them counted
missed (docs/emulator.md, "A late clock")."""
EMULATORS = 1
"""``--emulators K``: the networks hosted by K emulator processes (network j
by process j * K // G of G networks), all on core 0; by default one. A
network's long step (the HEARTBEAT step, 7-8 ms for 250 together) then
holds up only the networks of its own process: the others' steps are taken
by the kernel's scheduler in between, as separate vehicles would send."""
PHASES: int | None = None
"""``--phases SEED``: network j's emulator takes its first step at a share
of a period drawn uniformly (``random.Random(SEED)``), as networks that
know nothing of each other fall: some close together, some apart."""
STEP = "swarm"
"""``--step``: the mission's ``step`` (``network``: a step per network whose
reports are all in, docs/formation-law.md section 3b)."""
HANDSHAKES: int | None = None
"""``--handshakes W``: the mission's ``startup.handshakes_per_network`` (at most
W vehicles of a network in their start-up handshake at once)."""
READY_TIMEOUT_S: float | None = None
"""``--ready-timeout S``: the mission's ``startup.ready_timeout`` (its default,
90 s, when None): start-up in waves of a large fleet takes longer."""
LEAVE = 0
"""``--leave K`` (with ``--networks``): K vehicles of each network leave the
formation 0.5 s into it (mission events; the mission's end action, hold,
for them) and go on reporting, as vehicles that leave a large swarm do:
their reports are not a flying row's, so the datagrams that hold them are
ones the station's batch path declines (swarm/link_batch.py)."""


def _gains(cutoff_m: float | None = None):  # type: ignore[no-untyped-def]
    """Example 1's gains, the mission's ``gains:`` (repulsion cut at ``cutoff_m``)."""
    from gcs_swarm.control.params import Gains

    return Gains(M=1, D=1, k=9, k_s=1, k_r=0.2, alpha=2, q_default=10, repulsion_cutoff=cutoff_m)


def mission_options(ap: argparse.ArgumentParser) -> None:
    """The swarm's options (``--cutoff``, ``--step``, ``--settle``,
    ``--spread``, ``--phases``), also bench_shards.py's."""
    ap.add_argument("--cutoff", type=float, default=None, metavar="F",
                    help="start on the equilibrium sphere, repulsion cut at F x d_nn")  # fmt: skip
    ap.add_argument("--step", choices=("swarm", "network"), default="swarm",
                    help="the mission's step: swarm (default) or network")  # fmt: skip
    ap.add_argument("--settle", type=float, default=0.0, metavar="S",
                    help="with --cutoff: start where its law settles after S s")  # fmt: skip
    ap.add_argument("--spread", action="store_true",
                    help="the networks' emulators a share of a period apart")  # fmt: skip
    ap.add_argument("--phases", type=int, default=None, metavar="SEED",
                    help="the networks' emulators at random shares of a period")  # fmt: skip
    ap.add_argument("--heartbeats", choices=("together", "spread"), default="together",
                    help="the vehicles' HEARTBEATs in one step (a SITL swarm, default) "
                         "or each at its own phase (a fleet booted one by one)")  # fmt: skip
    ap.add_argument("--overrun", choices=("catch_up", "skip"), default="catch_up",
                    help="an emulator behind the wall clock: each missed step's reports "
                         "(as SITL, default) or physics, then one (as an autopilot)")  # fmt: skip
    ap.add_argument("--handshakes", type=int, default=None, metavar="W",
                    help="mission.startup.handshakes_per_network: W vehicles of a network "
                         "configure at once")  # fmt: skip
    ap.add_argument("--ready-timeout", type=float, default=None, metavar="S",
                    help="mission.startup.ready_timeout [s], default 90")  # fmt: skip
    ap.add_argument("--emulators", type=int, default=1, metavar="K",
                    help="host the networks in K emulator processes, all on core 0")  # fmt: skip


def _startup_yaml() -> str:
    """The mission's ``startup`` from ``--handshakes`` and ``--ready-timeout``
    ("" when neither is given)."""
    keys = [f"handshakes_per_network: {HANDSHAKES}"] if HANDSHAKES else []
    keys += [f"ready_timeout: {READY_TIMEOUT_S!r}"] if READY_TIMEOUT_S is not None else []
    return f", startup: {{{', '.join(keys)}}}" if keys else ""


def emulator_child(
    n: int, networks: bool, host: tuple[int, int] | None = None, epoch: float | None = None
) -> list[str]:
    """The emulator child's arguments for N vehicles (this file with
    ``--emulator``) from this module's settings (``RATE_HZ``, ``GROUP``,
    ``SPREAD``, ``PHASES``, ``HEARTBEATS``, ``OVERRUN``, ``CUTOFF``,
    ``SETTLE_S``), also bench_shards.py's; with a cut-off the settled start
    is cached first (the child reads it). ``host`` and ``epoch``:
    ``emulator_main``'s."""
    child = ["--emulator", str(n), "--rate", f"{RATE_HZ:g}", "--group", str(GROUP)]
    child += ["--spread"] if SPREAD else []
    child += ["--phases", str(PHASES)] if PHASES is not None else []
    child += ["--heartbeats", HEARTBEATS, "--overrun", OVERRUN]
    if CUTOFF is not None:
        mission_yaml(n, networks)
        child += ["--cutoff", repr(CUTOFF), "--settle", repr(SETTLE_S)]
    child += ["--networks"] if networks else []
    child += ["--host", f"{host[0]}:{host[1]}"] if host is not None else []
    child += ["--epoch", repr(epoch)] if epoch is not None else []
    return child


def host_ranges(n: int) -> list[tuple[int, int]]:
    """The networks (first, stop) each of the ``EMULATORS`` processes hosts."""
    count = len(groups(n))
    k = max(1, min(EMULATORS, count))
    return [(j * count // k, (j + 1) * count // k) for j in range(k)]


class EmulatorChildren:
    """The emulator processes of one run (``--emulators``): each hosts a
    range of the networks; their ports in network order; the window's start
    and stop written to all; their figures summed (CPU: of core 0, where all
    run)."""

    def __init__(self, procs: list[asyncio.subprocess.Process]) -> None:
        self.procs = procs

    @classmethod
    async def start(cls, n: int, networks: bool) -> tuple[EmulatorChildren, list[int]]:
        epoch = time.monotonic()  # every child's network 0 steps on one grid
        procs, ports = [], []
        try:
            for host in host_ranges(n):
                proc = await asyncio.create_subprocess_exec(
                    sys.executable, __file__, *emulator_child(n, networks, host, epoch),
                    stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                )  # fmt: skip
                procs.append(proc)
            for proc in procs:
                assert proc.stdout is not None
                ports += [int(p) for p in (await proc.stdout.readline()).split()]
        except BaseException:
            await cls(procs).close()
            raise
        return cls(procs), ports

    def write(self, line: bytes) -> None:
        """``line`` to every child (``b"start\\n"``, ``b"stop\\n"``: the window)."""
        for proc in self.procs:
            assert proc.stdin is not None
            proc.stdin.write(line)

    async def drain(self) -> None:
        for proc in self.procs:
            assert proc.stdin is not None
            await proc.stdin.drain()

    async def figures(self) -> dict[str, float]:
        """After the window's stop: each child's line of figures, summed
        (``late_steps``, ``cpu`` of core 0) or the least (``rt``)."""
        lines = []
        for proc in self.procs:
            assert proc.stdout is not None
            lines.append((await proc.stdout.readline()).decode())
        return _summed(lines)

    async def close(self) -> dict[str, float]:
        """Close stdin, wait; the window's figures if still unread (else empty)."""
        tails = []
        for proc in self.procs:
            assert proc.stdin is not None and proc.stdout is not None
            proc.stdin.close()
            tails.append((await proc.stdout.read()).decode())
            await proc.wait()
        return _summed(tails)


def _summed(lines: list[str]) -> dict[str, float]:
    """Emulator children's ``late_steps=.. cpu=.. rt=..`` lines as one; empty
    unless every child gave one."""
    figures = [dict(kv.split("=") for kv in t.split()) for t in lines if "late_steps=" in t]
    if not figures or len(figures) < len(lines):
        return {}
    return {
        "late_steps": sum(float(f["late_steps"]) for f in figures),
        "cpu": sum(float(f["cpu"]) for f in figures),
        "rt": min(float(f["rt"]) for f in figures),
    }


def mission_yaml(n: int, networks: bool = False, duration: float = 14400.0) -> str:
    """N vehicles on a 3 m grid; with ``networks``, one mission whose
    networks (``n0``, ``n1``, ...) hold ``GROUP`` vehicles each, the grid
    shared by all (one formation)."""
    side = math.ceil(n ** (1 / 3))
    cut, sphere = "", None
    if CUTOFF is not None:
        from bench_law import sphere_swarm

        sphere, d_nn = sphere_swarm(n, _gains())
        if SETTLE_S > 0.0:
            sphere = _settled(n, sphere, CUTOFF * d_nn)
        cut = f", repulsion_cutoff: {CUTOFF * d_nn!r}"
    g = _gains()
    lines = [
        f"mission: {{name: bench, duration: {duration:g}, rate: {RATE_HZ:g}, end: hold,"
        f" step: {STEP}" + _startup_yaml() + "}",
        "emulator: {dynamics: ideal, spawn: air, shared: true}",
        f"gains: {{M: {g.M!r}, D: {g.D!r}, k: {g.k!r}, k_s: {g.k_s!r}, k_r: {g.k_r!r},"
        f" alpha: {g.alpha!r}, q: {g.q_default!r}{cut}}}",
        "leader: {start: [0, 0, 0], force: [0, 0, 0]}",
    ]
    lines.append("networks:" if networks else "vehicles:")
    indent = "  "
    for i in range(n):
        if networks and i % GROUP == 0:
            lines.append(f"  - name: n{i // GROUP}")
            lines.append("    vehicles:")
            indent = "      "
        x, y, z = i % side, (i // side) % side, i // (side * side)
        c = (side - 1) / 2
        pos = f"[{3 * (x - c)}, {3 * (y - c)}, {3 * (z - c)}]"
        if sphere is not None:
            pos = "[" + ", ".join(f"{float(w)!r}" for w in sphere[i]) + "]"
        sysid = i % GROUP + 1 if networks else i + 1
        lines.append(f"{indent}- {{sysid: {sysid}, start: {pos}}}")
    if networks and LEAVE:
        lines.append("events:")
        for j in range(math.ceil(n / GROUP)):
            size = min(GROUP, n - j * GROUP)
            for i in range(LEAVE):  # spread over the network's system ids
                sysid = (i + 1) * size // (LEAVE + 1)
                lines.append(f"  - {{t: 0.5, network: n{j}, leave: {sysid}}}")
    return "\n".join(lines) + "\n"


def _settled(n: int, start: object, cutoff_m: float) -> object:
    """``SETTLE_S`` of the cut-off law from ``start`` (``SETTLE_S``), cached
    in the temporary directory: the station and the emulator child read the
    same floats."""
    import numpy as np

    name = f"gcs-swarm-bench-settled-{n}-{cutoff_m!r}-{SETTLE_S!r}.npy"
    cache = Path(tempfile.gettempdir()) / name
    if cache.exists():
        return np.load(cache)
    from gcs_swarm.control.params import LawConfig
    from gcs_swarm.integrator import integrate

    pos = integrate(LawConfig(gains=_gains(cutoff_m)), start, duration=SETTLE_S, dt=0.02).pos_m[-1]
    np.save(cache, pos)
    return pos


def load(n: int, networks: bool = False):  # type: ignore[no-untyped-def]
    from gcs_swarm.mission import load_mission

    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
        f.write(mission_yaml(n, networks))
    try:
        return load_mission(f.name)
    finally:
        os.unlink(f.name)


def groups(n: int) -> list[int]:
    return [min(GROUP, n - k) for k in range(0, n, GROUP)]


async def emulator_main(
    n: int, networks: bool, host: tuple[int, int] | None = None, epoch: float | None = None
) -> None:
    """Child: one realtime emulator per group (with ``networks``: per network of
    the one mission), shared endpoint each; ports on stdout. ``host``: only the
    groups [first, stop) (``--emulators``); ``epoch``: an instant of network 0's
    grid of steps (monotonic clock, one for every child: each starts on the
    grid's next instant), else 50 ms from now."""
    from dataclasses import replace

    from gcs_swarm.runtime.run import emulator_config
    from sim_vehicle import Emulator

    pin(0)
    default_slice()  # the vehicles' own: not the station's slice it inherits
    async with contextlib_stack() as stack:
        emus = []
        whole = load(n, networks=True) if networks else None
        sizes = groups(n)
        phases = _phases(len(sizes))
        # A network set up after its first step's time catches up at once, then
        # keeps its place on the grid (the realtime clock's pacing).
        first = time.monotonic() + 0.05
        if epoch is not None:  # the next instant of the common grid: the same phases
            first = epoch + math.ceil(max(0.0, first - epoch) * RATE_HZ) / RATE_HZ
        lo, hi = host if host is not None else (0, len(sizes))
        for j, size in enumerate(sizes):
            if not lo <= j < hi:
                continue
            if whole is not None:
                cfg = emulator_config(whole, airborne=True, network=j)
            else:
                cfg = emulator_config(load(size), airborne=True)
            cfg = replace(cfg, shared_port=0, heartbeats=HEARTBEATS, overrun=OVERRUN)
            if PHASES is not None:  # network j's first step at a random share of a period
                cfg = replace(cfg, start_at_s=first + phases[j] / RATE_HZ)
            elif SPREAD:  # network j's first step j/G of a period after network 0's
                cfg = replace(cfg, start_at_s=first + j / len(sizes) / RATE_HZ)
            emus.append(await stack.enter_async_context(Emulator(cfg)))
        print(" ".join(str(e.endpoints[1][1]) for e in emus), flush=True)
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
        await reader.readline()  # the parent's window starts
        late0 = sum(e.stats.late_steps for e in emus)
        steps0, c0, w0 = emus[0].step_count, time.process_time(), time.monotonic()
        await reader.readline()  # the window ends
        c1, w1 = time.process_time(), time.monotonic()
        rt = (emus[0].step_count - steps0) / RATE_HZ / (w1 - w0)
        late = sum(e.stats.late_steps for e in emus) - late0
        print(f"late_steps={late} cpu={(c1 - c0) / (w1 - w0):.3f} rt={rt:.3f}", flush=True)
        await reader.read()  # until the parent closes stdin


def _phases(count: int) -> list[float]:
    """``--phases``' share of a period for each of ``count`` networks."""
    import random

    rng = random.Random(PHASES)
    return [rng.random() for _ in range(count)]


def contextlib_stack():  # type: ignore[no-untyped-def]
    import contextlib

    return contextlib.AsyncExitStack()


_VIEW_CLIENT = """
import asyncio, sys
from websockets.asyncio.client import connect
async def main():
    n = 0
    async with connect(sys.argv[1], max_size=None) as ws:
        async def count():
            nonlocal n
            async for _ in ws:
                n += 1
        task = asyncio.ensure_future(count())
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
        task.cancel()
    print(n, flush=True)
asyncio.run(main())
"""
"""A page in its own process (as a browser is): reads frames until stdin closes."""


async def _open_views(stations, stack, view_rate_hz: float):  # type: ignore[no-untyped-def]
    """``--view``: the operator view on each station, one reading page per view."""
    from gcs_swarm.runtime.ending import EndRequest
    from gcs_swarm.view import live_view

    servers, pages = [], []
    for st in stations:
        got = []
        mission = load(len(st.vehicles))
        lv = live_view(mission, rate_hz=view_rate_hz, on_server=got.append)
        await stack.enter_async_context(lv(st, EndRequest(), st.recorder))
        url = got[0].url.replace("http://", "ws://").replace("/?", "/ws?")
        pages.append(await asyncio.create_subprocess_exec(
            sys.executable, "-c", _VIEW_CLIENT, url,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        ))  # fmt: skip
        servers.append(got[0])
    return servers, pages


CATCH_UP_TIMEOUT_S = 20.0
"""How long ``caught_up`` waits for a station to answer its reports as they come [s]."""


async def caught_up(stations: list[Any], n: int, period_s: float = 0.5) -> tuple[float, float]:
    """Wait until ``stations`` take their ``n`` vehicles' reports as the
    vehicles send them: at most 5 % more over ``period_s`` than n x RATE_HZ
    a second (a station working through its sockets' backlog takes more;
    one period's jitter is one step of a network, under 1 % at 1,500).
    (the seconds waited, the reports taken above n x RATE_HZ meanwhile)."""
    t0 = t_prev = time.monotonic()
    r0 = r_prev = sum(s.reports_in for s in stations)
    while True:
        await asyncio.sleep(period_s)
        now, r = time.monotonic(), sum(s.reports_in for s in stations)
        if (r - r_prev) / (now - t_prev) <= 1.05 * n * RATE_HZ or now - t0 >= CATCH_UP_TIMEOUT_S:
            # Caught up from the start of this period on.
            return t_prev - t0, max(0.0, (r - r0) - n * RATE_HZ * (now - t0))
        t_prev, r_prev = now, r


async def station_run(
    n: int,
    seconds: float,
    view_rate_hz: float | None = None,
    record: bool = False,
    networks: bool = False,
) -> dict[str, float]:
    import logging

    from gcs_swarm.report.record import FlightRecorder
    from gcs_swarm.runtime.links import LatencyRing
    from gcs_swarm.runtime.run import station_config
    from gcs_swarm.runtime.station import Station

    logging.getLogger("gcs_swarm").setLevel(logging.ERROR)
    emulators, ports = await EmulatorChildren.start(n, networks)
    try:
        stations = []
        async with contextlib_stack() as stack:
            plans = []
            if networks:  # one mission, one station: each network on its emulator's port
                whole = load(n, networks=True)
                plans.append((whole, {v.key: f"udpout:127.0.0.1:{ports[v.net_index]}"
                                      for v in whole.vehicles}))  # fmt: skip
            else:
                for size, port in zip(groups(n), ports, strict=True):
                    mission = load(size)
                    plans.append((mission, {v.sysid: f"udpout:127.0.0.1:{port}"
                                            for v in mission.vehicles}))  # fmt: skip
            for mission, links in plans:
                cfg = station_config(mission, links)
                # --record: the flight recorder of a logged run (the view then
                # reads its loss counts and builds its frames after its steps).
                recorder = FlightRecorder() if record else None
                stations.append(await stack.enter_async_context(Station(cfg, recorder=recorder)))
            t_ready = time.monotonic()
            flying = []
            for st in stations:  # one group after the other: see the module docstring
                await st.ready()
                flying.append(asyncio.create_task(st.fly()))
            t_ready = time.monotonic() - t_ready
            servers, pages = [], []
            if view_rate_hz is not None:
                servers, pages = await _open_views(stations, stack, view_rate_hz)
            await asyncio.sleep(1.0)
            catch_s, backlog = await caught_up(stations, n)
            links = [lk for s in stations for lk in s.links.values()]
            for lk in links:
                lk.latency = LatencyRing(size=int(RATE_HZ * GROUP * (seconds + 2)))
            rx0 = sum(lk.stats.received for lk in links)
            reports0 = sum(s.reports_in - s.reports_waiting for s in stations)
            steps0 = sum(s.control.steps for s in stations)
            drop0 = sum(lk.stats.setpoints_dropped for lk in links)
            emulators.write(b"start\n")
            c0, w0 = time.process_time(), time.monotonic()
            await asyncio.sleep(seconds)
            c1, w1 = time.process_time(), time.monotonic()
            emulators.write(b"stop\n")
            builds = sorted(x for sv in servers for x in sv.build_s)
            frames_read = 0
            for page in pages:
                assert page.stdin is not None and page.stdout is not None
                page.stdin.close()
                frames_read += int((await page.stdout.read()).split()[0])
                await page.wait()
            lat = sorted(x for lk in links for x in lk.latency.samples())
            sent = sum(lk.latency.count for lk in links)
            rx = sum(lk.stats.received for lk in links) - rx0
            steps = sum(s.control.steps for s in stations) - steps0
            # A report is answered by one setpoint at the next step unless a
            # newer one of the same vehicle replaced it first: reports accepted
            # (those still waiting for a step at either edge excluded) minus
            # setpoints written counts the vehicle-cycles left unanswered.
            reports = sum(s.reports_in - s.reports_waiting for s in stations) - reports0
            drops = sum(lk.stats.setpoints_dropped for lk in links) - drop0
            for task in flying:
                task.cancel()
            await asyncio.gather(*(s.end() for s in stations))
    except BaseException:
        await emulators.close()
        raise
    emu = await emulators.close()
    wall = w1 - w0

    def pct(q: float) -> float:
        return lat[min(len(lat) - 1, int(q / 100 * len(lat)))] * 1e3 if lat else math.nan

    view = {}
    if view_rate_hz is not None:
        view = {
            "view_frames_read": float(frames_read),
            "view_dropped": float(sum(sv.frames_dropped for sv in servers)),
            "frame_build_mean_ms": statistics.fmean(builds) * 1e3 if builds else math.nan,
            "frame_build_max_ms": builds[-1] * 1e3 if builds else math.nan,
        }
    return {
        **view,
        "ready_s": t_ready,
        "catch_up_s": catch_s,
        "backlog": backlog,
        "setpoints_per_s": sent / wall,
        "rx_per_s": rx / wall,
        "p50_ms": pct(50),
        "p99_ms": pct(99),
        "max_ms": lat[-1] * 1e3 if lat else math.nan,
        "missed": float(reports - sent),
        "missed_steps": max(0.0, RATE_HZ * wall * len(stations) - steps),
        "steps_per_s": steps / wall,
        "drops": drops,
        "cpu": (c1 - c0) / wall,
        "us_per_vehicle_cycle": (c1 - c0) / max(sent, 1) * 1e6,
        "emu_late": float(emu.get("late_steps", -1)),
        "emu_cpu": float(emu.get("cpu", -1)),
        "emu_rt": float(emu.get("rt", -1)),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--emulator", type=int)
    ap.add_argument("--host", default=None, help=argparse.SUPPRESS)  # the child's networks
    ap.add_argument("--epoch", type=float, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--counts", default="50,100,250,500")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--view", type=float, default=None, metavar="HZ",
                    help="open the operator view on each station at HZ frames/s, read by a"
                    " page in its own process")  # fmt: skip
    ap.add_argument("--record", action="store_true",
                    help="give each station a flight recorder, as a logged run has")  # fmt: skip
    ap.add_argument("--rate", type=float, default=50.0, help="control rate [Hz] (default 50)")
    ap.add_argument("--group", type=int, default=250,
                    help="vehicles per network or station group (default 250)")  # fmt: skip
    ap.add_argument("--networks", action="store_true",
                    help="N > 250 as one mission of several networks on one station")  # fmt: skip
    ap.add_argument("--leave", type=int, default=0, metavar="K",
                    help="with --networks: K vehicles of each network leave 0.5 s into "
                         "the formation and go on reporting")  # fmt: skip
    mission_options(ap)
    args = ap.parse_args()
    global RATE_HZ, GROUP, CUTOFF, STEP, SETTLE_S, SPREAD, PHASES, HEARTBEATS, EMULATORS, OVERRUN
    global LEAVE
    LEAVE = args.leave
    RATE_HZ, GROUP, CUTOFF, STEP = args.rate, args.group, args.cutoff, args.step
    SETTLE_S, SPREAD, PHASES = args.settle, args.spread, args.phases
    HEARTBEATS, EMULATORS, OVERRUN = args.heartbeats, args.emulators, args.overrun
    global HANDSHAKES, READY_TIMEOUT_S
    HANDSHAKES, READY_TIMEOUT_S = args.handshakes, args.ready_timeout
    if args.emulator:
        host = tuple(int(j) for j in args.host.split(":")) if args.host else None
        asyncio.run(emulator_main(args.emulator, args.networks, host, args.epoch))  # type: ignore[arg-type]
        return
    import bench_codec

    from gcs_swarm.errors import StartupError

    floor_us = bench_codec.main()
    where = pin(1)
    where += ", short slice" if short_slice() else ""  # as `gcs-swarm run` (runtime.sched)
    how = "one station, one mission of networks" if args.networks else "one station per group"
    how += f", step: {STEP}" + (", phases spread" if SPREAD else "")
    how += f", heartbeats {HEARTBEATS}, overrun {OVERRUN}"
    how += f", {EMULATORS} emulator processes" if EMULATORS > 1 else ""
    how += f", {LEAVE} of each network left at 0.5 s" if LEAVE else ""
    how += f", {HANDSHAKES} handshakes per network at once" if HANDSHAKES else ""
    how += f", ready timeout {READY_TIMEOUT_S:g} s" if READY_TIMEOUT_S is not None else ""
    if PHASES is not None:
        most = len(groups(max(int(c) for c in args.counts.split(","))))
        how += f", phases (seed {PHASES}): " + " ".join(f"{p:.2f}" for p in _phases(most))
    print(f"\nstation capacity, {RATE_HZ:g} Hz real time, station on {where}, emulator on core 0,"
          f" {args.seconds:g} s window, {how}")  # fmt: skip
    print(f"{'N':>4} {'ready s':>7} {'setpt/s':>8} {'telem/s':>8} {'p50 ms':>7} {'p99 ms':>7} "
          f"{'max ms':>7} {'missed':>7} {'miss st':>7} {'cpu':>5} {'us/veh':>6} {'x floor':>7} "
          f"{'emu late':>8} {'emu cpu':>7} {'emu rt':>6} {'steps/s':>7} {'catch s':>7} "
          f"{'backlog':>7}")  # fmt: skip
    for n in (int(c) for c in args.counts.split(",")):
        runs, failed = [], 0
        while len(runs) < args.repeat and failed < 3:
            try:
                runs.append(asyncio.run(
                    station_run(n, args.seconds, args.view, args.record, args.networks)
                ))  # fmt: skip
            except StartupError as err:  # reported, not hidden: see the README
                failed += 1
                print(f"{n:4d} start-up failed ({str(err)[:90]}...); retrying", flush=True)
        if not runs:
            continue
        r = {k: statistics.median(x[k] for x in runs) for k in runs[0]}
        print(f"{n:4d} {r['ready_s']:7.1f} {r['setpoints_per_s']:8.0f} {r['rx_per_s']:8.0f} "
              f"{r['p50_ms']:7.2f} {r['p99_ms']:7.2f} {r['max_ms']:7.2f} {r['missed']:7.0f} "
              f"{r['missed_steps']:7.0f} {r['cpu']:5.2f} {r['us_per_vehicle_cycle']:6.1f} "
              f"{r['us_per_vehicle_cycle'] / floor_us:7.2f} {r['emu_late']:8.0f} "
              f"{r['emu_cpu']:7.2f} {r['emu_rt']:6.3f} {r['steps_per_s']:7.1f} "
              f"{r['catch_up_s']:7.1f} {r['backlog']:7.0f}", flush=True)  # fmt: skip
        if args.view is not None:
            print(f"       view {args.view:g} Hz: frames read {r['view_frames_read']:.0f}, "
                  f"dropped {r['view_dropped']:.0f}, frame build+encode mean "
                  f"{r['frame_build_mean_ms']:.2f} ms, max {r['frame_build_max_ms']:.2f} ms",
                  flush=True)  # fmt: skip
        if len(runs) > 1:  # the spread behind the medians
            for key in ("p50_ms", "p99_ms", "max_ms", "missed", "us_per_vehicle_cycle"):
                vals = sorted(x[key] for x in runs)
                print(f"       {key}: " + " ".join(f"{v:.2f}" for v in vals), flush=True)


if __name__ == "__main__":
    main()
