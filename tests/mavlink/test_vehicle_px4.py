"""``VehicleProtocol`` with the PX4 personality, a hand-advanced clock and
hand-made messages (no sockets): the start-up sequence measured on PX4 v1.14
SITL (docs/mavlink-protocol.md, PX4 section)."""

from __future__ import annotations

import math
import struct

import pytest
from vehicle_harness import REF, SYS, commands, origin_msg, pos

from gcs_swarm.mavlink import MessageSpec, Phase, ProtocolConfig, VehicleProtocol
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.inbound import (
    CommandAck,
    EkfStatus,
    Event,
    GpsRaw,
    Heartbeat,
    ParamValue,
    SysStatus,
)
from gcs_swarm.mavlink.personality import personality_for
from gcs_swarm.mavlink.px4 import HOLD, LAND, OFFBOARD, PX4, TAKEOFF, envelope_from_px4
from gcs_swarm.mavlink.vehicle_params import ParamSettings

PREARM = 0x10000000
INT32 = 6


def _hb(mode: int, armed: bool = False) -> Heartbeat:
    return Heartbeat(SYS, 1, 2, 12, 1 | (128 if armed else 0), mode, 4)


def _make(params: ParamSettings | None = None) -> VehicleProtocol:
    cfg = ProtocolConfig(mission_origin=REF)
    return VehicleProtocol(SYS, cfg, goto_m=(5.0, 0.0, 12.0), params=params, personality=PX4)


def _ack_all(vp: VehicleProtocol, now: float) -> list[MessageSpec]:
    """Answer every awaited command at ``now`` (ACK 0 or the PARAM_VALUE echo)."""
    seen: list[MessageSpec] = []
    for _ in range(40):
        out = vp.take_outbound()
        seen += out
        pending = [m for m in out if m.name in ("COMMAND_LONG", "PARAM_SET", "PARAM_REQUEST_READ")]
        if not pending:
            break
        for m in pending:
            if m.name == "COMMAND_LONG":
                vp.handle_message(CommandAck(SYS, 1, int(m["command"]), 0), now)
            elif m.name == "PARAM_REQUEST_READ":  # PX4's defaults: 1.0 s, and INT32 0
                name = str(m["param_id"])
                value, ptype = (1.0, 9) if name == "COM_OF_LOSS_T" else (0.0, INT32)
                vp.handle_message(ParamValue(SYS, 1, name, value, ptype), now)
            else:
                vp.handle_message(ParamValue(SYS, 1, str(m["param_id"]), float(m["param_value"]),
                                             int(m["param_type"])), now)  # fmt: skip
    return seen


def test_px4_personality_is_picked_by_the_mission_name() -> None:
    assert personality_for("px4") is PX4
    assert personality_for("ardupilot").fly_mode == b.COPTER_MODES["GUIDED"]
    assert (HOLD, TAKEOFF, OFFBOARD, LAND) == (50593792, 33816576, 393216, 100925440)


def test_modes_are_set_as_main_and_sub() -> None:
    spec = PX4.set_mode(SYS, 1, OFFBOARD)
    assert (spec["param1"], spec["param2"], spec["param3"]) == (1.0, 6.0, 0.0)
    spec = PX4.set_mode(SYS, 1, HOLD)
    assert (spec["param2"], spec["param3"]) == (4.0, 3.0)


def test_takeoff_carries_nan_position_and_amsl_altitude() -> None:
    spec = PX4.takeoff(SYS, 1, 10.0, 594.5)
    assert [math.isnan(spec[f"param{i}"]) for i in (4, 5, 6)] == [True] * 3
    assert spec["param7"] == 594.5 and spec["command"] == b.MAV_CMD_NAV_TAKEOFF


def test_int32_parameters_are_set_and_read_bytewise() -> None:
    spec = PX4.params.param_set(SYS, 1, "COM_OBL_RC_ACT", 4.0)
    assert spec["param_type"] == INT32
    assert struct.unpack("<i", struct.pack("<f", spec["param_value"]))[0] == 4
    spec = PX4.params.param_set(SYS, 1, "COM_OF_LOSS_T", 1.0)
    assert spec["param_type"] == 9 and spec["param_value"] == 1.0
    echo = ParamValue(SYS, 1, "COM_OBL_RC_ACT", float(spec["param_value"]), 9)
    assert PX4.param_value(echo) == 1.0  # REAL32 read as it is
    raw = struct.unpack("<f", struct.pack("<i", 4))[0]
    assert PX4.param_value(ParamValue(SYS, 1, "COM_OBL_RC_ACT", raw, INT32)) == 4.0


def test_envelope_from_px4_defaults() -> None:
    values = {"MPC_ACC_HOR": 3.0, "MPC_ACC_UP_MAX": 4.0, "MPC_ACC_DOWN_MAX": 3.0,
              "MPC_JERK_MAX": 8.0, "MPC_XY_VEL_MAX": 12.0, "MPC_Z_VEL_MAX_UP": 3.0,
              "MPC_Z_VEL_MAX_DN": 1.5, "MPC_TILTMAX_AIR": 45.0}  # fmt: skip
    env, missing = envelope_from_px4(values, None, 0.2)
    assert missing == ()
    assert (env.accel_xy, env.accel_z, env.jerk_xy, env.jerk_z) == (3.0, 3.0, 8.0, 8.0)
    assert (env.speed_xy, env.speed_up, env.speed_down, env.lag_s) == (12.0, 3.0, 1.5, 0.3)
    # A 10 deg tilt limit caps the horizontal acceleration at g tan(10 deg) (Eq. E1-PX4).
    env, _ = envelope_from_px4({**values, "MPC_TILTMAX_AIR": 10.0}, None, 0.2)
    assert env.accel_xy == pytest.approx(9.80665 * math.tan(math.radians(10.0)))


def _to_waiting(vp: VehicleProtocol, now: float) -> list[MessageSpec]:
    vp.handle_message(_hb(HOLD), now)
    assert vp.phase is Phase.CONFIGURING
    seen = _ack_all(vp, now)
    streams = [int(m["param1"]) for m in commands(seen, b.MAV_CMD_SET_MESSAGE_INTERVAL)]
    assert streams == [32, 1, 230, 24, 245]  # no EKF_STATUS_REPORT: PX4 has none
    assert vp.phase is Phase.WAITING_ARMABLE  # booted in Hold: nothing to ask
    vp.handle_message(origin_msg(), now)
    vp.handle_message(pos(1000, (0.0, 0.0, 0.0)), now)
    return seen


def test_startup_arms_in_hold_after_prearm_takes_off_then_offboard_after_a_stream() -> None:
    vp = _make()
    seen = _to_waiting(vp, 0.0)
    sets = {str(m["param_id"]): m for m in seen if m.name == "PARAM_SET"}
    assert set(sets) == {"COM_OF_LOSS_T"}  # the failsafe's action only when asked
    vp.handle_message(GpsRaw(SYS, 1, 3, 10), 0.1)
    vp.handle_message(EkfStatus(SYS, 1, 0x37), 0.1)
    vp.handle_message(SysStatus(SYS, 1, PREARM, PREARM, 0), 0.2)  # pre-arm not passed
    assert vp.phase is Phase.WAITING_ARMABLE
    vp.handle_message(SysStatus(SYS, 1, PREARM, PREARM, PREARM), 9.3)
    assert vp.phase is Phase.ARMING
    assert len(commands(vp.take_outbound(), b.MAV_CMD_COMPONENT_ARM_DISARM)) == 1
    # A refusal's reason arrives as an EVENT: it is named in the log.
    vp.handle_message(Event(SYS, 1, 22831554, 0x44, (0,) * 40), 9.31)
    vp.handle_message(CommandAck(SYS, 1, b.MAV_CMD_COMPONENT_ARM_DISARM, 1), 9.32)
    refused = [e.text for e in vp.take_events() if e.kind == "refused"]
    assert refused and "Waiting for estimator to initialize" in refused[0]
    vp.handle_timer(11.4)
    assert len(commands(vp.take_outbound(), b.MAV_CMD_COMPONENT_ARM_DISARM)) == 1
    vp.handle_message(CommandAck(SYS, 1, b.MAV_CMD_COMPONENT_ARM_DISARM, 0), 11.41)
    (tk,) = commands(vp.take_outbound(), b.MAV_CMD_NAV_TAKEOFF)
    # Height 12 m in the mission frame, origin 10 m below the reference: 22 m
    # above the vehicle's origin, whose altitude is 590 m AMSL.
    assert tk["param7"] == pytest.approx(590.0 + 22.0) and math.isnan(tk["param5"])
    vp.handle_message(CommandAck(SYS, 1, b.MAV_CMD_NAV_TAKEOFF, 0), 11.5)
    vp.handle_message(_hb(TAKEOFF, armed=True), 12.0)  # PX4 climbs in AUTO.TAKEOFF
    assert vp.phase is Phase.TAKING_OFF
    vp.handle_message(_hb(HOLD, armed=True), 30.0)  # ... then Holds
    vp.handle_message(pos(30000, (0.0, 0.0, -21.8)), 30.0)
    assert vp.phase is Phase.GOING_TO_START
    out = vp.take_outbound()
    assert [m["type_mask"] for m in out if m.name == "SET_POSITION_TARGET_LOCAL_NED"] == [3576]
    assert not commands(out, b.MAV_CMD_DO_SET_MODE)  # not before the stream has run
    t = 30.0
    for k in range(1, 50):  # 1 s of telemetry, each answered by a setpoint
        t = 30.0 + 0.02 * k
        vp.handle_message(pos(30000 + 20 * k, (0.0, 0.0, -21.8)), t)
        vp.handle_timer(t)
    assert not commands(vp.take_outbound(), b.MAV_CMD_DO_SET_MODE)
    vp.handle_timer(31.0)
    (mode,) = commands(vp.take_outbound(), b.MAV_CMD_DO_SET_MODE)
    assert (mode["param2"], mode["param3"]) == (6.0, 0.0)
    vp.handle_message(CommandAck(SYS, 1, b.MAV_CMD_DO_SET_MODE, 0), 31.01)
    # At the start point, but READY only in OFFBOARD.
    goto = (-100.0, 5.0, -22.0)  # NED of the mission-frame (5, 0, 12) from its origin
    vp.handle_message(pos(31100, goto), 31.1)
    assert vp.phase is Phase.GOING_TO_START
    vp.handle_message(_hb(OFFBOARD, armed=True), 31.2)
    vp.handle_message(pos(31300, goto), 31.3)
    assert vp.phase is Phase.READY


def test_failsafe_action_from_the_end_action_and_the_ending_in_px4_modes() -> None:
    vp = _make(ParamSettings(gcs_failsafe=True, end="land"))
    seen = _to_waiting(vp, 0.0)
    sets = {str(m["param_id"]): m for m in seen if m.name == "PARAM_SET"}
    act = sets["COM_OBL_RC_ACT"]
    assert act["param_type"] == INT32
    assert struct.unpack("<i", struct.pack("<f", act["param_value"]))[0] == 4  # Land
    assert vp.vehicle_params.changes["COM_OBL_RC_ACT"].readback == 4.0
    assert vp.vehicle_params.changes["COM_OF_LOSS_T"].new == 1.0
    # In the air: the end action LAND is PX4's AUTO.LAND, confirmed by HEARTBEAT.
    vp.handle_message(_hb(HOLD, armed=True), 1.0)
    vp.handle_message(pos(2000, (0.0, 0.0, -10.0)), 1.0)
    vp.take_outbound()
    vp.finish(2.0, mode=b.COPTER_MODES["LAND"])
    (mode,) = commands(vp.take_outbound(), b.MAV_CMD_DO_SET_MODE)
    assert (mode["param2"], mode["param3"]) == (4.0, 6.0)
    vp.handle_message(CommandAck(SYS, 1, b.MAV_CMD_DO_SET_MODE, 0), 2.1)
    vp.handle_message(_hb(LAND, armed=True), 2.5)
    assert vp.phase is Phase.ENDED and vp.mode_name == "AUTO.LAND"
