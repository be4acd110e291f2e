"""The shards' Zenoh bus between two sessions on 127.0.0.1 (gcs_swarm.runtime.zbus):
a control message is never dropped, even behind a burst of large batches;
large payloads cross in shared memory on one host, and with shared memory
off on either side none does."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Iterator

import pytest

from gcs_swarm.errors import LinkError
from gcs_swarm.runtime.zbus import PICK_ATTEMPTS, SHM_THRESHOLD_BYTES, Bus, free_endpoint

BIG = 84 * 1000 + 24
"""A state batch of 1,000 vehicles [bytes] (24 + 60 per vehicle)."""

PACE_S = 0.02
"""One batch a control step at 50 Hz."""


class _Pair:
    """A listening session (the controller) and a connecting one (a shard)."""

    def __init__(self, *, ctl_shm: bool = True, shard_shm: bool = True) -> None:
        self.ctl = Bus.on_free_port(shm=ctl_shm)
        self.shard_shm = shard_shm
        self.shard = Bus()
        self.got: dict[str, list[bytes]] = {"state": [], "msg": []}
        self.arrived = asyncio.Event()

    async def open(self) -> None:
        await self.ctl.__aenter__()
        self.shard = Bus(connect=[self.ctl.listen[0]], shm=self.shard_shm)
        await self.shard.__aenter__()
        self.ctl.subscribe("up/0/state", lambda key, data: self._on("state", data))
        self.ctl.subscribe("up/0/msg", lambda key, data: self._on("msg", data))
        # A subscription reaches the other session through the link's
        # declarations: say hello until one arrives.
        async with asyncio.timeout(20):  # ~0.1 s on an idle machine
            while not self.got["msg"]:
                self.shard.put_json("up/0/msg", {"kind": "hello"})
                await asyncio.sleep(0.05)
        self.got["msg"].clear()
        self.ctl.samples_in = self.ctl.shm_in = 0

    async def close(self) -> None:
        await self.shard.__aexit__(None, None, None)
        await self.ctl.__aexit__(None, None, None)

    async def paced(self, marks: range, size: int) -> None:
        """Batches ``size`` bytes long, marked ``marks``, one step apart;
        return when all have come in."""
        for i in marks:
            self.shard.put("up/0/state", bytes([i]) * size, droppable=True)
            await asyncio.sleep(PACE_S)
        await self.wait("state", marks.stop)

    def _on(self, what: str, data: bytes) -> None:
        self.got[what].append(data)
        self.arrived.set()

    async def wait(self, what: str, n: int, timeout_s: float = 20.0) -> None:
        async with asyncio.timeout(timeout_s):
            while len(self.got[what]) < n:
                self.arrived.clear()
                await self.arrived.wait()


def test_control_messages_are_never_dropped_behind_a_burst_of_batches() -> None:
    """Fifty 84 kB batches at once (a stalled shard catching up), then twenty
    control messages: every control message arrives, in order; batches may
    be dropped (a newer one follows each step), any that arrive are intact
    and in order. Shared memory off, so the batches fill the TCP queue."""

    async def main() -> tuple[list[bytes], list[bytes]]:
        pair = _Pair(ctl_shm=False, shard_shm=False)
        await pair.open()
        try:
            for i in range(50):
                pair.shard.put("up/0/state", bytes([i]) * BIG, droppable=True)
            for i in range(20):
                pair.shard.put_json("up/0/msg", {"kind": "beat", "n": i})
            await pair.wait("msg", 20)
            await asyncio.sleep(0.2)  # any batch still under way
        finally:
            await pair.close()
        return pair.got["state"], pair.got["msg"]

    states, msgs = asyncio.run(main())
    assert [m.decode() for m in msgs] == [f'{{"kind": "beat", "n": {i}}}' for i in range(20)]
    marks = [s[0] for s in states]
    assert marks == sorted(marks) and all(s == bytes([s[0]]) * BIG for s in states)


def test_paced_large_batches_cross_in_shared_memory_small_ones_as_bytes() -> None:
    """Batches one step apart, as a shard sends them: after the first few
    (a new link), large ones come in shared memory;
    batches a byte under the threshold never do (measured: from 3,072 bytes on)."""

    async def main() -> tuple[int, int, int]:
        pair = _Pair()
        await pair.open()
        try:
            await pair.paced(range(10), BIG)
            first = pair.ctl.shm_in
            await pair.paced(range(10, 30), BIG)
            steady = pair.ctl.shm_in - first
            await pair.paced(range(30, 40), SHM_THRESHOLD_BYTES - 1)
            small = pair.ctl.shm_in - first - steady
        finally:
            await pair.close()
        assert [s[0] for s in pair.got["state"]] == list(range(40))
        return first, steady, small

    first, steady, small = asyncio.run(main())
    assert steady == 20, f"{steady} of 20 large batches in shared memory (first 10: {first})"
    assert small == 0


@pytest.mark.parametrize(("ctl_shm", "shard_shm"), [(False, True), (True, False)])
def test_shared_memory_off_on_either_side_sends_bytes(ctl_shm: bool, shard_shm: bool) -> None:
    """Shared memory is agreed per link: one side without it (a shard on
    another host has none to share) and every batch crosses as bytes."""

    async def main() -> Bus:
        pair = _Pair(ctl_shm=ctl_shm, shard_shm=shard_shm)
        await pair.open()
        try:
            await pair.paced(range(10), BIG)
        finally:
            await pair.close()
        return pair.ctl

    ctl = asyncio.run(main())
    assert (ctl.samples_in, ctl.shm_in) == (10, 0)


def _taken_then_free(holder: socket.socket, taken: int) -> Iterator[str]:
    """``taken`` ports held by ``holder``'s kind of socket, then free ones."""
    for _ in range(taken):
        yield f"tcp/127.0.0.1:{holder.getsockname()[1]}"
    while True:
        yield free_endpoint()


def test_a_free_port_taken_before_zenoh_binds_it_is_picked_again() -> None:
    """The race ``free_endpoint`` leaves open (its port is free when picked,
    another socket may bind it before Zenoh does), forced: the first two
    picks are a port a listening TCP socket holds. ``Bus.on_free_port``
    listens on the third, and a shard connecting there is heard."""
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        picks = _taken_then_free(holder, 2)
        tried: list[str] = []

        def pick(scheme: str) -> str:
            tried.append(next(picks))
            return tried[-1]

        async def main() -> list[bytes]:
            got: list[bytes] = []
            async with Bus.on_free_port(pick=pick) as ctl:
                assert ctl.listen == (tried[-1],)
                async with Bus(connect=[ctl.listen[0]]) as shard:
                    ctl.subscribe("t", lambda key, data: got.append(data))
                    async with asyncio.timeout(20):  # ~0.1 s on an idle machine
                        while not got:
                            shard.put("t", b"hello")
                            await asyncio.sleep(0.05)
            return got

        assert asyncio.run(main())[0] == b"hello"
        assert len(tried) == 3 and tried[0] == tried[1] != tried[2]


def test_a_given_port_that_is_taken_is_an_error_and_so_are_too_many_taken_picks() -> None:
    """An endpoint the user named is never swapped for another: taken, it is
    a ``LinkError`` naming it; and ``on_free_port`` gives up after
    ``PICK_ATTEMPTS`` taken picks (a machine out of ports), naming the last."""
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        endpoint = f"tcp/127.0.0.1:{holder.getsockname()[1]}"
        picks = _taken_then_free(holder, PICK_ATTEMPTS)

        async def main(bus: Bus) -> None:
            async with bus:
                pass

        with pytest.raises(LinkError, match=f"zenoh session on {endpoint}: .*in use"):
            asyncio.run(main(Bus(listen=[endpoint])))
        with pytest.raises(LinkError, match=f"zenoh session on {endpoint}: .*in use"):
            asyncio.run(main(Bus.on_free_port(pick=lambda scheme: next(picks))))
