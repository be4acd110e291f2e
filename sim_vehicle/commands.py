"""Inbound message handling of one autopilot: commands, setpoints, parameters, streams. NO I/O.

Owns the mapping from decoded MAVLink messages to ``Autopilot`` transitions and
the replies ArduCopter gives: a COMMAND_ACK for every COMMAND_LONG/COMMAND_INT
addressed to the vehicle (unknown commands: MAV_RESULT_UNSUPPORTED), a
STATUSTEXT before the ACK when a check refuses, PARAM_VALUE for parameter
traffic. ``dispatch`` is called by ``Autopilot.handle``.

READING of ArduCopter 4.5's SET_POSITION_TARGET_LOCAL_NED rules (protocol sheet
and "Copter commands in Guided mode"): a bit set in a group (position 1|2|4,
velocity 8|16|32, acceleration 64|128|256) ignores the whole group; FORCE_SET
(512) drops the message; frames LOCAL_NED (1), LOCAL_OFFSET_NED (7), BODY_NED
(8), BODY_OFFSET_NED (9) are supported (body frames rotate by the heading,
offset frames add the current position); any other frame stops the vehicle.
Accepted combinations: position+velocity(+accel), velocity(+accel),
acceleration only, position only; anything else stops the vehicle.

Hostile numbers (issue 9): a setpoint whose used fields are NaN, infinite or
absurd (beyond ``SETPOINT_LIMIT``) is dropped and counted in
``Autopilot.rejected``, as ArduCopter ignores NaN targets; a PARAM_SET of a
non-finite value is ignored (ArduPilot's rule); a command whose numeric
parameters it needs are not finite is answered MAV_RESULT_DENIED.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire.protocols import MAVLinkMessage
from sim_vehicle import telemetry
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin, Vec3

if TYPE_CHECKING:
    from sim_vehicle.autopilot import Autopilot

__all__ = ["DATA_STREAMS", "STREAMABLE", "dispatch"]

#: Streamable message id -> default rate in Hz (used when the interval asked is 0).
STREAMABLE: dict[int, float] = {
    mav.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mav.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
    mav.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 4.0,
    mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 10.0,
    mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT: 2.0,
    mav.MAVLINK_MSG_ID_HOME_POSITION: 0.2,
    mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
}
#: REQUEST_DATA_STREAM groups (MAV_DATA_STREAM_*) -> message ids, as ArduPilot groups them.
DATA_STREAMS: dict[int, tuple[int, ...]] = {
    mav.MAV_DATA_STREAM_EXTENDED_STATUS: (
        mav.MAVLINK_MSG_ID_SYS_STATUS,
        mav.MAVLINK_MSG_ID_GPS_RAW_INT,
    ),
    mav.MAV_DATA_STREAM_POSITION: (
        mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
        mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    ),
    mav.MAV_DATA_STREAM_EXTRA1: (mav.MAVLINK_MSG_ID_ATTITUDE,),
    mav.MAV_DATA_STREAM_EXTRA3: (mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT,),
}
DATA_STREAMS[mav.MAV_DATA_STREAM_ALL] = tuple(i for ids in DATA_STREAMS.values() for i in ids)

ACCEPTED = mav.MAV_RESULT_ACCEPTED
DENIED = mav.MAV_RESULT_DENIED
FAILED = mav.MAV_RESULT_FAILED
UNSUPPORTED = mav.MAV_RESULT_UNSUPPORTED
ARM_FORCE, DISARM_FORCE = 2989, 21196
_FRAMES = {
    mav.MAV_FRAME_LOCAL_NED,
    mav.MAV_FRAME_LOCAL_OFFSET_NED,
    mav.MAV_FRAME_BODY_NED,
    mav.MAV_FRAME_BODY_OFFSET_NED,
}
#: Echoed type_mask per tracked kind (ArduCopter 4.5 reports its guided sub-mode).
ZERO: Vec3 = (0.0, 0.0, 0.0)
ECHO_MASK = {"accel": 3135, "vel": 3079, "pos": 3576, "posvel": 3072}
Msgs = list[mav.MAVLink_message]
#: Largest |value| of a setpoint field the emulator accepts (m, m/s, m/s^2, rad).
SETPOINT_LIMIT = 1.0e5


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _for_me(ap: Autopilot, msg: MAVLinkMessage) -> bool:
    ts, tc = msg.target_system, msg.target_component
    return ts in (0, ap.sysid) and tc in (0, ap.compid)


def dispatch(ap: Autopilot, msg: MAVLinkMessage, now: float, kin: Kin) -> Msgs:
    """Handle one decoded message addressed (or broadcast) to ``ap``; return replies."""
    kind = msg.get_type()
    if kind == "HEARTBEAT":  # ArduPilot: any HEARTBEAT from SYSID_MYGCS, whatever its type
        if msg.get_srcSystem() == round(ap.params["SYSID_MYGCS"]):
            return ap.gcs_heartbeat(now)
        return []
    if kind == "SET_POSITION_TARGET_LOCAL_NED":
        if _for_me(ap, msg):
            _setpoint(ap, msg, now, kin)
        return []
    if kind == "COMMAND_LONG" and _for_me(ap, msg):
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        return _command(ap, msg.command, p, msg, now, kin)
    if kind == "COMMAND_INT" and _for_me(ap, msg):
        p = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
        return _command(ap, msg.command, p, msg, now, kin)
    if kind == "SET_MODE" and msg.target_system == ap.sysid:
        ok = ap.set_mode(int(msg.custom_mode), now, kin)
        return [_ack(mav.MAV_CMD_DO_SET_MODE, ACCEPTED if ok else FAILED, msg)]
    if kind.startswith("PARAM_") and _for_me(ap, msg):
        return _param(ap, kind, msg, now, kin)
    if kind == "REQUEST_DATA_STREAM" and _for_me(ap, msg):
        on = msg.start_stop and msg.req_message_rate > 0
        for msgid in DATA_STREAMS.get(msg.req_stream_id, ()):
            ap.set_interval(msgid, 1.0 / msg.req_message_rate if on else -1.0, now)
        return []
    if kind == "TIMESYNC":
        # ArduPilot answers a request (tc1 = 0) with its boot time in ns and the
        # request's ts1, which lets a station measure round trip and clock offset.
        if msg.tc1 == 0:
            return [
                mav.MAVLink_timesync_message(tc1=max(1, int((now - ap.boot) * 1e9)), ts1=msg.ts1)
            ]
        return []
    if kind == "MISSION_REQUEST_LIST" and _for_me(ap, msg):
        return [
            mav.MAVLink_mission_count_message(
                target_system=msg.get_srcSystem(),
                target_component=msg.get_srcComponent(),
                count=0,
                mission_type=msg.mission_type,
            )
        ]
    return []


def _ack(command: int, result: int, msg: MAVLinkMessage) -> mav.MAVLink_message:
    return telemetry.command_ack(command, result, msg.get_srcSystem(), msg.get_srcComponent())


def _command(
    ap: Autopilot, cmd: int, p: tuple[float, ...], msg: MAVLinkMessage, now: float, kin: Kin
) -> Msgs:
    if not _finite(*p[:2]) or (cmd == mav.MAV_CMD_NAV_TAKEOFF and not ap.takeoff_params_ok(p)):
        ap.rejected += 1
        return [_ack(cmd, DENIED, msg)]
    out: Msgs = []
    result = ACCEPTED
    after: Msgs = []
    if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
        interval = p[1] / 1e6 if p[1] > 0 else (0.0 if p[1] == 0 else -1.0)
        ok = ap.set_interval(int(p[0]), interval, now)
        result = ACCEPTED if ok else ap.unknown_stream_result
    elif cmd == mav.MAV_CMD_GET_MESSAGE_INTERVAL:
        iv = ap.interval_of(int(p[0]))
        us = round(iv * 1e6) if iv > 0 else -1
        after.append(mav.MAVLink_message_interval_message(message_id=int(p[0]), interval_us=us))
    elif cmd == mav.MAV_CMD_REQUEST_MESSAGE:
        m = ap.build(int(p[0]), now, kin)
        result = FAILED if m is None else ACCEPTED
        after.extend([m] if m is not None else [])
    elif cmd == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
        after.append(telemetry.autopilot_version(ap.sysid))
    elif cmd == mav.MAV_CMD_DO_SET_MODE:
        result = ap.mode_command(p, now, kin)
    elif cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
        if p[0] == 1.0:
            ok, why = ap.arm(now, kin, force=round(p[1]) == ARM_FORCE)
        else:
            ok, why = ap.disarm(now, kin, force=round(p[1]) == DISARM_FORCE)
        result, reasons = ap.arm_reply(ok, why, now)
        out.extend(reasons)
    elif cmd == mav.MAV_CMD_NAV_TAKEOFF:
        result = ap.takeoff_command(p, now, kin)
    elif cmd == mav.MAV_CMD_NAV_LAND:
        result = ACCEPTED if ap.set_mode(9, now, kin) else FAILED
    elif cmd == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        result = ACCEPTED if ap.set_mode(6, now, kin) else FAILED
    else:
        result = UNSUPPORTED
    out.append(_ack(cmd, result, msg))
    return out + after


def _param(ap: Autopilot, kind: str, msg: MAVLinkMessage, now: float, kin: Kin) -> Msgs:
    store: ParamStore = ap.params
    if kind == "PARAM_REQUEST_LIST":
        return list(store.all_messages())
    if kind == "PARAM_REQUEST_READ":
        name = store.name_at(msg.param_index) if msg.param_index >= 0 else _pid(msg)
        return [store.message(name)] if name is not None and store.on_wire(name) else []
    if kind == "PARAM_SET":
        name = _pid(msg)
        if not _finite(float(msg.param_value)):
            ap.rejected += 1
            return []  # ArduPilot ignores NaN and infinite values
        if not store.on_wire(name):
            return []  # ArduPilot and PX4 ignore unknown names
        value = store.decode_set(name, float(msg.param_value), int(msg.param_type))
        if value is None or not store.set(name, value):
            return []  # PX4: a REAL32 PARAM_SET on an INT32 parameter is ignored
        ap.refresh(now, kin)
        return [store.message(name)]
    return []


def _pid(msg: MAVLinkMessage) -> str:
    pid = msg.param_id
    if isinstance(pid, bytes):
        pid = pid.decode("ascii", "replace")
    return str(pid).rstrip("\x00")


def _rot(yaw: float, v: Vec3) -> Vec3:
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


_ACCEL_ONLY = ECHO_MASK["accel"]
"""type_mask 3135: position, velocity, yaw and yaw rate ignored (the station's stream)."""


def stream_accel(ap: Autopilot, msg: MAVLinkMessage, now: float, landed: bool) -> bool:
    """``dispatch`` of a streamed acceleration setpoint, the station's 50 Hz
    message: type_mask 3135 in MAV_FRAME_LOCAL_NED for this vehicle, GUIDED,
    armed, airborne (``landed``: its fleet row's flag, what ``Kin.landed``
    holds) and within ``SETPOINT_LIMIT``. The same calls in the same order
    as ``dispatch`` makes for it (``_setpoint``), without a ``Kin`` for each
    (tests/sim_vehicle/test_stream_accel.py compares the two bit for bit).
    False, having changed nothing, for any other message or state: then
    ``dispatch`` takes it."""
    return stream_accel_fields(
        ap, msg.type_mask, msg.coordinate_frame, msg.target_system, msg.target_component,
        msg.afx, msg.afy, msg.afz, now, landed,
    )  # fmt: skip


def stream_accel_fields(
    ap: Autopilot,
    type_mask: int,
    frame: int,
    ts: int,
    tc: int,
    ax: float,
    ay: float,
    az: float,
    now: float,
    landed: bool,
) -> bool:
    """``stream_accel`` of a setpoint given by the fields it reads (a
    ``codec.RawSetpoint``'s, without a pymavlink message)."""
    if ap.mode != 4 or not ap.armed or landed or ts not in (0, ap.sysid):
        return False
    a = streamed_accel(type_mask, frame, tc, ap.compid, ax, ay, az)
    if a is None:
        return False
    ap.stream_accel(a, now)  # heard, then applied
    return True


def streamed_accel(
    type_mask: int, frame: int, tc: int, compid: int, ax: float, ay: float, az: float
) -> Vec3 | None:
    """The acceleration (local NED) a streamed setpoint's fields ask of a vehicle
    of component ``compid`` in GUIDED, armed and airborne, or None when they are
    not the station's stream (type_mask 3135, MAV_FRAME_LOCAL_NED, this
    component or 0, every value within ``SETPOINT_LIMIT``): then ``dispatch``
    takes it. What ``_setpoint`` would make of them, bit for bit."""
    if type_mask != _ACCEL_ONLY or frame != mav.MAV_FRAME_LOCAL_NED or tc not in (0, compid):
        return None
    lim = SETPOINT_LIMIT
    if not (abs(ax) <= lim and abs(ay) <= lim and abs(az) <= lim):
        return None  # dispatch counts the rejection
    # _rot(0.0, a) written out: cos 0 = 1 and sin 0 = 0 exactly, so the same
    # floats (signed zeros included) without two calls, 50 times a second.
    return (ax - 0.0 * ay, 0.0 * ax + ay, az)


def _setpoint(ap: Autopilot, msg: MAVLinkMessage, now: float, kin: Kin) -> None:
    ap.setpoint_heard(now)
    if ap.mode != 4 or not ap.armed or kin.landed:
        return  # honoured only in GUIDED, armed and airborne; silently ignored otherwise
    mask = msg.type_mask
    if mask & mav.POSITION_TARGET_TYPEMASK_FORCE_SET:
        return  # FORCE_SET: dropped (protocol sheet)
    frame = msg.coordinate_frame
    if frame not in _FRAMES:
        ap.stop(now, kin)
        return
    pos_ign, vel_ign, acc_ign = mask & 0x7, mask & 0x38, mask & 0x1C0
    yaw_ign = mask & mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    lim = SETPOINT_LIMIT
    # abs(NaN) <= x and abs(inf) <= x are False: one test covers "finite and not absurd"
    # (each used group in turn: this runs for every setpoint)
    if not (
        (pos_ign or (abs(msg.x) <= lim and abs(msg.y) <= lim and abs(msg.z) <= lim))
        and (vel_ign or (abs(msg.vx) <= lim and abs(msg.vy) <= lim and abs(msg.vz) <= lim))
        and (acc_ign or (abs(msg.afx) <= lim and abs(msg.afy) <= lim and abs(msg.afz) <= lim))
        and (yaw_ign or abs(msg.yaw) <= lim)
    ):
        ap.rejected += 1
        return  # dropped: the vehicle keeps its last target (GUID_TIMEOUT still runs)
    if not yaw_ign:
        ap.yaw = float(msg.yaw)
    body = frame in (mav.MAV_FRAME_BODY_NED, mav.MAV_FRAME_BODY_OFFSET_NED)
    yaw = ap.yaw if body else 0.0
    p: Vec3 = ZERO  # each group is computed only when used
    if not pos_ign:
        p = (
            _rot(yaw, (msg.x, msg.y, msg.z))
            if frame == mav.MAV_FRAME_BODY_OFFSET_NED
            else (msg.x, msg.y, msg.z)
        )
        if frame in (mav.MAV_FRAME_LOCAL_OFFSET_NED, mav.MAV_FRAME_BODY_OFFSET_NED):
            p = (kin.pos[0] + p[0], kin.pos[1] + p[1], kin.pos[2] + p[2])
    v = _rot(yaw, (msg.vx, msg.vy, msg.vz)) if not vel_ign else ZERO
    a = _rot(yaw, (msg.afx, msg.afy, msg.afz)) if not acc_ign else ZERO
    sp: dict[str, Any]
    if not pos_ign and not vel_ign:
        kind, sp = "posvel", {"p": p, "v": v, "a": a if not acc_ign else (0.0, 0.0, 0.0)}
    elif pos_ign and not vel_ign:
        kind, sp = "vel", {"v": v, "a": a if not acc_ign else (0.0, 0.0, 0.0)}
    elif pos_ign and vel_ign and not acc_ign:
        kind, sp = "accel", {"a": a}
    elif not pos_ign and vel_ign and acc_ign:
        kind, sp = "pos", {"p": p}
    else:
        ap.stop(now, kin)
        return
    ap.apply_setpoint(kind, sp, ECHO_MASK[kind], now, kin)
