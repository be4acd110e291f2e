"""What the shards' bus adds to a step: a Zenoh round trip between two processes.

Run from the repository root: ``python benchmarks/bench_zbus.py`` (about 30 s).

A sharded step crosses ``gcs_swarm.runtime.zbus.Bus`` twice: a shard puts its
state batch, the controller's loop gets it (Zenoh's thread hands it over with
``call_soon_threadsafe``), steps, and puts a reply that the shard's loop gets.
This measures those two crossings with nothing else: this process puts a
batch of ``24 + 60 K`` bytes (``shard_wire.StateBatch`` of K vehicles) at
``--rate`` per second, a child process (``--echo``, as a controller) answers
each on its loop with ``24 + 28 R`` bytes (a ``SetpointReply`` of R vehicles),
and the round trip is timed from before the put to the reply's handler on
this process's loop. Also: how long ``Bus.put`` itself holds the caller.
Shared memory on (as ``run_sharded``) and off. Two processes on one machine,
as ``gcs-swarm run --shards``; nothing else runs, so the figures are the
bus's floor: under load each crossing also waits for a core
(benchmarks/README.md, "Scale, 2026-12-05 (sixth session)").

    .venv/bin/python benchmarks/bench_zbus.py [--rate 300] [--count 3000]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gcs_swarm.runtime.zbus import Bus
from gcs_swarm.swarm.shard_wire import (
    HEADER_BYTES,
    REPLY_BYTES_PER_VEHICLE,
    STATE_BYTES_PER_VEHICLE,
)

CASES = ((250, 250), (1500, 250))
"""(vehicles in a state batch, vehicles answered): a shard of one network of
250, and one shard of 1,500 vehicles on six networks answered a network at a
time (``step: network``)."""


async def _echo(endpoint: str, shm: bool) -> None:
    """The child: answer every ping with a pong of the size the ping asks for."""
    async with Bus(connect=[endpoint], shm=shm) as bus:
        heard, done = asyncio.Event(), asyncio.Event()

        def on_ping(key: str, data: bytes) -> None:
            heard.set()
            if data == b"end":
                done.set()
            elif data != b"go":
                size = int.from_bytes(data[:4], "little")
                bus.put("pong/0", data[4:12] + bytes(size - 8))

        bus.subscribe("ping/*", on_ping)
        while not heard.is_set():  # until the other side is connected and heard us
            bus.put("pong/0", b"hello")
            await asyncio.sleep(0.05)
        await done.wait()


async def _measure(size_up: int, size_down: int, rate: float, count: int, shm: bool) -> str:
    bus = Bus.on_free_port(shm=shm)
    async with bus:
        got: dict[int, float] = {}
        hello = asyncio.Event()

        def on_pong(key: str, data: bytes) -> None:
            if data == b"hello":
                hello.set()
            else:
                got[int.from_bytes(data[:8], "little")] = time.perf_counter()

        bus.subscribe("pong/*", on_pong)
        child = await asyncio.create_subprocess_exec(
            sys.executable, __file__, "--echo", bus.listen[0], *([] if shm else ["--no-shm"])
        )
        try:
            async with asyncio.timeout(20):
                await hello.wait()
            bus.put("ping/0", b"go")
            await asyncio.sleep(0.5)
            pad = bytes(size_up - 12)
            sent: dict[int, float] = {}
            held: list[float] = []
            t0 = time.perf_counter()
            for i in range(count):
                delay = t0 + i / rate - time.perf_counter()
                if delay > 0:
                    await asyncio.sleep(delay)
                data = size_down.to_bytes(4, "little") + i.to_bytes(8, "little") + pad
                sent[i] = time.perf_counter()
                bus.put("ping/0", data)
                held.append(time.perf_counter() - sent[i])
            await asyncio.sleep(0.5)
            bus.put("ping/0", b"end")
        finally:
            try:
                await asyncio.wait_for(child.wait(), 10)
            except TimeoutError:
                child.kill()
                await child.wait()
    rtt = np.array([got[i] - sent[i] for i in sent if i in got]) * 1e3
    put = np.array(held) * 1e3
    lost = count - len(rtt)
    return (
        f"{size_up:>7} {size_down:>6} {'on' if shm else 'off':>4} "
        f"{np.percentile(put, 50):7.3f} {np.percentile(put, 99):7.3f} "
        f"{np.percentile(rtt, 50):7.3f} {np.percentile(rtt, 99):7.3f} {rtt.max():7.3f} {lost:5}"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=300.0, help="batches per second (300: 6 x 50 Hz)")
    p.add_argument("--count", type=int, default=3000)
    p.add_argument("--echo", metavar="ENDPOINT", help=argparse.SUPPRESS)
    p.add_argument("--no-shm", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.echo:
        asyncio.run(_echo(a.echo, not a.no_shm))
        return
    print(f"Zenoh round trip between two processes, {a.count} batches at {a.rate:g}/s")
    print("  bytes up / down  shm  put p50 put p99  rtt p50 rtt p99 rtt max  lost  [ms]")
    for up, down in CASES:
        for shm in (True, False):
            size_up = HEADER_BYTES + STATE_BYTES_PER_VEHICLE * up
            size_down = HEADER_BYTES + REPLY_BYTES_PER_VEHICLE * down
            print("  " + asyncio.run(_measure(size_up, size_down, a.rate, a.count, shm)))


if __name__ == "__main__":
    main()
