"""MAVLink 2 signing on both ends (issue 9). The mission names the key
(``mission.signing.key_env``); the station and the bundled emulator sign
everything and drop unsigned, wrongly signed and replayed frames.

The closed loop: the station listens (``udpin``) and the emulator sends to it
(``out``), in lockstep, ideal dynamics. An attacker on 127.0.0.1 sends forged
setpoints and commands to every vehicle's port and forged telemetry to the
station's port, each kind unsigned, signed with a wrong key, and replayed
(signed with the right key, but with timestamps older than the genuine
stream's). Every forged frame must be rejected (counted), and the flight must
end exactly where the same flight without the attacker ends."""

from __future__ import annotations

import asyncio
import dataclasses
import socket
import time
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.errors import StartupError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import Codec, MessageSpec
from gcs_swarm.mission import Mission, Signing
from gcs_swarm.runtime.run import signing_key, station_config
from gcs_swarm.runtime.station import Station
from gcs_swarm.runtime.summary import RunSummary
from sim_vehicle import Emulator
from tests.station.station_harness import lockstep_config, mission_from

KEY = bytes(range(100, 132))
WRONG = bytes(range(32))
ENV = "GCS_SWARM_TEST_SIGNING_KEY"


def _signed_mission(monkeypatch: pytest.MonkeyPatch) -> Mission:
    monkeypatch.setenv(ENV, KEY.hex())
    m = mission_from("example1_octahedron.yaml", n=3, duration=6.0)
    settings = dataclasses.replace(m.settings, signing=Signing(key_env=ENV))
    return dataclasses.replace(m, settings=settings)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _telemetry(sysid: int) -> MessageSpec:
    return MessageSpec(
        "LOCAL_POSITION_NED",
        {"time_boot_ms": 4_000_000, "x": 50.0, "y": 50.0, "z": -50.0,
         "vx": 9.0, "vy": 9.0, "vz": 9.0},
    )  # fmt: skip


def _forgeries(
    sysids: list[int], replay_station: Codec, replay_vehicle: dict[int, Codec]
) -> tuple[list[bytes], list[bytes]]:
    """(to the vehicles, to the station): unsigned, wrong key, replayed."""
    to_vehicles: list[bytes] = []
    to_station: list[bytes] = []
    for s in sysids:
        setpoint = b.accel_setpoint(s, 1, 0, (0.0, 0.0, -9.0))  # full climb
        land = b.set_mode(s, 1, b.COPTER_MODES["LAND"])
        disarm = MessageSpec("COMMAND_LONG", {
            "target_system": s, "target_component": 1, "command": 400,
            "confirmation": 0, "param1": 0.0, "param2": 21196.0, "param3": 0.0,
            "param4": 0.0, "param5": 0.0, "param6": 0.0, "param7": 0.0})  # fmt: skip
        wrong = Codec(signing_key=WRONG, unix_s=time.time())
        for codec in (Codec(), wrong, replay_station):
            to_vehicles += [codec.encode(m) for m in (setpoint, land, disarm)]
        for codec in (
            Codec(s, 1),
            Codec(s, 1, signing_key=WRONG, unix_s=time.time()),
            replay_vehicle[s],
        ):
            to_station += [codec.encode(_telemetry(s)), codec.encode(b.heartbeat())]
    return to_vehicles, to_station


@dataclasses.dataclass
class _Flight:
    positions: dict[int, np.ndarray]
    modes: set[str]
    station_rejected: int
    emulator_rejected: int
    forged_to_vehicles: int
    forged_to_station: int


async def _fly(mission: Mission, *, attack: bool) -> _Flight:
    port = _free_port()
    cfg = dataclasses.replace(lockstep_config(mission), out=("127.0.0.1", port))
    assert cfg.signing_key == KEY
    sysids = [v.sysid for v in mission.vehicles]
    # "Captured" now, replayed later: the genuine streams' timestamps are newer by then.
    replay_station = Codec(signing_key=KEY, unix_s=time.time())
    replay_vehicle = {s: Codec(s, 1, signing_key=KEY, unix_s=time.time()) for s in sysids}
    to_vehicles, to_station = _forgeries(sysids, replay_station, replay_vehicle)
    await asyncio.sleep(0.05)  # the genuine signers start after the captures
    links = {s: f"udpin:127.0.0.1:{port}" for s in sysids}
    sent = [0, 0]
    async with asyncio.timeout(60), Emulator(cfg) as emu:
        async with Station(station_config(mission, links, lockstep=True)) as station:

            async def attacker() -> None:
                await emu.wait_until(lambda: emu.sim_time_s >= 2.0)
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                    for _ in range(5):
                        for ep in emu.endpoints.values():
                            for frame in to_vehicles:
                                sock.sendto(frame, ep)
                                sent[0] += 1
                        for frame in to_station:
                            sock.sendto(frame, ("127.0.0.1", port))
                            sent[1] += 1
                        await emu.wait_steps(10)

            task = asyncio.create_task(attacker()) if attack else None
            await station.ready()
            await station.fly()
            if task is not None:
                await task
            await station.end()
            link = next(iter(station.links.values()))
            # The run summary (summary.json's "links") reports the same count.
            summary = RunSummary.from_station(station, outcome="completed", wall_time_s=0.0)
            assert summary.signature_rejected == link.stats.signature_rejected
            return _Flight(
                {s: vp.state_mission()[0] for s, vp in station.vehicles.items()},
                {vp.mode_name for vp in station.vehicles.values()},
                link.stats.signature_rejected,
                emu.stats.link.signature_rejected,
                *sent,
            )


def test_forged_and_replayed_frames_are_all_rejected_and_change_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    mission = _signed_mission(monkeypatch)
    clean = asyncio.run(_fly(mission, attack=False))
    attacked = asyncio.run(_fly(mission, attack=True))
    assert clean.station_rejected == clean.emulator_rejected == 0
    # 100 % of the forgeries rejected, by signature, on both ends.
    assert attacked.forged_to_vehicles == 5 * 3 * 27 and attacked.forged_to_station == 5 * 18
    assert attacked.emulator_rejected == attacked.forged_to_vehicles
    assert attacked.station_rejected == attacked.forged_to_station
    # Nothing changed: same modes, same end positions (lockstep is deterministic;
    # 1e-9 m allows only float noise).
    assert clean.modes == attacked.modes == {"BRAKE"}
    for s, p in clean.positions.items():
        np.testing.assert_allclose(attacked.positions[s], p, atol=1e-9)


def test_the_key_comes_from_the_environment_or_a_file_and_is_never_shown(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    mission = _signed_mission(monkeypatch)
    assert signing_key(mission) == KEY
    key_file = tmp_path / "swarm.key"
    key_file.write_bytes(KEY)
    by_file = dataclasses.replace(
        mission,
        settings=dataclasses.replace(mission.settings, signing=Signing(key_file=str(key_file))),
    )
    assert signing_key(by_file) == KEY
    cfg = lockstep_config(mission)
    assert KEY.hex() not in repr(cfg) and str(KEY) not in repr(cfg)
    monkeypatch.setenv(ENV, "not a key " + KEY.hex()[:20])
    with pytest.raises(StartupError) as err:
        signing_key(mission)
    assert KEY.hex()[:20] not in str(err.value) and "bytes" in str(err.value)
    monkeypatch.delenv(ENV)
    with pytest.raises(StartupError, match=f"{ENV} is not set"):
        signing_key(mission)


def test_standalone_emulator_takes_the_key_from_the_environment(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from sim_vehicle.cli import build_config, parse_args

    monkeypatch.setenv(ENV, KEY.hex())
    assert build_config(parse_args(["--signing-key-env", ENV])).signing_key == KEY
    monkeypatch.setenv(ENV, "00" * 31)
    with pytest.raises(ValueError, match="not 64 hex digits") as err:
        build_config(parse_args(["--signing-key-env", ENV]))
    assert "00" * 31 not in str(err.value)
    # Without a key there is no signing, and the station listens where it is told:
    # the bundled emulator and every shipped sim link bind 127.0.0.1.
    assert build_config(parse_args([])).signing_key is None
    assert lockstep_config(mission_from("example1_octahedron.yaml")).host == "127.0.0.1"
