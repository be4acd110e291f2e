"""The asyncio shell of the station: links (UDP/TCP), the station lifetime,
the control loop in vehicle time, the status line and summary, and
``run_mission`` behind ``gcs-swarm run``.
"""

from __future__ import annotations

from gcs_swarm.control.loop import ControlLoop, StepResult
from gcs_swarm.runtime.links import Endpoint, Link, LinkStats, parse_connection
from gcs_swarm.runtime.run import (
    END_MODES,
    emulator_config,
    run_mission,
    station_config,
)
from gcs_swarm.runtime.station import Station, StationConfig, VehiclePlan
from gcs_swarm.runtime.summary import RunSummary, VehicleAtEnd

__all__ = [
    "END_MODES",
    "ControlLoop",
    "Endpoint",
    "Link",
    "LinkStats",
    "RunSummary",
    "Station",
    "StationConfig",
    "StepResult",
    "VehicleAtEnd",
    "VehiclePlan",
    "emulator_config",
    "parse_connection",
    "run_mission",
    "station_config",
]
