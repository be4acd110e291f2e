"""Hand-made inbound messages and a scripted start-up for the unit tests of
``VehicleProtocol`` (a hand-advanced clock: no event loop, no sockets)."""

from __future__ import annotations

import numpy as np

from gcs_swarm.mavlink import GeoOrigin, MessageSpec, Phase, ProtocolConfig, VehicleProtocol
from gcs_swarm.mavlink.builders import COPTER_MODES, MAV_CMD_SET_MESSAGE_INTERVAL
from gcs_swarm.mavlink.inbound import (
    CommandAck,
    EkfStatus,
    GpsGlobalOrigin,
    GpsRaw,
    Heartbeat,
    LocalPositionNed,
    ParamValue,
)

SYS = 3
GUIDED, BRAKE, STABILIZE, LOITER = (
    COPTER_MODES[k] for k in ("GUIDED", "BRAKE", "STABILIZE", "LOITER")
)
REF = GeoOrigin(-35.0, 149.0, 600.0)
# Vehicle origin 100 m north-ish of the mission origin and 10 m below it.
ORIGIN = GeoOrigin(-35.0 + 100 / 6378137.0 * 180 / np.pi, 149.0, 590.0)


def hb(mode: int, armed: bool = False) -> Heartbeat:
    return Heartbeat(SYS, 1, 2, 3, 1 | (128 if armed else 0), mode, 4)


def pos(t_ms: int, ned: tuple[float, float, float], vel: tuple[float, float, float] = (0, 0, 0)):
    return LocalPositionNed(SYS, 1, t_ms, *ned, *vel)


def origin_msg() -> GpsGlobalOrigin:
    return GpsGlobalOrigin(
        SYS, 1, round(ORIGIN.lat_deg * 1e7), round(ORIGIN.lon_deg * 1e7), round(ORIGIN.alt_m * 1e3)
    )


def commands(out: list[MessageSpec], command: int) -> list[MessageSpec]:
    return [m for m in out if m.name == "COMMAND_LONG" and m["command"] == command]


def make(**kw: object) -> VehicleProtocol:
    cfg = ProtocolConfig(mission_origin=REF, **kw)  # type: ignore[arg-type]
    return VehicleProtocol(SYS, cfg, goto_m=(5.0, 0.0, 12.0))


def configure(
    vp: VehicleProtocol,
    now: float,
    *,
    mode: int = STABILIZE,
    armed: bool = False,
    landed_stream: int = 0,
):
    """Drive CONNECTING -> past CONFIGURING, answering every request (the
    EXTENDED_SYS_STATE stream with ``landed_stream``: 2 denied, as today's
    emulator; 0 accepted, as ArduCopter)."""
    vp.handle_message(hb(mode, armed), now)
    assert vp.phase is Phase.CONFIGURING
    streams = []
    for result in (0, 0, 0, landed_stream):
        out = vp.take_outbound()
        (cmd,) = commands(out, MAV_CMD_SET_MESSAGE_INTERVAL)
        streams.append(cmd["param1"])
        vp.handle_message(CommandAck(SYS, 1, MAV_CMD_SET_MESSAGE_INTERVAL, result), now)
    # LOCAL_POSITION_NED, EKF_STATUS_REPORT, GPS_RAW_INT, EXTENDED_SYS_STATE.
    assert streams == [32, 193, 24, 245]
    for name, value in (("GUID_TIMEOUT", 0.5), ("WP_YAW_BEHAVIOR", 0.0)):
        (ps,) = [m for m in vp.take_outbound() if m.name == "PARAM_SET"]
        assert ps["param_id"] == name and ps["param_value"] == value
        vp.handle_message(ParamValue(SYS, 1, name, value), now)
    return cmd


def ready_sensors(vp: VehicleProtocol, now: float, ned=(0.0, 0.0, 0.0)) -> None:
    vp.handle_message(origin_msg(), now)
    vp.handle_message(GpsRaw(SYS, 1, 3, 10), now)
    vp.handle_message(EkfStatus(SYS, 1, 1 | 2 | 4 | 8 | 16 | 32), now)
    vp.handle_message(pos(1000, ned), now)
