"""Builders of every message the station sends, returned as ``MessageSpec`` data.

Numbers and semantics follow ``shared/spec/mavlink-protocol.md``; each
builder names the section it implements. Frames: every position, velocity
and acceleration here is already in the vehicle's LOCAL_NED frame (north,
east, down, metres, relative to its own EKF origin); the mission-frame
conversion lives in ``gcs_swarm.mavlink.coordinates``.
"""

from __future__ import annotations

from gcs_swarm.mavlink.codec import MessageSpec

__all__ = [
    "COPTER_MODES",
    "MAV_CMD_COMPONENT_ARM_DISARM",
    "MAV_CMD_DO_SET_MODE",
    "MAV_CMD_NAV_LAND",
    "MAV_CMD_NAV_TAKEOFF",
    "MAV_CMD_REQUEST_MESSAGE",
    "MAV_CMD_SET_MESSAGE_INTERVAL",
    "MAV_FRAME_LOCAL_NED",
    "MSG_ID_EKF_STATUS_REPORT",
    "MSG_ID_ESTIMATOR_STATUS",
    "MSG_ID_EXTENDED_SYS_STATE",
    "MSG_ID_GPS_GLOBAL_ORIGIN",
    "MSG_ID_GPS_RAW_INT",
    "MSG_ID_LOCAL_POSITION_NED",
    "MSG_ID_SYS_STATUS",
    "TYPE_MASK_ACCEL",
    "TYPE_MASK_POSITION",
    "TYPE_MASK_POS_VEL",
    "TYPE_MASK_VEL_ACCEL",
    "accel_setpoint",
    "arm",
    "command_long",
    "heartbeat",
    "param_request_read",
    "param_set",
    "position_setpoint",
    "posvel_setpoint",
    "request_message",
    "set_message_interval",
    "set_mode",
    "set_mode_main_sub",
    "takeoff",
    "takeoff_amsl",
    "vel_accel_setpoint",
]

# MAV_CMD values (MAVLink common.xml).
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512

# Message ids the station asks for (mavlink-protocol.md, start-up step 2).
MSG_ID_SYS_STATUS = 1
MSG_ID_GPS_RAW_INT = 24
MSG_ID_LOCAL_POSITION_NED = 32
MSG_ID_GPS_GLOBAL_ORIGIN = 49
MSG_ID_EKF_STATUS_REPORT = 193
MSG_ID_ESTIMATOR_STATUS = 230
MSG_ID_EXTENDED_SYS_STATE = 245

MAV_FRAME_LOCAL_NED = 1
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_PARAM_TYPE_REAL32 = 9

TYPE_MASK_ACCEL = 3135
"""0x0C3F: ignore position (1|2|4), velocity (8|16|32), yaw (1024) and yaw
rate (2048); acceleration bits and FORCE_SET (512) clear
(mavlink-protocol.md, "The acceleration setpoint")."""

TYPE_MASK_VEL_ACCEL = 3079
"""0x0C07: velocity with the acceleration as its feed-forward; ignore
position (1|2|4), yaw (1024) and yaw rate (2048). PX4 v1.14 hands both to
its velocity PID (docs/setpoints.md, Eq. V1); ArduCopter 4.5 flies it as
its guided velocity sub-mode, and echoes 3079."""

TYPE_MASK_POSITION = 3576
"""0x0DF8: position only; ignore velocity (8|16|32), acceleration
(64|128|256), yaw (1024) and yaw rate (2048)."""

TYPE_MASK_POS_VEL = 3520
"""0x0DC0: position with the velocity as its feed-forward; ignore
acceleration (64|128|256), yaw (1024) and yaw rate (2048). ArduCopter 4.5
flies it as its guided pos-vel-accel sub-mode (acceleration zero), PX4
v1.14 as a position setpoint with a velocity feed-forward: a vehicle can
track a moving point with no steady lag (docs/mavlink-protocol.md)."""

COPTER_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "LAND": 9,
    "BRAKE": 17,
}
"""ArduCopter ``custom_mode`` numbers used by the station."""

MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4


def heartbeat() -> MessageSpec:
    """The station's 1 Hz HEARTBEAT: a GCS, no autopilot, active."""
    return MessageSpec(
        "HEARTBEAT",
        {
            "type": MAV_TYPE_GCS,
            "autopilot": MAV_AUTOPILOT_INVALID,
            "base_mode": 0,
            "custom_mode": 0,
            "system_status": MAV_STATE_ACTIVE,
            "mavlink_version": 3,
        },
    )


def command_long(
    target_system: int,
    target_component: int,
    command: int,
    params: tuple[float, ...] = (),
    *,
    confirmation: int = 0,
) -> MessageSpec:
    """COMMAND_LONG with up to seven parameters (missing ones are 0).

    ``confirmation`` counts retransmissions of the same command (0 first).
    """
    if len(params) > 7:
        raise ValueError("COMMAND_LONG carries at most 7 parameters")
    p = tuple(float(v) for v in params) + (0.0,) * (7 - len(params))
    fields: dict[str, int | float] = {
        "target_system": target_system,
        "target_component": target_component,
        "command": command,
        "confirmation": confirmation,
    }
    for i, value in enumerate(p, start=1):
        fields[f"param{i}"] = value
    return MessageSpec("COMMAND_LONG", fields)


def set_message_interval(
    target_system: int, target_component: int, message_id: int, interval_s: float
) -> MessageSpec:
    """MAV_CMD_SET_MESSAGE_INTERVAL (511): param1 message id, param2 interval [us]."""
    return command_long(
        target_system,
        target_component,
        MAV_CMD_SET_MESSAGE_INTERVAL,
        (message_id, round(interval_s * 1e6)),
    )


def request_message(target_system: int, target_component: int, message_id: int) -> MessageSpec:
    """MAV_CMD_REQUEST_MESSAGE (512): param1 = the message id, sent once."""
    return command_long(target_system, target_component, MAV_CMD_REQUEST_MESSAGE, (message_id,))


def set_mode(target_system: int, target_component: int, custom_mode: int) -> MessageSpec:
    """MAV_CMD_DO_SET_MODE (176): param1 = CUSTOM_MODE_ENABLED, param2 = Copter mode."""
    return command_long(
        target_system,
        target_component,
        MAV_CMD_DO_SET_MODE,
        (MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode),
    )


def arm(target_system: int, target_component: int, *, armed: bool = True) -> MessageSpec:
    """MAV_CMD_COMPONENT_ARM_DISARM (400): param1 = 1 arm, 0 disarm."""
    return command_long(
        target_system, target_component, MAV_CMD_COMPONENT_ARM_DISARM, (1.0 if armed else 0.0,)
    )


def set_mode_main_sub(
    target_system: int, target_component: int, main: int, sub: int
) -> MessageSpec:
    """MAV_CMD_DO_SET_MODE (176) as PX4 reads it: param1 = CUSTOM_MODE_ENABLED,
    param2 = main mode, param3 = sub mode (mavlink-protocol.md, PX4)."""
    return command_long(
        target_system,
        target_component,
        MAV_CMD_DO_SET_MODE,
        (MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub),
    )


def takeoff_amsl(target_system: int, target_component: int, altitude_amsl_m: float) -> MessageSpec:
    """MAV_CMD_NAV_TAKEOFF (22) as PX4 reads it: params 4-6 (yaw, latitude,
    longitude) NaN = "here, as you are"; param7 = altitude [m AMSL]. PX4
    takes 0 in params 5-6 as latitude/longitude 0 and never leaves the
    ground (mavlink-protocol.md, PX4)."""
    nan = float("nan")
    return command_long(
        target_system,
        target_component,
        MAV_CMD_NAV_TAKEOFF,
        (0.0, 0.0, 0.0, nan, nan, nan, altitude_amsl_m),
    )


def takeoff(target_system: int, target_component: int, altitude_m: float) -> MessageSpec:
    """MAV_CMD_NAV_TAKEOFF (22): param7 = altitude [m] above home."""
    return command_long(
        target_system,
        target_component,
        MAV_CMD_NAV_TAKEOFF,
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, altitude_m),
    )


def param_set(
    target_system: int,
    target_component: int,
    name: str,
    value: float,
    *,
    param_type: int = MAV_PARAM_TYPE_REAL32,
) -> MessageSpec:
    """PARAM_SET of a parameter, by default as REAL32 (ArduPilot converts to
    its own type). Another ``param_type`` sends ``value`` as it is: the
    caller has encoded it (PX4 carries an integer's bytes in the float)."""
    if len(name) > 16:
        raise ValueError(f"parameter name {name!r} longer than 16 characters")
    return MessageSpec(
        "PARAM_SET",
        {
            "target_system": target_system,
            "target_component": target_component,
            "param_id": name,
            "param_value": float(value),
            "param_type": param_type,
        },
    )


def param_request_read(target_system: int, target_component: int, name: str) -> MessageSpec:
    """PARAM_REQUEST_READ by name (param_index -1)."""
    return MessageSpec(
        "PARAM_REQUEST_READ",
        {
            "target_system": target_system,
            "target_component": target_component,
            "param_id": name,
            "param_index": -1,
        },
    )


def _local_ned_target(
    target_system: int,
    target_component: int,
    time_boot_ms: int,
    type_mask: int,
    pos_ned_m: tuple[float, float, float],
    accel_ned_mps2: tuple[float, float, float],
    vel_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> MessageSpec:
    return MessageSpec(
        "SET_POSITION_TARGET_LOCAL_NED",
        {
            "time_boot_ms": int(time_boot_ms) & 0xFFFFFFFF,
            "target_system": target_system,
            "target_component": target_component,
            "coordinate_frame": MAV_FRAME_LOCAL_NED,
            "type_mask": type_mask,
            "x": float(pos_ned_m[0]),
            "y": float(pos_ned_m[1]),
            "z": float(pos_ned_m[2]),
            "vx": float(vel_ned_mps[0]),
            "vy": float(vel_ned_mps[1]),
            "vz": float(vel_ned_mps[2]),
            "afx": float(accel_ned_mps2[0]),
            "afy": float(accel_ned_mps2[1]),
            "afz": float(accel_ned_mps2[2]),
            "yaw": 0.0,
            "yaw_rate": 0.0,
        },
        kind="setpoint",
    )


def accel_setpoint(
    target_system: int,
    target_component: int,
    time_boot_ms: int,
    accel_ned_mps2: tuple[float, float, float],
) -> MessageSpec:
    """Acceleration-only SET_POSITION_TARGET_LOCAL_NED: type_mask 3135,
    MAV_FRAME_LOCAL_NED, (afx, afy, afz) [m/s^2] NED (mavlink-protocol.md,
    "The acceleration setpoint")."""
    return _local_ned_target(
        target_system,
        target_component,
        time_boot_ms,
        TYPE_MASK_ACCEL,
        (0.0, 0.0, 0.0),
        accel_ned_mps2,
    )


def vel_accel_setpoint(
    target_system: int,
    target_component: int,
    time_boot_ms: int,
    vel_ned_mps: tuple[float, float, float],
    accel_ned_mps2: tuple[float, float, float],
) -> MessageSpec:
    """Velocity SET_POSITION_TARGET_LOCAL_NED with the acceleration as its
    feed-forward: type_mask 3079, MAV_FRAME_LOCAL_NED, (vx, vy, vz) [m/s] and
    (afx, afy, afz) [m/s^2] NED (Eq. V1 of docs/setpoints.md)."""
    return _local_ned_target(
        target_system,
        target_component,
        time_boot_ms,
        TYPE_MASK_VEL_ACCEL,
        (0.0, 0.0, 0.0),
        accel_ned_mps2,
        vel_ned_mps,
    )


def position_setpoint(
    target_system: int,
    target_component: int,
    time_boot_ms: int,
    pos_ned_m: tuple[float, float, float],
) -> MessageSpec:
    """Position-only SET_POSITION_TARGET_LOCAL_NED (type_mask 3576): fly to
    (x, y, z) [m], NED, relative to the vehicle's EKF origin."""
    return _local_ned_target(
        target_system,
        target_component,
        time_boot_ms,
        TYPE_MASK_POSITION,
        pos_ned_m,
        (0.0, 0.0, 0.0),
    )


def posvel_setpoint(
    target_system: int,
    target_component: int,
    time_boot_ms: int,
    pos_ned_m: tuple[float, float, float],
    vel_ned_mps: tuple[float, float, float],
) -> MessageSpec:
    """Position SET_POSITION_TARGET_LOCAL_NED with the velocity [m/s] of the
    point as its feed-forward (type_mask 3520): fly to (x, y, z) [m], NED,
    relative to the vehicle's EKF origin, moving at (vx, vy, vz) there."""
    return _local_ned_target(
        target_system,
        target_component,
        time_boot_ms,
        TYPE_MASK_POS_VEL,
        pos_ned_m,
        (0.0, 0.0, 0.0),
        vel_ned_mps,
    )
