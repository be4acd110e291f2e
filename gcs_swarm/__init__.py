"""gcs_swarm: a MAVLink ground station that flies a drone swarm in formation.

Layers (imports flow one way, ``runtime -> mavlink -> control``):

- ``gcs_swarm.control``: the formation law, pure numpy, no I/O;
- ``gcs_swarm.mavlink``: codec and per-vehicle protocol state, no I/O;
- ``gcs_swarm.runtime``: asyncio transports, the station, logging;
- ``gcs_swarm.mission``: YAML mission files into frozen dataclasses;
- ``gcs_swarm.cli``: the ``gcs-swarm`` command line.
"""

from __future__ import annotations

from gcs_swarm.errors import (
    ExpressionError,
    InfeasibleError,
    LinkError,
    MissionError,
    StartupError,
    SwarmError,
    VehicleError,
)

__version__ = "0.1.0"

__all__ = [
    "ExpressionError",
    "InfeasibleError",
    "LinkError",
    "MissionError",
    "StartupError",
    "SwarmError",
    "VehicleError",
    "__version__",
]
