"""One value for each default (issue 16): what a mission leaves out, what
``StationConfig`` and ``ProtocolConfig`` default to, must be the same, so a
flight scripted through the runtime or the protocol takes off, times out and
ends as one flown from a mission file does. ``StationConfig`` takes its
shared defaults from ``ProtocolConfig``; the mission layer (which imports
neither) is held to them here."""

from __future__ import annotations

import dataclasses

from gcs_swarm.mavlink.states import ProtocolConfig
from gcs_swarm.mission import parse_mission
from gcs_swarm.mission.model import Settings, Startup
from gcs_swarm.runtime.config import StationConfig
from gcs_swarm.runtime.run import END_MODES, station_config

_STATION_VS_PROTOCOL = {
    "rate_hz": "control_rate_hz",
    "end_mode": "end_mode",
    "stale_timeout_s": "stale_timeout_s",
    "guid_timeout_s": "guid_timeout_s",
    "takeoff_alt_m": "takeoff_min_alt_m",
    "start_tolerance_m": "goto_tolerance_m",
    "start_speed_tolerance_mps": "goto_speed_tolerance_mps",
    "command_attempts": "command_attempts",
    "velocity_bias": "velocity_bias",
}


def _defaults(cls: type) -> dict[str, object]:
    out: dict[str, object] = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return out


def test_station_config_defaults_are_the_protocols() -> None:
    station, protocol = _defaults(StationConfig), _defaults(ProtocolConfig)
    got = {k: station[k] for k in _STATION_VS_PROTOCOL}
    want = {k: protocol[v] for k, v in _STATION_VS_PROTOCOL.items()}
    assert got == want
    # and what the station hands its protocols, from its defaults:
    law = parse_mission("vehicles:\n  - {sysid: 1, start: [0, 0, 5]}\n").law
    pc = StationConfig(vehicles=(), law=law).protocol_config()
    assert {k: getattr(pc, v) for k, v in _STATION_VS_PROTOCOL.items()} == want


def test_a_mission_that_says_nothing_flies_the_station_defaults() -> None:
    mission = parse_mission("vehicles:\n  - {sysid: 1, start: [0, 0, 5]}\n")
    cfg = station_config(mission, {1: "sim"})
    station = _defaults(StationConfig)
    for name in _STATION_VS_PROTOCOL:
        assert getattr(cfg, name) == station[name], name
    s, st = Settings(name=""), Startup()
    assert (s.rate, END_MODES[s.end], s.stale_timeout) == (
        station["rate_hz"],
        station["end_mode"],
        station["stale_timeout_s"],
    )
    assert (st.takeoff_alt, st.guid_timeout, st.ready_timeout) == (
        station["takeoff_alt_m"],
        station["guid_timeout_s"],
        station["ready_timeout_s"],
    )
    assert (s.duration, st.start_tolerance, st.start_speed_tolerance, st.command_attempts) == (
        station["duration_s"], station["start_tolerance_m"],
        station["start_speed_tolerance_mps"], station["command_attempts"],
    )  # fmt: skip
