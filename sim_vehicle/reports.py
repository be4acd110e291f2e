"""The messages a vehicle reports on request or by stream (REQUEST_MESSAGE, SET_MESSAGE_INTERVAL).

Owns ``build``: one instance of a streamable or requestable message from an
``Autopilot``'s state and the vehicle's kinematics. NO I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import telemetry
from sim_vehicle.telemetry import Kin

if TYPE_CHECKING:
    from sim_vehicle.autopilot import Autopilot

__all__ = ["bucket_due", "build"]

GUIDED = 4
LPN = mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED
ZERO = (0.0, 0.0, 0.0)


def build(ap: Autopilot, msgid: int, now: float, kin: Kin) -> mav.MAVLink_message | None:
    """One instance of a streamable / requestable message, or None if not available."""
    t = now - ap.boot
    if msgid == mav.MAVLINK_MSG_ID_HEARTBEAT:
        return ap.heartbeat()
    if msgid == mav.MAVLINK_MSG_ID_SYS_STATUS:
        return telemetry.sys_status(ap.ekf_ready)
    if msgid == mav.MAVLINK_MSG_ID_GPS_RAW_INT:
        return telemetry.gps_raw_int(t, ap.origin, kin, 3 if ap.ekf_ready else 1)
    if msgid == mav.MAVLINK_MSG_ID_ATTITUDE:
        return telemetry.attitude(t, kin, ap.heading(kin))
    if msgid == LPN:
        return mav.MAVLink_local_position_ned_message(
            round(t * 1000) & 0xFFFFFFFF, *kin.pos, *kin.vel
        )
    if msgid == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
        return telemetry.global_position_int(t, ap.origin, ap.home[2], kin, ap.heading(kin))
    if msgid == mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
        return telemetry.ekf_status_report(ap.ekf_ready)
    if msgid == mav.MAVLINK_MSG_ID_HOME_POSITION:
        return telemetry.home_position(t, ap.origin, ap.home) if ap.ekf_ready else None
    if msgid == mav.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
        return telemetry.gps_global_origin(t, ap.origin) if ap.ekf_ready else None
    if msgid == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
        return telemetry.autopilot_version(ap.sysid)
    if msgid == mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
        return telemetry.extended_sys_state(ap.landed_state)
    if msgid == mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED:
        if ap.mode != GUIDED or not ap.armed:
            return None
        sp = ap.sp
        return telemetry.position_target_local_ned(
            t,
            ap.echo_mask,
            sp.get("p", ap.hold_ned),
            sp.get("v", ZERO),
            sp.get("a", ZERO),
            ap.yaw,
        )
    return None


def bucket_due(streams: Iterable[list[float]], interval_s: float, now: float) -> float:
    """When a stream of ``interval_s`` asked for at ``now`` first goes, beside
    ``streams`` ([interval s, next due s] each), as ArduPilot schedules it
    (GCS_MAVLINK::set_ap_message_interval): every message of one interval
    shares a bucket, sent at once. One joining a bucket goes with the bucket's
    send after its next (that one's list is already taken); a new interval's
    bucket first sends one interval after it was asked for. Measured on
    ArduCopter 4.5.6 SITL (docs/emulator.md): EKF_STATUS_REPORT, GPS_RAW_INT
    and EXTENDED_SYS_STATE asked at 2 Hz 0, 62 and 141 ms apart came first
    at 0.502, 1.004 and 1.004 s, then together every 0.5 s."""
    for interval, due in streams:
        if interval == interval_s:
            return due + interval_s
    return now + interval_s
