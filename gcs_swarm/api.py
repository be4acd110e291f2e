"""The public Python API: fly, simulate and read a mission from a script.

A façade over the layers, with the command line's defaults::

    import gcs_swarm

    mission = gcs_swarm.load_mission("config/missions/example1_octahedron.yaml")
    summary = gcs_swarm.run(mission, log_dir="runs")   # blocks, as `gcs-swarm run`
    print(summary.format())                            # the text `gcs-swarm run` prints
    print(summary.outcome, summary.min_separation_m)

    result = gcs_swarm.simulate(mission)               # the law alone, no MAVLink
    print(result.text())

Inside your own event loop, ``await gcs_swarm.fly(mission)`` does what
``run`` does while your other tasks go on. Vehicles on ``link: sim`` are
flown on the bundled emulator, started on 127.0.0.1 for the run; the others
over their links (SITL or real vehicles: read README.md first). Errors are
``gcs_swarm.SwarmError`` and its subclasses: a bad mission raises
``MissionError`` before anything flies; a vehicle that cannot be readied,
``StartupError``. The run's outcome (completed, degraded, failed) is in the
summary, not an exception. Nothing here prints: ``on_status`` receives the
status lines the command line shows.

Everything else (``gcs_swarm.runtime.run_mission`` and its options, the
station, the law) is reachable in the sub-packages for those who need it.
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable
from pathlib import Path

from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.offline import MissionSimResult, simulate_mission
from gcs_swarm.runtime.run import run_mission
from gcs_swarm.runtime.summary import RunSummary

__all__ = ["fly", "run", "simulate"]

MissionLike = Mission | str | os.PathLike[str]


def _mission(mission: MissionLike) -> Mission:
    return mission if isinstance(mission, Mission) else load_mission(Path(mission))


async def fly(
    mission: MissionLike,
    *,
    log_dir: str | os.PathLike[str] | None = None,
    picture: bool = True,
    on_status: Callable[[str], None] | None = None,
) -> RunSummary:
    """Fly ``mission`` (a ``Mission`` or the path of its YAML file) and
    return its summary once every vehicle has ended.

    ``log_dir``: give the run a folder there (``flight.tlog``, the mission,
    ``summary.json`` and, unless ``picture`` is False, ``report.png``), as
    ``gcs-swarm run`` does with the mission's ``log.dir``; None writes nothing.
    ``on_status``: called with each status line. Cancelling the task ends the
    flight the defined way (zero acceleration, then the end action)."""
    m = _mission(mission)
    return await run_mission(
        m, on_status=on_status, log_dir=None if log_dir is None else Path(log_dir),
        picture=picture,
    )  # fmt: skip


def run(
    mission: MissionLike,
    *,
    log_dir: str | os.PathLike[str] | None = None,
    picture: bool = True,
    on_status: Callable[[str], None] | None = None,
) -> RunSummary:
    """``fly`` in a new event loop, blocking until the run has ended (the
    form for scripts; from inside a running event loop, await ``fly``)."""
    return asyncio.run(fly(mission, log_dir=log_dir, picture=picture, on_status=on_status))


def simulate(mission: MissionLike, *, duration_s: float | None = None) -> MissionSimResult:
    """The law alone on ideal point masses with the mission's envelope and
    safety filter (``gcs-swarm simulate``): no MAVLink, deterministic.
    ``duration_s`` overrides the mission's duration."""
    return simulate_mission(_mission(mission), duration_s=duration_s)
