"""The messages a vehicle reports on request or by stream (REQUEST_MESSAGE, SET_MESSAGE_INTERVAL).

Owns ``build``: one instance of a streamable or requestable message from an
``Autopilot``'s state and the vehicle's kinematics; ``set_interval``: a
stream's interval and its next message (ArduPilot's buckets); the status
path's pieces (``FLEET_STREAMS``, ``first_due``, ``take_fleet_streams``,
``status_frame``). NO I/O.

**The status path.** ArduCopter's 2 Hz EKF_STATUS_REPORT, GPS_RAW_INT and
EXTENDED_SYS_STATE are functions of the autopilot's EKF and landed state,
its origin and boot time, and the row's position and velocity. An
autopilot whose ``fleet_streams`` name them (``EmulatorCore.add``) leaves
them out of its poll deadline (``first_due``); the emulator looks at each
row's ``Fleet.st_next`` (``first_due`` of them, copied at every ``sync``) and, for
a row whose only due work they are, takes them (``take_fleet_streams``,
the poll's own rule for a stream) and packs their frames without a poll or
a message object (``status_frame``). A row polled anyway sends them from
its poll, as before. The same bytes in the same order:
tests/sim_vehicle/test_sv_status_path.py.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from operator import itemgetter
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire.framing import frame_payload
from sim_vehicle import telemetry
from sim_vehicle.codec import plain_spec
from sim_vehicle.commands import STREAMABLE
from sim_vehicle.telemetry import Kin

if TYPE_CHECKING:
    from sim_vehicle.autopilot import Autopilot

__all__ = [
    "FLEET_STREAMS", "bucket_due", "build", "first_due", "next_due", "set_interval",
    "status_frame", "take_fleet_streams",
]  # fmt: skip

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


def set_interval(ap: Autopilot, msgid: int, interval_s: float, now: float) -> bool:
    """SET_MESSAGE_INTERVAL of ``ap``: interval s, 0 the default, < 0 off; False
    for an id it cannot stream. LOCAL_POSITION_NED's is the emulator's
    vectorised stream (``lpn_interval_s``, capped at SIM_LPN_MAX_HZ, the
    router's rate); the others go in ``ap._streams``, due in a bucket
    (``bucket_due``) unless ``ap.stream_buckets`` is False (then at once)."""
    if msgid not in STREAMABLE:
        return False
    if interval_s == 0.0:
        interval_s = 1.0 / STREAMABLE[msgid]
    if msgid == LPN:
        cap_hz = ap.params["SIM_LPN_MAX_HZ"]
        if interval_s > 0 and cap_hz > 0:
            interval_s = max(interval_s, 1.0 / cap_hz)  # the router's rate wins
        ap.lpn_interval_s = interval_s if interval_s > 0 else None
        ap.lpn_kick = interval_s > 0
        ap.version += 1
    elif interval_s > 0:
        streams = ap._streams
        kept = streams.pop(msgid, None)
        due = bucket_due(streams.values(), interval_s, now)
        if not ap.stream_buckets:
            due = now
        elif kept is not None and kept[0] == interval_s:
            due = kept[1]  # asked again at its interval: its bucket stays (ArduPilot)
        streams[msgid] = [interval_s, due]
        ap.deadline = min(ap.deadline, due)
    else:
        ap._streams.pop(msgid, None)
    return True


_EKF, _GPS, _EXT = (
    mav.MAVLink_ekf_status_report_message,
    mav.MAVLink_gps_raw_int_message,
    mav.MAVLink_extended_sys_state_message,
)
FLEET_STREAMS: frozenset[int] = frozenset({_EKF.id, _GPS.id, _EXT.id})
"""The streams an ArduPilot autopilot leaves to the status path (module
docstring)."""


def next_due(sched: list[float], now: float) -> float:
    """When a stream ([interval s, due s]) sent at ``now`` next goes: an
    interval on, or half of one from ``now`` when that is due already."""
    return max(sched[1] + sched[0], now + 0.5 * sched[0])


def first_due(ap: Autopilot, *, status_path: bool) -> float:
    """The first due time of ``ap``'s streams the status path sends
    (``status_path``) or of those its poll sends (not); inf: none."""
    fleet, d = ap.fleet_streams, math.inf
    for msgid, sched in ap._streams.items():
        if (msgid in fleet) is status_path and sched[1] < d:
            d = sched[1]
    return d


def take_fleet_streams(ap: Autopilot, now: float) -> tuple[list[int], float]:
    """The status-path streams of ``ap`` due at ``now``, in the order its
    poll sends streams, each moved on as the poll moves it; and then their
    ``first_due``."""
    out, fleet, d = [], ap.fleet_streams, math.inf
    for msgid, sched in ap._streams.items():
        if msgid in fleet:
            if now >= sched[1] - 1e-6:
                out.append(msgid)
                sched[1] = next_due(sched, now)
            if sched[1] < d:
                d = sched[1]
    return out, d


_CONSTANT: dict[tuple[int, int], bytes] = {}
"""(message id, the state it depends on) -> its payload: EKF_STATUS_REPORT
by the EKF's readiness, EXTENDED_SYS_STATE by the landed state."""
_GPS_ORDER = itemgetter(*_GPS.ordered_fieldnames)


def _spec(cls: type) -> tuple[bytes, bytes, Any, Any]:
    spec = plain_spec(cls)
    assert spec is not None  # none of the three has an array or a text field
    return spec


_SPECS = {c.id: _spec(c) for c in (_EKF, _GPS, _EXT)}
"""Each one's id, CRC_EXTRA, pack and field getter (``codec.plain_spec``)."""


def status_frame(
    ap: Autopilot,
    msgid: int,
    now: float,
    pos: telemetry.Vec3,
    vel: telemetry.Vec3,
    ids: tuple[int, int, int],
) -> bytes:
    """The unsigned frame of status-path stream ``msgid`` of ``ap`` at
    ``now`` (``pos``, ``vel``: its row's kinematics; ``ids``: seq, sysid,
    compid): the bytes ``build``'s message packs to, without the message."""
    mid, extra, pack, get = _SPECS[msgid]
    if msgid == _GPS.id:
        f = telemetry.gps_raw_int_fields(
            now - ap.boot, ap.origin, pos, vel, 3 if ap.ekf_ready else 1
        )
        payload = pack(*_GPS_ORDER(f))
    else:
        key = (msgid, int(ap.ekf_ready) if msgid == _EKF.id else ap.landed_state)
        payload = _CONSTANT.get(key, b"")
        if not payload:
            msg = (telemetry.ekf_status_report(ap.ekf_ready) if msgid == _EKF.id
                   else telemetry.extended_sys_state(ap.landed_state))  # fmt: skip
            payload = _CONSTANT[key] = pack(*get(msg))
    return frame_payload(mid, extra, ids[0], ids[1], ids[2], payload)
