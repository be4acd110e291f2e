"""The mission's ``emulator:`` keys reach the bundled emulator, and a shared
endpoint (every sim vehicle on one port) flies like separate ones."""

from __future__ import annotations

import asyncio
from pathlib import Path

from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.runtime import RunSummary, emulator_config, run_mission

MISSION = """\
mission: {name: emulator keys, duration: 2, rate: 50, end: hold}
emulator:
  mode: lockstep
  dynamics: ideal
  accel_max: 7.5
  noise_pos: 0.01
  noise_vel: 0.02
  spawn: air
  heartbeats: spread
  base_port: 0
  shared: %s
vehicles:
  - {sysid: 1, start: [2, 0, 0], start_velocity: [0.25, -0.5, 0.125]}
  - {sysid: 2, start: [-2, 0, 0]}
"""


def _mission(tmp_path: Path, shared: bool) -> Mission:
    path = tmp_path / "m.yaml"
    path.write_text(MISSION % ("true" if shared else "false"))
    return load_mission(path)


def test_emulator_keys_reach_the_emulator_config(tmp_path: Path) -> None:
    cfg = emulator_config(_mission(tmp_path, shared=False))
    assert cfg.params == {"SIM_ACC_MAX": 7.5}
    assert (cfg.noise_pos_m, cfg.noise_vel_m_s) == (0.01, 0.02)
    assert all(v.airborne for v in cfg.vehicles)  # spawn: air
    # [east, north, up] in the mission, north-east-down in the emulator
    assert [v.start_vel_ned_m_s for v in cfg.vehicles] == [(-0.5, 0.25, -0.125), None]
    assert cfg.heartbeats == "spread"
    assert cfg.shared_port is None and cfg.base_port == 0
    shared = emulator_config(_mission(tmp_path, shared=True))
    assert shared.shared_port == 0
    # left out: together, as the emulator's own default (a SITL swarm's)
    path = tmp_path / "plain.yaml"
    path.write_text(MISSION.replace("  heartbeats: spread\n", "") % "false")
    assert emulator_config(load_mission(path)).heartbeats == "together"


def test_shared_endpoint_flies_both_vehicles(tmp_path: Path) -> None:
    mission = _mission(tmp_path, shared=True)

    async def fly() -> RunSummary:
        async with asyncio.timeout(60):
            return await run_mission(mission, end_timeout_s=5.0)

    summary = asyncio.run(fly())
    assert summary.outcome == "completed"
    # Both flew the whole formation on the one endpoint, at 50 Hz of vehicle time.
    assert summary.steps >= 2.0 * 50 - 1
    positions = summary.positions()
    assert sorted(positions) == [1, 2]
