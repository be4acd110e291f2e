"""Unit tests of the I/O-free autopilot with a hand-advanced clock (no sockets, no loop)."""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle.autopilot import Autopilot
from sim_vehicle.config import DEFAULT_ORIGIN
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin

ENC = mav.MAVLink(None, 255, 190)
HOVER = Kin((0.0, 0.0, -10.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False)
GROUND = Kin((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), True)


def _decoded(msg: Any) -> Any:
    """Round-trip through bytes so the autopilot sees what a parser would give it."""
    return mav.MAVLink(None, 1, 1).parse_buffer(msg.pack(ENC))[0]


def _sp(mask: int, frame: int = 1, a: tuple[float, float, float] = (1.0, 0.0, 0.0)) -> Any:
    return _decoded(
        mav.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, frame, mask, 5.0, 6.0, -7.0, 0.5, 0.0, 0.0, *a, 0.0, 0.0
        )
    )


def _cmd(cmd: int, *p: float) -> Any:
    q = [*p, 0, 0, 0, 0, 0, 0, 0][:7]
    return _decoded(mav.MAVLink_command_long_message(1, 1, cmd, 0, *q))


def _airborne(**params: float) -> Autopilot:
    return Autopilot(1, DEFAULT_ORIGIN, ParamStore(params), 0.0, airborne_at=HOVER.pos)


def test_type_mask_table() -> None:
    ap = _airborne()
    ap.handle(_sp(3135), 0.0, HOVER)  # acceleration only
    assert ap.target.a_ff == (1.0, 0.0, 0.0) and ap.target.wv == 0.0
    ap.handle(_sp(0b110111000111), 0.0, HOVER)  # velocity only (pos, accel, yaw ignored)
    assert ap.target.v_t == (0.5, 0.0, 0.0) and ap.target.wp == (0.0, 0.0, 0.0)
    ap.handle(_sp(0b110111111000), 0.0, HOVER)  # position only
    assert ap.target.p_t == (5.0, 6.0, -7.0) and ap.target.wp == (1.0, 1.0, 1.0)
    ap.handle(_sp(0b110111000000), 0.0, HOVER)  # position + velocity
    assert ap.target.p_t == (5.0, 6.0, -7.0) and ap.target.v_t == (0.5, 0.0, 0.0)


def test_force_set_is_dropped_and_bad_frame_or_combination_stops() -> None:
    ap = _airborne()
    ap.handle(_sp(3135), 0.0, HOVER)
    before = ap.target
    ap.handle(_sp(3135 | 512, a=(0.0, 3.0, 0.0)), 0.1, HOVER)
    assert ap.target == before  # FORCE_SET: dropped
    ap.handle(_sp(3135, frame=mav.MAV_FRAME_GLOBAL_INT), 0.2, HOVER)
    assert ap.target.a_ff == (0.0, 0.0, 0.0) and ap.target.wv == 1.0  # stop: brake
    ap.handle(_sp(3135), 0.3, HOVER)
    ap.handle(_sp(0b110000111000), 0.4, HOVER)  # position + accel without velocity: invalid
    assert ap.target.a_ff == (0.0, 0.0, 0.0) and ap.mode == 4


def test_setpoints_ignored_outside_guided_or_on_ground() -> None:
    ap = _airborne()
    ap.handle(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 5), 0.0, HOVER)  # LOITER
    ap.handle(_sp(3135), 0.1, HOVER)
    assert ap.target.a_ff == (0.0, 0.0, 0.0)
    ground = Autopilot(1, DEFAULT_ORIGIN, ParamStore({"SIM_EKF_DELAY": 0}), 0.0)
    ground.handle(_cmd(mav.MAV_CMD_DO_SET_MODE, 1, 4), 0.0, GROUND)
    ground.handle(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), 0.0, GROUND)
    assert ground.armed
    ground.handle(_sp(3135), 0.1, GROUND)
    assert ground.target.a_ff == (0.0, 0.0, 0.0)


def test_guid_timeout_brakes_and_keeps_guided() -> None:
    ap = _airborne(GUID_TIMEOUT=0.5)
    ap.handle(_sp(3135), 1.0, HOVER)
    assert ap.deadline <= 1.5
    ap.poll(1.49, HOVER)
    assert ap.target.a_ff == (1.0, 0.0, 0.0)  # still applied before the timeout
    ap.poll(1.5, HOVER)
    assert ap.target.a_ff == (0.0, 0.0, 0.0) and ap.target.wv == 1.0  # braking
    assert ap.mode == 4
    ap.poll(1.52, HOVER)  # at rest: hold where it stopped
    assert ap.target.wp == (1.0, 1.0, 1.0) and ap.target.p_t == HOVER.pos


def test_guid_timeout_floor_is_a_tenth_of_a_second() -> None:
    ap = _airborne(GUID_TIMEOUT=0.0)
    ap.handle(_sp(3135), 0.0, HOVER)
    ap.poll(0.09, HOVER)
    assert ap.target.a_ff == (1.0, 0.0, 0.0)


def test_arming_refused_until_ekf_ready_then_auto_disarm() -> None:
    ap = Autopilot(1, DEFAULT_ORIGIN, ParamStore({"SIM_EKF_DELAY": 5, "DISARM_DELAY": 3}), 0.0)
    out = ap.handle(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), 1.0, GROUND)
    assert out[0].get_type() == "STATUSTEXT" and out[0].text.startswith("PreArm:")
    assert out[1].result == mav.MAV_RESULT_FAILED
    sent = ap.poll(5.0, GROUND)
    assert {m.get_type() for m in sent} >= {"GPS_GLOBAL_ORIGIN", "HOME_POSITION"}
    out = ap.handle(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1), 5.0, GROUND)
    assert out[-1].result == mav.MAV_RESULT_ACCEPTED and ap.armed
    assert ap.deadline <= 8.0
    ap.poll(7.9, GROUND)
    assert ap.armed
    ap.poll(8.0, GROUND)
    assert not ap.armed


def test_unknown_command_is_unsupported() -> None:
    ap = _airborne()
    (ack,) = ap.handle(_cmd(mav.MAV_CMD_DO_SET_SERVO, 1, 1500), 0.0, HOVER)
    assert ack.result == mav.MAV_RESULT_UNSUPPORTED and ack.command == mav.MAV_CMD_DO_SET_SERVO


def _sent_times(
    ap: Autopilot, asks: list[tuple[float, int, float]], until: float
) -> dict[int, list[float]]:
    """Poll ``ap`` at its deadlines on a 50 Hz clock, handing it the
    SET_MESSAGE_INTERVAL ``asks`` (time, message id, interval s) on the way:
    when each asked message went out."""
    sent: dict[int, list[float]] = {mid: [] for _, mid, _ in asks}
    pending = sorted(asks)
    for k in range(round(until / 0.02) + 1):
        now = round(k * 0.02, 6)
        while pending and pending[0][0] <= now + 1e-9:
            _, mid, interval = pending.pop(0)
            ap.handle(_cmd(511, mid, interval * 1e6), now, HOVER)
        if ap.deadline <= now + 1e-9:
            for msg in ap.poll(now, HOVER):
                if msg.get_msgId() in sent:
                    sent[msg.get_msgId()].append(now)
    return sent


def test_streams_of_one_interval_share_arducopter_s_bucket() -> None:
    """ArduCopter 4.5.6 SITL, measured (docs/emulator.md): EKF_STATUS_REPORT,
    GPS_RAW_INT and EXTENDED_SYS_STATE asked at 2 Hz at 0, 62 and 141 ms
    came first at 0.502, 1.004 and 1.004 s, then together every 0.5 s. On the
    emulator's 50 Hz clock, asked at 0, 60 and 140 ms: the first one interval
    after it was asked for, the two that joined its bucket at the bucket's
    send after its next, then all three at once."""
    ekf, gps, ess = 193, 24, 245
    asks = [(0.0, ekf, 0.5), (0.06, gps, 0.5), (0.14, ess, 0.5)]
    sent = _sent_times(_airborne(), asks, 2.6)
    assert sent[ekf] == [0.5, 1.0, 1.5, 2.0, 2.5]
    assert sent[gps] == sent[ess] == [1.0, 1.5, 2.0, 2.5]
    # Asked again at its interval, a stream keeps its bucket's times.
    sent = _sent_times(_airborne(), [*asks, (0.7, ekf, 0.5), (1.2, gps, 0.5)], 2.6)
    assert sent[ekf] == [0.5, 1.0, 1.5, 2.0, 2.5]
    assert sent[gps] == sent[ess] == [1.0, 1.5, 2.0, 2.5]
    # Another interval is a bucket of its own: first one interval after the ask.
    sent = _sent_times(_airborne(), [(0.0, ekf, 0.5), (0.1, gps, 0.25)], 1.2)
    assert sent[ekf] == [0.5, 1.0] and sent[gps] == [0.36, 0.6, 0.86, 1.1]
