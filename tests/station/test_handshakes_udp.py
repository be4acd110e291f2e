"""``mission.startup.handshakes_per_network`` end to end: the station over
real UDP on 127.0.0.1 against the bundled emulator in lockstep, two
networks of three (config/missions/example1_networks.yaml, from the ground),
one vehicle of each network configuring at a time. The run's own log
says, in order, when each vehicle began and ended its handshake; the
formation then flies and forms as without the bound."""

from __future__ import annotations

import asyncio
import dataclasses
import re
from pathlib import Path

import numpy as np
from station_harness import mission_from

from gcs_swarm.mavlink.states import Phase
from gcs_swarm.runtime import RunSummary, run_mission

_PHASE = re.compile(r"^vehicle (blue|red):(\d): ([a-z_]+)$")


def _fly(window: int | None, log_dir: Path) -> RunSummary:
    mission = mission_from("example1_networks.yaml", duration=20.0)
    startup = dataclasses.replace(mission.settings.startup, handshakes_per_network=window)
    mission = dataclasses.replace(
        mission, settings=dataclasses.replace(mission.settings, startup=startup)
    )

    async def go() -> RunSummary:
        async with asyncio.timeout(120):
            return await run_mission(mission, log_dir=log_dir, picture=False, end_timeout_s=5.0)

    return asyncio.run(go())


def _most_configuring(log: tuple[str, ...]) -> dict[str, int]:
    """The most vehicles of each network configuring at once, replayed from
    the log's phase lines (a vehicle is in CONFIGURING from its
    ``configuring`` line to its next phase line)."""
    inside: dict[str, set[str]] = {"blue": set(), "red": set()}
    most = {"blue": 0, "red": 0}
    for line in log:
        if (m := _PHASE.match(line)) is None:
            continue
        now = inside[m[1]]
        if m[3] == Phase.CONFIGURING.value:
            now.add(m[2])
        else:
            now.discard(m[2])
        most[m[1]] = max(most[m[1]], len(now))
    return most


def test_one_handshake_per_network_at_a_time_then_the_formation_forms(tmp_path: Path) -> None:
    free = _fly(None, tmp_path / "free")
    gated = _fly(1, tmp_path / "gated")
    assert _most_configuring(free.log) == {"blue": 3, "red": 3}  # unbounded: all at once
    assert _most_configuring(gated.log) == {"blue": 1, "red": 1}
    assert gated.outcome == free.outcome == "completed"
    assert [v.label for v in gated.vehicles] == [v.label for v in free.vehicles]
    # Both forming towards Example 1's octahedron (2.48418 m; within 1 % at
    # 20 s as tests/station/test_networks.py). They start the formation from
    # slightly different hover states (the gated vehicles waited at their
    # starts for different times), so they agree to that, not bit for bit.
    for flight in (free, gated):
        radii = np.array([v.radius_m for v in flight.vehicles], dtype=float)
        np.testing.assert_allclose(radii, 2.48418, atol=0.025)
    assert (gated.setpoints_dropped, gated.bad_packets) == (0, 0)
