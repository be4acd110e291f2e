"""The shards' Zenoh bus over quic/ and tls/ with mutual TLS, on 127.0.0.1
(``gcs_swarm.runtime.zbus``; docs/architecture.md, "Shards between hosts").

The CA and the certificates are made at test time (``tls_harness``): the
controller's names 127.0.0.1, each shard has its own, all signed by one CA.

- a controller ``Bus`` listening on ``quic/127.0.0.1:<free port>`` (and
  ``tls/``) and a shard ``Bus`` connecting with the CA's files exchange
  messages both ways;
- a shard whose CA did not sign the controller's certificate, and one whose
  own certificate the controller's CA did not sign (mutual TLS), never
  join: nothing either sends is received in ``REFUSED_S``, while a good
  shard on the same controller is;
- a ``Bus`` refuses a quic/ endpoint without TLS files, and TLS files
  without a quic/ or tls/ endpoint.
"""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Callable

import pytest

from gcs_swarm.errors import UsageError
from gcs_swarm.runtime.zbus import Bus
from tests.station.tls_harness import Pki, make_pki

EXCHANGE_S = 20.0
"""Bound on a good exchange [s] (measured: 0.1 s on 127.0.0.1; generous
for a loaded 2-core machine: it ends as soon as both messages arrived)."""

REFUSED_S = 2.0
"""How long a refused shard is watched [s], after the good shard on the same
controller got through (which measured 0.1 s): Zenoh opens the connection at
once and retries every second or more after a failure, so this covers the
first attempt and a retry; a certificate is refused every time, not by chance."""


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))


@pytest.fixture(scope="module")
def foreign(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    """Another CA's files: a stranger's."""
    return make_pki(tmp_path_factory.mktemp("foreign"))


@pytest.mark.parametrize("scheme", ["quic", "tls"])
def test_a_shard_with_the_ca_s_files_exchanges_messages_with_its_controller(
    scheme: str, pki: Pki
) -> None:
    up: list[bytes] = []
    down: list[bytes] = []

    async def main() -> None:
        async with (
            Bus.on_free_port(scheme, tls=pki.controller) as controller,
            Bus(connect=[controller.listen[0]], tls=pki.shard) as shard,
        ):
            controller.subscribe("t/up", lambda key, data: up.append(data))
            shard.subscribe("t/down", lambda key, data: down.append(data))
            async with asyncio.timeout(EXCHANGE_S):
                while not (up and down):  # either may be declared before the link is up
                    shard.put("t/up", b"hello")
                    controller.put("t/down", b"assign")
                    await asyncio.sleep(0.05)

    asyncio.run(main())
    assert set(up) == {b"hello"} and set(down) == {b"assign"}


def test_a_shard_without_the_right_ca_or_certificate_never_joins(pki: Pki, foreign: Pki) -> None:
    """Three shards on one controller (quic/): the good one gets through; the
    one that trusts another CA (and has that CA's certificate) and the one
    that trusts the right CA but shows another CA's certificate (refused by
    mutual TLS) receive nothing, and nothing they send is received."""
    wrong_cert = dataclasses.replace(pki.shard, cert=foreign.shard.cert, key=foreign.shard.key)
    shards = {"good": pki.shard, "foreign_ca": foreign.shard, "foreign_cert": wrong_cert}
    up: dict[str, list[bytes]] = {name: [] for name in shards}
    down: dict[str, list[bytes]] = {name: [] for name in shards}

    async def main() -> None:
        good = asyncio.Event()

        def heard(into: list[bytes]) -> Callable[[str, bytes], None]:
            def on(key: str, data: bytes) -> None:
                into.append(data)
                if up["good"] and down["good"]:
                    good.set()

            return on

        async with Bus.on_free_port("quic", tls=pki.controller) as controller:
            endpoint = controller.listen[0]
            for name in shards:
                controller.subscribe(f"t/up/{name}", heard(up[name]))
            buses = [Bus(connect=[endpoint], tls=files) for files in shards.values()]
            await asyncio.gather(*(bus.__aenter__() for bus in buses))  # 0.5 s each, at once
            for name, bus in zip(shards, buses, strict=True):
                bus.subscribe("t/down", heard(down[name]))

            async def chatter() -> None:
                while True:
                    controller.put("t/down", b"beat")
                    for name, bus in zip(shards, buses, strict=True):
                        bus.put(f"t/up/{name}", b"hello")
                    await asyncio.sleep(0.1)

            talking = asyncio.ensure_future(chatter())
            try:
                async with asyncio.timeout(EXCHANGE_S):
                    await good.wait()
                await asyncio.sleep(REFUSED_S)
            finally:
                talking.cancel()
                for bus in buses:
                    await bus.__aexit__(None, None, None)

    asyncio.run(main())
    assert up["good"] and down["good"]
    for name in ("foreign_ca", "foreign_cert"):
        assert (up[name], down[name]) == ([], []), name


def test_a_bus_refuses_quic_without_tls_files_and_tls_files_without_quic(pki: Pki) -> None:
    with pytest.raises(UsageError, match="quic/ and tls/ endpoints need TLS files"):
        Bus(listen=["quic/127.0.0.1:7447"])
    with pytest.raises(UsageError, match="TLS files are for quic/ and tls/ endpoints only"):
        Bus(connect=["tcp/127.0.0.1:7447"], tls=pki.shard)
