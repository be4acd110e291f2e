"""Hostile bytes on both receive paths (issue 9): random bytes, truncated
frames, bad CRCs, wrong lengths, unknown ids, MAVLink 1 noise and valid frames
carrying NaN, infinities and 1e30, fed to the station's UDP receive path (link,
codec, station, vehicle protocols) and to the emulator's (endpoint parser,
autopilot). Nothing may raise, bad frames are counted, and no non-finite or
absurd number may reach the station's vehicle state or the emulated physics.

``FUZZ_FRAMES`` (default 10^5 per path) sets the count; the README's 10^6 run
is ``FUZZ_FRAMES=1000000 pytest tests/reliability/test_fuzz.py``."""

from __future__ import annotations

import asyncio
import math
import os

import numpy as np
from fuzzframes import STATION_INBOUND, VEHICLE_INBOUND, datagrams

from gcs_swarm.mavlink.inbound import POSITION_LIMIT_M, SPEED_LIMIT_MPS
from gcs_swarm.mission import load_mission
from gcs_swarm.runtime.station import Station, StationConfig, VehiclePlan
from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec
from tests.station.station_harness import MISSIONS

N = int(os.environ.get("FUZZ_FRAMES", "100000"))
SEED = int(os.environ.get("FUZZ_SEED", "9"))


def _station_config() -> StationConfig:
    law = load_mission(MISSIONS / "example1_octahedron.yaml").law
    plans = tuple(VehiclePlan(s, "udpin:127.0.0.1:0", (float(s), 0.0, 2.0), 10.0) for s in (1, 2))
    return StationConfig(vehicles=plans, law=law, ready_timeout_s=600.0)


def test_station_receive_path_survives_hostile_datagrams() -> None:
    async def main() -> None:
        async with Station(_station_config()) as station:
            link = next(iter(station.links.values()))
            assert link._udp is not None
            proto = link._udp.get_protocol()
            peer = ("127.0.0.1", 40001)
            for i, data in enumerate(datagrams(SEED, N, STATION_INBOUND, sysid=1)):
                proto.datagram_received(data, peer)  # type: ignore[attr-defined]
                if i % 1000 == 0:
                    await asyncio.sleep(0)  # let timers (retries, stale checks) run
            stats = link.stats
            # A quarter are valid frames, every other is malformed in some way:
            # each is counted as a bad packet or an unknown message.
            assert stats.bad_packets + stats.unknown_messages > N // 2, stats
            assert stats.received > N // 10, stats
            vp = station.vehicles[1]
            assert vp.rejected_values > N // 100  # NaN / 1e30 telemetry was seen, and refused
            print(f"station path, {N} datagrams: {stats.received} messages decoded,"
                  f" {stats.bad_packets} bad packets, {stats.unknown_messages} unknown ids,"
                  f" {vp.rejected_values} implausible values refused")  # fmt: skip
            if vp.position is not None:
                p = vp.position
                values = (p.x, p.y, p.z, p.vx, p.vy, p.vz)
                assert all(math.isfinite(v) for v in values)
                assert max(abs(v) for v in values[:3]) <= POSITION_LIMIT_M
                assert max(abs(v) for v in values[3:]) <= SPEED_LIMIT_MPS
            if vp.offset_m is not None:
                assert np.isfinite(vp.offset_m).all()

    asyncio.run(main())


def test_emulator_receive_path_survives_hostile_datagrams() -> None:
    spec = VehicleSpec(sysid=1, start_ned_m=(0.0, 0.0, -10.0), airborne=True)
    cfg = EmulatorConfig(vehicles=(spec,), clock="lockstep", dynamics="ideal", speedup=1000.0)

    async def main() -> None:
        async with Emulator(cfg) as emu:
            ep = emu.core.vehicles[1].ep
            peer = ("127.0.0.1", 40002)
            for i, data in enumerate(datagrams(SEED, N, VEHICLE_INBOUND, sysid=255)):
                ep.datagram_received(data, peer)
                if i % 1000 == 0:
                    await asyncio.sleep(0)  # physics steps run in between
            stats = emu.stats.link
            assert stats.bad_frames + stats.unknown_frames > N // 2, stats
            assert stats.unknown_frames > 0, stats
            assert emu.step_count > 0
            assert emu.core.vehicles[1].ap.rejected > N // 1000  # NaN / 1e30 commands refused
            print(f"emulator path, {N} datagrams: {stats.bad_frames} bad frames,"
                  f" {stats.unknown_frames} unknown ids,"
                  f" {emu.core.vehicles[1].ap.rejected} hostile numbers refused")  # fmt: skip
            f = emu.fleet
            for arr in (f.pos, f.vel, f.acc):
                assert np.isfinite(arr).all()
            state = emu.vehicle_state(1)
            assert all(math.isfinite(v) for v in state.params.values())

    asyncio.run(main())
