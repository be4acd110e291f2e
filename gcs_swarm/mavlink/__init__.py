"""MAVLink layer of the station, with no I/O: codec per peer, message builders
returning plain specs, typed inbound messages, the NED <-> mission frame
conversion (coordinates.py), the per-vehicle protocol state machine (time is
an argument) and the flying vehicles' telemetry table (telemetry_table.py).
"""

from __future__ import annotations

from gcs_swarm.mavlink.codec import STATION_COMPID, STATION_SYSID, Codec, CodecStats, MessageSpec
from gcs_swarm.mavlink.coordinates import (
    GeoOrigin,
    mission_to_ned,
    ned_to_mission,
    origin_offset_m,
    vector_mission_to_ned,
    vector_ned_to_mission,
)
from gcs_swarm.mavlink.inbound import Inbound, from_pymavlink
from gcs_swarm.mavlink.states import Phase, ProtocolConfig, ProtocolEvent, mode_name
from gcs_swarm.mavlink.vehicle import VehicleProtocol

__all__ = [
    "STATION_COMPID",
    "STATION_SYSID",
    "Codec",
    "CodecStats",
    "GeoOrigin",
    "Inbound",
    "MessageSpec",
    "Phase",
    "ProtocolConfig",
    "ProtocolEvent",
    "VehicleProtocol",
    "from_pymavlink",
    "mission_to_ned",
    "mode_name",
    "ned_to_mission",
    "origin_offset_m",
    "vector_mission_to_ned",
    "vector_ned_to_mission",
]
