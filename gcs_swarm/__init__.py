"""gcs_swarm: a MAVLink ground station that flies a drone swarm in formation.

Fly a mission from Python (``examples/`` has short scripts)::

    import gcs_swarm

    summary = gcs_swarm.run("config/missions/example1_octahedron.yaml")
    print(summary.format())

The public API is what this package exports (``__all__``):

- ``load_mission(path)``, ``parse_mission(text)``: a YAML mission into a frozen
  ``Mission`` (``MissionError`` names file, line and key on a bad one);
- ``run(mission)`` (blocking) and ``await fly(mission)`` (in your own event
  loop): fly it, return its ``RunSummary``;
- ``simulate(mission)``: the law alone, no MAVLink (``MissionSimResult``);
- the exception tree, rooted at ``SwarmError`` (``gcs_swarm.errors``).

Layers (imports flow one way, ``view -> runtime -> swarm -> report -> mavlink ->
mission -> control``; docs/architecture.md):

- ``gcs_swarm.control``: the formation law and the control step, pure numpy;
- ``gcs_swarm.mavlink``: codec, per-vehicle protocol state and the flying
  vehicles' telemetry table, no I/O;
- ``gcs_swarm.swarm``: the station's core (membership, events, the step) and
  each link's policy, no I/O;
- ``gcs_swarm.runtime``: asyncio transports, the station, logging;
- ``gcs_swarm.view``: the operator view in a browser (frames, page, server);
- ``gcs_swarm.report``: flight records, logs, summaries and pictures;
- ``gcs_swarm.mission``: YAML mission files into frozen dataclasses;
- ``gcs_swarm.cli``: the ``gcs-swarm`` command line.

Importing the package is light: the station and the simulator are loaded on
first use of ``run``, ``fly``, ``simulate`` or their result types.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from gcs_swarm.errors import (
    ExpressionError,
    InfeasibleError,
    LinkError,
    MissionError,
    ReportError,
    StartupError,
    SwarmError,
    UsageError,
    VehicleError,
)

if TYPE_CHECKING:
    from gcs_swarm.api import fly, run, simulate
    from gcs_swarm.mission import Mission, load_mission, parse_mission
    from gcs_swarm.offline import MissionSimResult
    from gcs_swarm.runtime.summary import RunSummary

__version__ = "0.1.0"

__all__ = [
    "ExpressionError",
    "InfeasibleError",
    "LinkError",
    "Mission",
    "MissionError",
    "MissionSimResult",
    "ReportError",
    "RunSummary",
    "StartupError",
    "SwarmError",
    "UsageError",
    "VehicleError",
    "__version__",
    "fly",
    "load_mission",
    "parse_mission",
    "run",
    "simulate",
]

_LAZY = {
    "fly": "gcs_swarm.api",
    "run": "gcs_swarm.api",
    "simulate": "gcs_swarm.api",
    "Mission": "gcs_swarm.mission",
    "load_mission": "gcs_swarm.mission",
    "parse_mission": "gcs_swarm.mission",
    "MissionSimResult": "gcs_swarm.offline",
    "RunSummary": "gcs_swarm.runtime.summary",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'gcs_swarm' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
