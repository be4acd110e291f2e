"""Shared fixtures of the operator view's tests."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gcs_swarm.runtime import run_mission
from tests.station.station_harness import mission_from


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4 s lockstep run of the demo from the ground, logged."""
    mission = mission_from("example1_octahedron.yaml", duration=4.0)
    base = tmp_path_factory.mktemp("runs")
    folders: list[Path] = []

    async def main() -> None:
        async with asyncio.timeout(25.0):
            await run_mission(
                mission, log_dir=base, picture=False, on_folder=lambda f: folders.append(f.path)
            )

    asyncio.run(main())
    return folders[0]
