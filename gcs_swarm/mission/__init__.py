"""Mission files: YAML in, a frozen ``Mission`` out, or every problem at once.

``load_mission(path)`` validates a file strictly (unknown keys, types, ranges
and cross-checks) and raises ``MissionError`` with one line per problem,
``file:line: key.path: message``. ``schema()`` is the JSON Schema of the
format; ``gcs-swarm check`` is ``gcs_swarm.commands.check_command``. The format is
described in ``docs/mission-format.md``.
"""

from __future__ import annotations

from gcs_swarm.mission.loader import describe, load_mission, parse_mission
from gcs_swarm.mission.model import (
    DEFAULT_SIM_HOME,
    Emulator,
    Event,
    Failsafe,
    GeoPoint,
    Impairments,
    LogSettings,
    Mission,
    Settings,
    Signing,
    Startup,
    Vehicle,
    enu_offset_m,
    geodetic_at,
)
from gcs_swarm.mission.schema import schema

__all__ = [
    "DEFAULT_SIM_HOME",
    "Emulator",
    "Event",
    "Failsafe",
    "GeoPoint",
    "Impairments",
    "LogSettings",
    "Mission",
    "Settings",
    "Signing",
    "Startup",
    "Vehicle",
    "describe",
    "enu_offset_m",
    "geodetic_at",
    "load_mission",
    "parse_mission",
    "schema",
]
