"""Start-up and take-over that work the first time on a freshly booted
ArduCopter 4.5.6 (issue 14 item 1), as unit tests of ``VehicleProtocol`` with
hand-made messages and a hand-advanced clock.

The sequences replay what SITL did (mavlink-protocol.md, "Start-up
sequence"): GUIDED accepted at 0.2 s, then "ArduPilot Ready" and a HEARTBEAT
in STABILIZE (custom_mode 0) about 1 s later; "Arming motors" (INFO) before
the arm's ACK; a take-off refused with result 4 and no STATUSTEXT of its own.
"""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.mavlink import Codec, MessageSpec, Phase, VehicleProtocol, from_pymavlink
from gcs_swarm.mavlink.builders import (
    COPTER_MODES,
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_SET_MESSAGE_INTERVAL,
)
from gcs_swarm.mavlink.commands import NO_REASON, refusal_reason
from gcs_swarm.mavlink.inbound import CommandAck, ExtendedSysState, StatusText
from tests.mavlink.vehicle_harness import (
    GUIDED,
    STABILIZE,
    SYS,
    commands,
    configure,
    hb,
    make,
    pos,
    ready_sensors,
)

LAND = COPTER_MODES["LAND"]
INFO, WARNING, CRITICAL = 6, 4, 2
ARM, TAKEOFF, SET_MODE = MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_NAV_TAKEOFF, MAV_CMD_DO_SET_MODE


def landed(state: int) -> ExtendedSysState:
    return ExtendedSysState(SYS, 1, 0, state)


def arms(out: list[MessageSpec]) -> list[MessageSpec]:
    return [m for m in commands(out, ARM) if m["param1"] == 1.0]


def disarms(out: list[MessageSpec]) -> list[MessageSpec]:
    return [m for m in commands(out, ARM) if m["param1"] == 0.0]


def guided_asks(out: list[MessageSpec]) -> int:
    return sum(1 for m in commands(out, SET_MODE) if m["param2"] == GUIDED)


def _to_guided_confirmed(vp: VehicleProtocol, t: float) -> None:
    """STABILIZE at connection -> GUIDED asked, accepted, shown by HEARTBEAT."""
    configure(vp, t)
    assert guided_asks(vp.take_outbound()) == 1
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), t + 0.2)
    vp.handle_message(hb(GUIDED), t + 0.5)
    assert vp.phase is Phase.WAITING_ARMABLE


def _armed_and_taking_off(vp: VehicleProtocol, t: float) -> None:
    """Through arming (with SITL's INFO chatter) to the take-off in flight."""
    _to_guided_confirmed(vp, t)
    ready_sensors(vp, t + 1.0)
    assert vp.phase is Phase.ARMING and arms(vp.take_outbound())
    vp.handle_message(StatusText(SYS, 1, INFO, "Arming motors"), t + 1.01)
    vp.handle_message(CommandAck(SYS, 1, ARM, 0), t + 1.02)
    assert vp.phase is Phase.TAKING_OFF and commands(vp.take_outbound(), TAKEOFF)


# ------------------------------------------------------------ GUIDED kept
def test_guided_lost_to_stabilize_at_end_of_boot_is_set_again_before_arming() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _to_guided_confirmed(vp, 0.0)
    vp.take_events()
    # ~1 s later ArduCopter finishes booting and returns to STABILIZE.
    vp.handle_message(StatusText(SYS, 1, INFO, "ArduPilot Ready"), 1.2)
    vp.handle_message(hb(STABILIZE), 1.5)
    assert vp.phase is Phase.SETTING_GUIDED
    assert guided_asks(vp.take_outbound()) == 1
    # Routine on every fresh ArduCopter: logged, not a warning.
    events = [(e.kind, e.text) for e in vp.take_events() if "asking for" in e.text]
    assert events == [
        ("info",
         f"vehicle {SYS}: in STABILIZE while waiting: asking for GUIDED again (2 of at most 8)")
    ]  # fmt: skip
    # EKF, GPS and origin ready while GUIDED is not yet confirmed: no arm.
    ready_sensors(vp, 2.0)
    vp.handle_message(hb(STABILIZE), 2.05)  # sent before the switch: before its ACK
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), 2.1)
    assert not arms(vp.take_outbound()) and vp.phase is Phase.SETTING_GUIDED
    vp.handle_message(hb(GUIDED), 2.5)
    assert vp.phase is Phase.ARMING
    assert len(arms(vp.take_outbound())) == 1


def test_stabilize_shown_after_guided_was_accepted_asks_again_at_once() -> None:
    # The boot ends between the accepting ACK and the next HEARTBEAT (as the
    # emulator with boot_s = 1 s does): that HEARTBEAT says STABILIZE.
    vp = make(heartbeat_timeout_s=100.0)
    configure(vp, 0.0)
    vp.take_outbound()
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), 0.2)
    vp.handle_message(StatusText(SYS, 1, INFO, "ArduPilot Ready"), 1.0)
    vp.handle_message(hb(STABILIZE), 1.0)
    assert guided_asks(vp.take_outbound()) == 1  # at once, not after the 2 s confirm wait
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), 1.1)
    vp.handle_message(hb(GUIDED), 2.0)
    assert vp.phase is Phase.WAITING_ARMABLE
    # A refused GUIDED is not asked again on every HEARTBEAT: after the wait.
    vp = make(heartbeat_timeout_s=100.0)
    configure(vp, 0.0)
    vp.take_outbound()
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 4), 0.2)
    vp.handle_message(hb(STABILIZE), 1.0)
    assert guided_asks(vp.take_outbound()) == 0
    vp.handle_timer(0.2 + 2 * vp.config.command_timeout_s)
    assert guided_asks(vp.take_outbound()) == 1


def test_arm_is_never_sent_while_the_heartbeat_says_stabilize() -> None:
    # An autopilot that accepts GUIDED but whose HEARTBEAT always says
    # STABILIZE: GUIDED is asked guided_attempts times, never an arm, then the
    # vehicle fails saying why.
    vp = make(heartbeat_timeout_s=100.0)
    configure(vp, 0.0)
    ready_sensors(vp, 0.0)
    out: list[MessageSpec] = []
    t = 0.0
    while vp.phase is not Phase.FAILED and t < 100.0:
        out += vp.take_outbound()
        if commands(out[-1:], SET_MODE):
            vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), t + 0.05)
        t = round(t + 0.5, 6)
        vp.handle_message(hb(STABILIZE), t)
        vp.handle_timer(t)
    out += vp.take_outbound()
    assert not arms(out) and not commands(out, TAKEOFF)
    assert guided_asks(out) == vp.config.guided_attempts == 8
    assert vp.failure == "GUIDED not kept: asked 8 times, the vehicle is in STABILIZE"
    # Each ask after the first was reported, with why: the first re-ask as
    # info (routine at the end of boot), every later one as a warning.
    asks = [(e.kind, e.text) for e in vp.take_events() if "asking for" in e.text]
    assert [k for k, _ in asks] == ["info"] + ["warning"] * 6
    assert asks[-1][1].endswith("asking for GUIDED again (8 of at most 8)")
    assert asks[0][1] == (
        f"vehicle {SYS}: in STABILIZE after GUIDED was accepted: asking for GUIDED "
        "again (2 of at most 8)"
    )


def test_mode_lost_between_arm_attempts_is_set_again_before_the_retry() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _to_guided_confirmed(vp, 0.0)
    ready_sensors(vp, 1.0)
    assert arms(vp.take_outbound())
    vp.handle_message(StatusText(SYS, 1, CRITICAL, "PreArm: Gyros still settling"), 1.05)
    vp.handle_message(CommandAck(SYS, 1, ARM, 4), 1.06)
    assert vp.next_deadline() == pytest.approx(3.0)  # the retry, 2 s after the attempt
    vp.handle_message(hb(STABILIZE), 2.0)
    out = vp.take_outbound()
    assert guided_asks(out) == 1 and vp.phase is Phase.SETTING_GUIDED
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), 2.1)
    vp.handle_timer(3.0)
    assert not arms(vp.take_outbound())  # the retry waits for GUIDED
    vp.handle_message(hb(GUIDED), 3.5)
    assert len(arms(vp.take_outbound())) == 1


def test_take_off_refused_in_stabilize_asks_guided_then_takes_off() -> None:
    # The run: armed, then ArduCopter was in STABILIZE and refused the
    # take-off (result 4). Now: GUIDED again, then the take-off at once (the
    # vehicle is still armed on the ground: no second arm).
    vp = make(heartbeat_timeout_s=100.0)
    _armed_and_taking_off(vp, 0.0)
    vp.handle_message(hb(STABILIZE, armed=True), 1.03)
    assert vp.phase is Phase.SETTING_GUIDED
    vp.handle_message(CommandAck(SYS, 1, TAKEOFF, 4), 1.04)  # the take-off in flight
    out = vp.take_outbound()
    assert guided_asks(out) == 1 and not commands(out, TAKEOFF)
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), 1.1)
    vp.handle_message(hb(GUIDED, armed=True), 1.5)
    out = vp.take_outbound()
    assert not arms(out) and len(commands(out, TAKEOFF)) == 1
    assert vp.phase is Phase.TAKING_OFF


def test_mode_change_when_ready_still_means_someone_else_has_it() -> None:
    vp = make()
    configure(vp, 0.0, mode=GUIDED, armed=True)
    ready_sensors(vp, 0.1, ned=(-100.0, 5.0, -22.0))
    assert vp.phase is Phase.READY
    vp.handle_message(hb(COPTER_MODES["LOITER"], armed=True), 0.5)
    assert vp.phase is Phase.FAILED and "someone else has it" in str(vp.failure)
    assert guided_asks(vp.take_outbound()) == 0


# ------------------------------------------------ take-off or take-over
@pytest.mark.parametrize(
    ("landed_stream", "state", "up_m"),
    [(0, 1, 0.0), (2, None, 0.1)],
    ids=["landed-state-on-ground", "no-landed-state-height-0.1m"],
)
def test_armed_on_the_ground_takes_off_at_once_never_taken_over(
    landed_stream: int, state: int | None, up_m: float
) -> None:
    vp = make()
    configure(vp, 0.0, mode=GUIDED, armed=True, landed_stream=landed_stream)
    vp.take_outbound()
    if state is not None:
        vp.handle_message(landed(state), 0.05)
    ready_sensors(vp, 0.1, ned=(0.0, 0.0, -up_m))
    out = vp.take_outbound()
    assert not vp.took_over and vp.phase is Phase.TAKING_OFF
    assert not arms(out)  # already armed: arming is a no-op
    (tko,) = commands(out, TAKEOFF)
    assert tko["param7"] == pytest.approx(22.0 - up_m)  # to the start's height
    assert not [m for m in out if m.name == "SET_POSITION_TARGET_LOCAL_NED"]
    info = [e.text for e in vp.take_events() if e.kind == "info"]
    assert any("is armed on the ground" in t and "taking off at once" in t for t in info), info


@pytest.mark.parametrize(
    ("landed_stream", "state", "up_m"),
    [(0, 2, 0.5), (2, None, 22.0)],
    ids=["landed-state-in-air-0.5m", "no-landed-state-height-22m"],
)
def test_in_the_air_armed_in_guided_is_taken_over(
    landed_stream: int, state: int | None, up_m: float
) -> None:
    # The landed state wins over the height (in the air at 0.5 m); without it,
    # 22 m above the origin is in the air.
    vp = make()
    configure(vp, 0.0, mode=GUIDED, armed=True, landed_stream=landed_stream)
    vp.take_outbound()
    if state is not None:
        vp.handle_message(landed(state), 0.05)
    ready_sensors(vp, 0.1, ned=(-90.0, 5.0, -up_m))  # 10 m from its start
    out = vp.take_outbound()
    assert vp.took_over and vp.phase is Phase.GOING_TO_START
    assert not commands(out, ARM) and not commands(out, TAKEOFF)
    (sp,) = [m for m in out if m.name == "SET_POSITION_TARGET_LOCAL_NED"]
    assert sp["z"] == pytest.approx(-22.0, abs=0.01)


def test_landed_state_on_the_ground_wins_over_a_height() -> None:
    # Booted on a roof 3 m above where the EKF origin was set, say: the
    # landed state says ground, so it takes off instead of being "taken over".
    vp = make()
    configure(vp, 0.0, mode=GUIDED, armed=True)
    vp.handle_message(landed(1), 0.05)
    ready_sensors(vp, 0.1, ned=(0.0, 0.0, -3.0))
    assert vp.phase is Phase.TAKING_OFF and not vp.took_over


def test_extended_sys_state_decodes_from_the_wire_and_streams_at_the_status_rate() -> None:
    mav = dialect.MAVLink(None, SYS, 1)
    (msg,) = Codec().decode(mav.extended_sys_state_encode(0, 2).pack(mav))
    assert from_pymavlink(msg) == ExtendedSysState(SYS, 1, 0, 2)
    vp = make()
    vp.handle_message(hb(STABILIZE), 0.0)
    for _ in range(3):
        vp.handle_message(CommandAck(SYS, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0), 0.0)
    (ask,) = commands(vp.take_outbound(), MAV_CMD_SET_MESSAGE_INTERVAL)[-1:]
    assert (ask["param1"], ask["param2"]) == (245, 500_000)  # 2 Hz, as EKF_STATUS_REPORT


def test_denied_landed_state_stream_is_said_once_in_the_log() -> None:
    vp = make()
    configure(vp, 0.0, landed_stream=3)
    info = [e.text for e in vp.take_events() if "EXTENDED_SYS_STATE" in e.text]
    assert info == [
        f"vehicle {SYS}: no EXTENDED_SYS_STATE stream (unsupported): on the ground or in "
        "the air is judged from the armed flag and the height"
    ]


# ----------------------------------------------------- refusal reasons
def test_refusal_reason_picks_arming_checks_and_warnings_never_chatter() -> None:
    texts = [
        (INFO, "Arming motors"),
        (WARNING, "EKF3 lane switch 1"),
        (CRITICAL, "PreArm: Need Position Estimate"),
        (CRITICAL, "PreArm: Need Position Estimate"),
        (5, "Throttle armed"),
        (3, "Arm: Mode not armable"),
    ]
    assert refusal_reason(texts) == (
        "PreArm: Need Position Estimate; Arm: Mode not armable; EKF3 lane switch 1"
    )
    assert refusal_reason([(INFO, "Arming motors")]) == NO_REASON == "no reason given"
    assert refusal_reason([]) == NO_REASON


def test_take_off_refusal_quotes_its_own_statustext_not_the_arming_chatter() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _armed_and_taking_off(vp, 0.0)
    vp.handle_message(hb(GUIDED, armed=True), 1.03)
    vp.handle_message(StatusText(SYS, 1, INFO, "EKF3 IMU0 is using GPS"), 1.05)
    vp.handle_message(CommandAck(SYS, 1, TAKEOFF, 4), 1.06)
    assert vp.phase is Phase.TAKING_OFF  # decided on the next HEARTBEAT, not a stale one
    vp.handle_message(hb(GUIDED, armed=True), 1.5)
    assert vp.phase is Phase.FAILED
    assert vp.failure == "take-off refused (failed) in GUIDED, armed: no reason given"
    refused = [e.text for e in vp.take_events() if e.kind == "refused"]
    assert refused == [f"vehicle {SYS}: take-off refused (failed): no reason given"]


def test_arming_refusal_quotes_only_texts_heard_while_that_arm_was_pending() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _to_guided_confirmed(vp, 0.0)
    # Heard before any arm was sent: not this arm's reason.
    vp.handle_message(StatusText(SYS, 1, CRITICAL, "PreArm: Need 3D Fix"), 0.8)
    ready_sensors(vp, 1.0)
    assert arms(vp.take_outbound())
    vp.handle_message(StatusText(SYS, 1, INFO, "Arming motors"), 1.01)
    vp.handle_message(StatusText(SYS, 1, CRITICAL, "PreArm: Gyros inconsistent"), 1.02)
    vp.handle_message(CommandAck(SYS, 1, ARM, 4), 1.03)
    refused = [e.text for e in vp.take_events() if e.kind == "refused"]
    assert refused == [
        f"vehicle {SYS}: arming (attempt 1) refused (failed): PreArm: Gyros inconsistent"
    ]


# ------------------------------------------------------ failed start-up
def _run_clock(vp: VehicleProtocol, t0: float, t1: float, *, armed: bool) -> list[MessageSpec]:
    """Advance the clock from ``t0`` to ``t1`` [s] in 0.25 s steps, the
    vehicle sending HEARTBEAT (GUIDED) and telemetry, firing every timer."""
    out: list[MessageSpec] = []
    k = 0
    t = t0
    while t < t1:
        k += 1
        t = t0 + 0.25 * k
        vp.handle_message(hb(GUIDED, armed=armed), t)
        vp.handle_message(pos(10_000 + 250 * k, (0.0, 0.0, 0.0)), t)
        vp.handle_timer(t)
        out += vp.take_outbound()
    return out


def test_failed_start_up_disarms_a_vehicle_whose_arm_was_in_flight_then_sends_nothing() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _to_guided_confirmed(vp, 0.0)
    ready_sensors(vp, 1.0)
    assert arms(vp.take_outbound())  # pending: its ACK has not come
    vp.finish(1.1, mode=LAND)  # another vehicle failed: the start-up is aborted
    out = vp.take_outbound()
    assert len(disarms(out)) == 1 and not arms(out)
    assert not commands(out, SET_MODE)  # on the ground: no end mode, no setpoint
    assert not [m for m in out if m.name == "SET_POSITION_TARGET_LOCAL_NED"]
    assert vp.phase is Phase.ENDING
    # The late arm lands (its ACK answers the pending disarm's number) and the
    # vehicle says armed: the disarm is asked again after end_confirm_timeout_s.
    vp.handle_message(CommandAck(SYS, 1, ARM, 0), 1.2)
    out = _run_clock(vp, 1.2, 1.2 + vp.config.end_confirm_timeout_s + 0.1, armed=True)
    assert len(disarms(out)) == 1 and not arms(out)
    vp.handle_message(CommandAck(SYS, 1, ARM, 0), 4.5)
    vp.handle_message(hb(GUIDED, armed=False), 5.0)
    assert vp.phase is Phase.ENDED
    # Past every retry interval (arm 2 s, commands 1 s, GUIDED confirm 2 s,
    # take-off 40 s): nothing more goes out.
    assert _run_clock(vp, 5.0, 60.0, armed=False) == []
    assert vp.next_deadline() is None


def test_failed_start_up_cancels_a_pending_arm_retry() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _to_guided_confirmed(vp, 0.0)
    ready_sensors(vp, 1.0)
    vp.take_outbound()
    vp.handle_message(CommandAck(SYS, 1, ARM, 4), 1.05)  # refused: retry due at 3 s
    vp.finish(1.5, mode=LAND)
    out = vp.take_outbound()
    assert len(disarms(out)) == 1  # an arm went out: undo it whatever its fate
    vp.handle_message(CommandAck(SYS, 1, ARM, 0), 1.6)
    vp.handle_message(hb(GUIDED, armed=False), 2.0)
    assert vp.phase is Phase.ENDED
    out = _run_clock(vp, 2.0, 60.0, armed=False)
    assert not commands(out, ARM) and not commands(out, TAKEOFF) and not commands(out, SET_MODE)


def test_vehicle_failed_armed_on_the_ground_is_disarmed_at_the_end() -> None:
    # Take-off refused for good (in GUIDED, armed): FAILED, still armed on the
    # ground. The end of the run disarms it; it keeps its failure for the summary.
    vp = make(heartbeat_timeout_s=100.0)
    _armed_and_taking_off(vp, 0.0)
    vp.handle_message(hb(GUIDED, armed=True), 1.03)
    vp.handle_message(CommandAck(SYS, 1, TAKEOFF, 4), 1.06)
    vp.handle_message(hb(GUIDED, armed=True), 1.4)
    assert vp.phase is Phase.FAILED
    vp.finish(1.5, mode=LAND)
    out = vp.take_outbound()
    assert len(disarms(out)) == 1 and not commands(out, SET_MODE)
    vp.handle_message(CommandAck(SYS, 1, ARM, 0), 1.6)
    vp.handle_message(hb(GUIDED, armed=False), 2.0)
    assert vp.phase is Phase.ENDED and "take-off refused" in str(vp.failure)


def test_airborne_vehicle_of_a_failed_start_up_gets_the_end_mode() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _armed_and_taking_off(vp, 0.0)
    vp.handle_message(CommandAck(SYS, 1, TAKEOFF, 0), 1.05)
    vp.handle_message(landed(3), 1.5)  # taking off
    vp.handle_message(pos(3000, (0.0, 0.0, -4.0)), 2.0)
    vp.take_outbound()
    vp.finish(2.1, mode=LAND)
    out = vp.take_outbound()
    assert not disarms(out)
    assert out[0].name == "SET_POSITION_TARGET_LOCAL_NED" and out[0]["afz"] == 0.0
    assert [m["param2"] for m in commands(out, SET_MODE)] == [LAND]


def test_disarm_refused_in_flight_falls_back_to_the_end_mode() -> None:
    # No landed state and 0.4 m up (below ground_height_m): judged on the
    # ground; ArduCopter refuses the disarm (it is flying), so it is landed.
    vp = make(heartbeat_timeout_s=100.0)
    _armed_and_taking_off(vp, 0.0)
    vp.handle_message(pos(3000, (0.0, 0.0, -0.4)), 2.0)
    vp.take_outbound()
    vp.finish(2.1, mode=LAND)
    assert len(disarms(vp.take_outbound())) == 1
    vp.handle_message(CommandAck(SYS, 1, ARM, 4), 2.2)
    out = vp.take_outbound()
    assert out[0].name == "SET_POSITION_TARGET_LOCAL_NED"
    assert [m["param2"] for m in commands(out, SET_MODE)] == [LAND]
    vp.handle_message(CommandAck(SYS, 1, SET_MODE, 0), 2.3)
    vp.handle_message(hb(LAND, armed=True), 2.5)
    assert vp.phase is Phase.ENDED


def test_vehicle_never_armed_on_the_ground_just_stops() -> None:
    vp = make(heartbeat_timeout_s=100.0)
    _to_guided_confirmed(vp, 0.0)
    vp.take_outbound()
    vp.finish(1.0, mode=LAND)
    assert vp.phase is Phase.ENDED and vp.take_outbound() == []


def test_a_refused_take_off_is_judged_on_a_fresh_heartbeat_not_a_stale_one() -> None:
    # Seen in the emulator: the boot's end (back to STABILIZE) came 20 ms before
    # the arm; the last HEARTBEAT still said GUIDED and disarmed, so each refusal
    # read as "disarmed itself" and the vehicle was re-armed until the tries ran out.
    vp = make(heartbeat_timeout_s=100.0)
    _armed_and_taking_off(vp, 0.0)
    vp.handle_message(CommandAck(SYS, 1, TAKEOFF, 4), 1.06)
    assert vp.phase is Phase.TAKING_OFF
    assert not arms(vp.take_outbound())  # nothing decided on the stale HEARTBEAT
    vp.handle_message(hb(STABILIZE, armed=True), 1.5)  # what really happened
    out = vp.take_outbound()
    assert commands(out, MAV_CMD_DO_SET_MODE) and not arms(out)  # GUIDED again, no re-arm
    assert vp.phase is not Phase.FAILED
