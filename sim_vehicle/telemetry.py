"""Outbound message builders of one vehicle (data, not bytes) and the flat-earth map.

Owns the content of every telemetry message except the vectorised
LOCAL_POSITION_NED fast path (``codec``). Builders return pymavlink dialect
message objects, still unpacked: sequence numbers are assigned at the edge by
the vehicle's encoder. No I/O.

Flat earth (protocol sheet, "Frames and origins"; R = 6378137 m)::

    lat = lat0 + degrees(n / R)
    lon = lon0 + degrees(e / (R cos(lat0)))
    alt = alt0 - d
"""

from __future__ import annotations

import math
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mav

__all__ = [
    "EARTH_RADIUS_M",
    "Kin",
    "ned_to_geo",
]

EARTH_RADIUS_M = 6378137.0
Vec3 = tuple[float, float, float]


class Kin(NamedTuple):
    """One vehicle's kinematics snapshot (local NED, m, m/s, m/s^2). Immutable: a
    named tuple, built for every vehicle every step (cheaper than a frozen dataclass)."""

    pos: Vec3
    vel: Vec3
    acc: Vec3
    landed: bool


def ned_to_geo(origin: Vec3, ned: Vec3) -> Vec3:
    """(lat deg, lon deg, alt m AMSL) of local NED point ``ned`` from ``origin`` (flat earth)."""
    lat0, lon0, alt0 = origin
    lat = lat0 + math.degrees(ned[0] / EARTH_RADIUS_M)
    lon = lon0 + math.degrees(ned[1] / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    return lat, lon, alt0 - ned[2]


def _e7(deg: float) -> int:
    return round(deg * 1e7)


def heartbeat(custom_mode: int, armed: bool, guided_like: bool) -> mav.MAVLink_message:
    """HEARTBEAT as ArduCopter fills it (base_mode flags as in GCS_MAVLink_Copter)."""
    base = (
        mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        | mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    )
    if guided_like:
        base |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
    if armed:
        base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
    return mav.MAVLink_heartbeat_message(
        type=mav.MAV_TYPE_QUADROTOR,
        autopilot=mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode=base,
        custom_mode=custom_mode,
        system_status=mav.MAV_STATE_ACTIVE if armed else mav.MAV_STATE_STANDBY,
        mavlink_version=3,
    )


def sys_status(ekf_ready: bool) -> mav.MAVLink_message:
    """SYS_STATUS: gyro, accel, mag, baro, GPS, AHRS and pre-arm checks present;
    GPS, AHRS and pre-arm healthy once the EKF is ready; geofence healthy."""
    present = (
        mav.MAV_SYS_STATUS_SENSOR_3D_GYRO
        | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
        | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
        | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
        | mav.MAV_SYS_STATUS_SENSOR_GPS
        | mav.MAV_SYS_STATUS_AHRS
        # ArduPilot reports its pre-arm checks as a sensor: enabled, healthy
        # when arming would pass (here: once the EKF is ready).
        | mav.MAV_SYS_STATUS_PREARM_CHECK
    )
    not_ready = (
        mav.MAV_SYS_STATUS_SENSOR_GPS | mav.MAV_SYS_STATUS_AHRS | mav.MAV_SYS_STATUS_PREARM_CHECK
    )
    health = present if ekf_ready else present & ~not_ready
    # ArduPilot sets the geofence health bit whenever the fence is not breached,
    # also with no fence configured; without it MAVProxy announces "fence breach".
    health |= mav.MAV_SYS_STATUS_GEOFENCE
    return mav.MAVLink_sys_status_message(
        onboard_control_sensors_present=present,
        onboard_control_sensors_enabled=present,
        onboard_control_sensors_health=health,
        load=100,
        voltage_battery=12600,
        current_battery=0,
        battery_remaining=100,
        drop_rate_comm=0,
        errors_comm=0,
        errors_count1=0,
        errors_count2=0,
        errors_count3=0,
        errors_count4=0,
    )


def gps_raw_int(now: float, origin: Vec3, kin: Kin, fix: int) -> mav.MAVLink_message:
    """GPS_RAW_INT at the true position (fix 3D once the GPS is up)."""
    return mav.MAVLink_gps_raw_int_message(**gps_raw_int_fields(now, origin, kin.pos, kin.vel, fix))


def gps_raw_int_fields(now: float, origin: Vec3, pos: Vec3, vel: Vec3, fix: int) -> dict[str, int]:
    """``gps_raw_int``'s fields, every one (the extensions at 0), for a packer
    that builds no message (``reports.status_frame``)."""
    lat, lon, alt = ned_to_geo(origin, pos)
    spd = math.hypot(vel[0], vel[1])
    cog = math.degrees(math.atan2(vel[1], vel[0])) % 360.0
    return {
        "time_usec": round(now * 1e6),
        "fix_type": fix,
        "lat": _e7(lat),
        "lon": _e7(lon),
        "alt": round(alt * 1000),
        "eph": 121,
        "epv": 200,
        "vel": round(spd * 100),
        "cog": round(cog * 100) % 36000,
        "satellites_visible": 10 if fix >= 3 else 0,
        **_GPS_EXTENSIONS,
    }


_GPS_EXTENSIONS = dict.fromkeys(("alt_ellipsoid", "h_acc", "v_acc", "vel_acc", "hdg_acc", "yaw"), 0)


def global_position_int(
    now: float, origin: Vec3, home_d: float, kin: Kin, yaw: float
) -> mav.MAVLink_message:
    """GLOBAL_POSITION_INT (what MAVProxy shows as the position)."""
    lat, lon, alt = ned_to_geo(origin, kin.pos)
    return mav.MAVLink_global_position_int_message(
        time_boot_ms=round(now * 1000) & 0xFFFFFFFF,
        lat=_e7(lat),
        lon=_e7(lon),
        alt=round(alt * 1000),
        relative_alt=round((home_d - kin.pos[2]) * 1000),
        vx=round(kin.vel[0] * 100),
        vy=round(kin.vel[1] * 100),
        vz=round(kin.vel[2] * 100),
        hdg=round(math.degrees(yaw) % 360.0 * 100) % 36000,
    )


def attitude(now: float, kin: Kin, yaw: float) -> mav.MAVLink_message:
    """ATTITUDE with the tilt a multirotor needs for the achieved horizontal acceleration."""
    c, s = math.cos(yaw), math.sin(yaw)
    a_fwd = c * kin.acc[0] + s * kin.acc[1]
    a_right = -s * kin.acc[0] + c * kin.acc[1]
    g = 9.80665
    return mav.MAVLink_attitude_message(
        time_boot_ms=round(now * 1000) & 0xFFFFFFFF,
        roll=math.atan2(a_right, g),
        pitch=-math.atan2(a_fwd, g),
        yaw=math.remainder(yaw, 2 * math.pi),
        rollspeed=0.0,
        pitchspeed=0.0,
        yawspeed=0.0,
    )


#: EKF_STATUS_REPORT flags once the EKF is ready (attitude, velocities, positions, predictions).
EKF_READY_FLAGS = (
    mav.EKF_ATTITUDE
    | mav.EKF_VELOCITY_HORIZ
    | mav.EKF_VELOCITY_VERT
    | mav.EKF_POS_HORIZ_REL
    | mav.EKF_POS_HORIZ_ABS
    | mav.EKF_POS_VERT_ABS
    | mav.EKF_POS_VERT_AGL
    | mav.EKF_PRED_POS_HORIZ_REL
    | mav.EKF_PRED_POS_HORIZ_ABS
)
EKF_INIT_FLAGS = mav.EKF_ATTITUDE | mav.EKF_VELOCITY_VERT | mav.EKF_CONST_POS_MODE


def ekf_status_report(ekf_ready: bool) -> mav.MAVLink_message:
    """EKF_STATUS_REPORT: attitude only (constant position mode) until ready."""
    return mav.MAVLink_ekf_status_report_message(
        flags=EKF_READY_FLAGS if ekf_ready else EKF_INIT_FLAGS,
        velocity_variance=0.02,
        pos_horiz_variance=0.01,
        pos_vert_variance=0.01,
        compass_variance=0.01,
        terrain_alt_variance=0.0,
        airspeed_variance=0.0,
    )


def gps_global_origin(now: float, origin: Vec3) -> mav.MAVLink_message:
    """GPS_GLOBAL_ORIGIN (the EKF origin LOCAL_POSITION_NED is relative to)."""
    return mav.MAVLink_gps_global_origin_message(
        latitude=_e7(origin[0]),
        longitude=_e7(origin[1]),
        altitude=round(origin[2] * 1000),
        time_usec=round(now * 1e6),
    )


def home_position(now: float, origin: Vec3, home_ned: Vec3) -> mav.MAVLink_message:
    """HOME_POSITION in lat/lon/alt and in the local frame."""
    lat, lon, alt = ned_to_geo(origin, home_ned)
    return mav.MAVLink_home_position_message(
        latitude=_e7(lat),
        longitude=_e7(lon),
        altitude=round(alt * 1000),
        x=home_ned[0],
        y=home_ned[1],
        z=home_ned[2],
        q=[1.0, 0.0, 0.0, 0.0],
        approach_x=0.0,
        approach_y=0.0,
        approach_z=0.0,
        time_usec=round(now * 1e6),
    )


def position_target_local_ned(
    now: float, mask: int, pos: Vec3, vel: Vec3, acc: Vec3, yaw: float
) -> mav.MAVLink_message:
    """POSITION_TARGET_LOCAL_NED: the echo of what the vehicle is tracking (frame LOCAL_NED)."""
    return mav.MAVLink_position_target_local_ned_message(
        time_boot_ms=round(now * 1000) & 0xFFFFFFFF,
        coordinate_frame=mav.MAV_FRAME_LOCAL_NED,
        type_mask=mask,
        x=pos[0],
        y=pos[1],
        z=pos[2],
        vx=vel[0],
        vy=vel[1],
        vz=vel[2],
        afx=acc[0],
        afy=acc[1],
        afz=acc[2],
        yaw=yaw,
        yaw_rate=0.0,
    )


def autopilot_version(sysid: int) -> mav.MAVLink_message:
    """AUTOPILOT_VERSION: ArduCopter 4.5.6-like, MAVLink 2 and local setpoints capable."""
    caps = (
        mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
        | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
        | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    )
    return mav.MAVLink_autopilot_version_message(
        capabilities=caps,
        flight_sw_version=(4 << 24) | (5 << 16) | (6 << 8) | 255,
        middleware_sw_version=0,
        os_sw_version=0,
        board_version=0,
        flight_custom_version=[0] * 8,
        middleware_custom_version=[0] * 8,
        os_custom_version=[0] * 8,
        vendor_id=0,
        product_id=0,
        uid=sysid,
    )


def statustext(severity: int, text: str) -> mav.MAVLink_message:
    """STATUSTEXT (up to 50 characters)."""
    return mav.MAVLink_statustext_message(
        severity=severity, text=text[:50].encode(), id=0, chunk_seq=0
    )


def command_ack(
    command: int, result: int, target_system: int, target_component: int
) -> mav.MAVLink_message:
    """COMMAND_ACK addressed to the requester."""
    return mav.MAVLink_command_ack_message(
        command=command,
        result=result,
        progress=0,
        result_param2=0,
        target_system=target_system,
        target_component=target_component,
    )


def extended_sys_state(landed_state: int) -> mav.MAVLink_message:
    """EXTENDED_SYS_STATE (245): ``landed_state`` MAV_LANDED_STATE (1 on ground, 2 in air,
    3 taking off, 4 landing), ``vtol_state`` 0 (MAV_VTOL_STATE_UNDEFINED), as a copter."""
    return mav.MAVLink_extended_sys_state_message(vtol_state=0, landed_state=landed_state)
