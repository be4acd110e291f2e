"""Unit tests of the vehicle's parameters (envelope read, GCS failsafe, fence,
restore): ``VehicleProtocol`` driven by hand-made PARAM_VALUE and the other
answers of an ArduCopter written out in ``Copter`` below, with a
hand-advanced clock (no sockets, no sleeps)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gcs_swarm.control.params import Envelope
from gcs_swarm.mavlink import GeoOrigin, MessageSpec, Phase, ProtocolConfig, VehicleProtocol
from gcs_swarm.mavlink.builders import (
    COPTER_MODES,
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_SET_MESSAGE_INTERVAL,
)
from gcs_swarm.mavlink.inbound import (
    CommandAck,
    EkfStatus,
    GpsGlobalOrigin,
    GpsRaw,
    Heartbeat,
    LocalPositionNed,
    ParamValue,
)
from gcs_swarm.mavlink.vehicle_params import (
    ARDUCOPTER_DEFAULTS,
    ENVELOPE_PARAMS,
    ParamSettings,
    envelope_from_params,
    failsafe_values,
    fence_values,
)

SYS = 2
GUIDED, LAND, BRAKE, STABILIZE = (COPTER_MODES[k] for k in ("GUIDED", "LAND", "BRAKE", "STABILIZE"))
REF = GeoOrigin(-35.0, 149.0, 600.0)
#: The vehicle's EKF origin (home): 2 m below the mission origin, right on it.
HOME = GeoOrigin(-35.0, 149.0, 598.0)
BOX = ((-50.0, -40.0, 0.0), (50.0, 40.0, 30.0))
ON = ParamSettings(
    read_envelope=True,
    gcs_failsafe=True,
    fence=True,
    end="land",
    geofence_min=BOX[0],
    geofence_max=BOX[1],
)


def f32(x: float) -> float:
    """What a PARAM_VALUE carries: the value as float32."""
    return float(np.float32(x))


class Copter:
    """The answers of an ArduCopter to the station's commands: PARAM_VALUE for
    a read of a name it knows and for every PARAM_SET (``clamp`` overrides the
    value it keeps), COMMAND_ACK accepted for streams and modes. Arming and
    take-off are answered by the tests."""

    def __init__(self, params: dict[str, float], *, silent: tuple[str, ...] = (),
                 clamp: dict[str, float] | None = None) -> None:  # fmt: skip
        self.params = dict(params)
        self.silent = set(silent)
        self.clamp = dict(clamp or {})
        self.sent: list[MessageSpec] = []

    def serve(self, vp: VehicleProtocol, now: float) -> None:
        for _ in range(500):
            out = vp.take_outbound()
            if not out:
                return
            for m in out:
                self.sent.append(m)
                self.answer(vp, m, now)
        raise AssertionError("the station never stops sending")

    def answer(self, vp: VehicleProtocol, m: MessageSpec, now: float) -> None:
        if m.name == "COMMAND_LONG" and m["command"] in (
            MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_DO_SET_MODE
        ):  # fmt: skip
            vp.handle_message(CommandAck(SYS, 1, int(m["command"]), 0), now)
        elif m.name in ("PARAM_REQUEST_READ", "PARAM_SET"):
            name = str(m["param_id"])
            if name in self.silent or name not in self.params:
                return
            if m.name == "PARAM_SET":
                self.params[name] = self.clamp.get(name, float(m["param_value"]))
            vp.handle_message(ParamValue(SYS, 1, name, f32(self.params[name])), now)

    def names(self, kind: str) -> list[str]:
        return [str(m["param_id"]) for m in self.sent if m.name == kind]

    def sets(self) -> list[tuple[str, float]]:
        return [(str(m["param_id"]), float(m["param_value"])) for m in self.sent
                if m.name == "PARAM_SET"]  # fmt: skip


def hb(mode: int, armed: bool = False) -> Heartbeat:
    return Heartbeat(SYS, 1, 2, 3, 1 | (128 if armed else 0), mode, 4)


def make(settings: ParamSettings = ON, **kw: object) -> VehicleProtocol:
    cfg = ProtocolConfig(mission_origin=REF, **kw)  # type: ignore[arg-type]
    return VehicleProtocol(SYS, cfg, goto_m=(0.0, 0.0, 10.0), params=settings)


def texts(vp: VehicleProtocol, kind: str | None = None) -> list[str]:
    return [e.text for e in vp.take_events() if kind is None or e.kind == kind]


def to_armable(vp: VehicleProtocol, copter: Copter, t: float) -> None:
    """CONFIGURING -> GUIDED -> sensors ready (the fence goes out here)."""
    vp.handle_message(hb(STABILIZE), t)
    copter.serve(vp, t)
    assert vp.phase is Phase.SETTING_GUIDED, vp.failure
    vp.handle_message(hb(GUIDED), t + 0.5)
    assert vp.phase is Phase.WAITING_ARMABLE
    vp.handle_message(
        GpsGlobalOrigin(SYS, 1, round(HOME.lat_deg * 1e7), round(HOME.lon_deg * 1e7),
                        round(HOME.alt_m * 1e3)), t + 1)  # fmt: skip
    vp.handle_message(GpsRaw(SYS, 1, 3, 10), t + 1)
    vp.handle_message(EkfStatus(SYS, 1, 1 | 2 | 4 | 16 | 32), t + 1)
    vp.handle_message(LocalPositionNed(SYS, 1, 1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), t + 1)
    copter.serve(vp, t + 1)


# ------------------------------------------------------------ pure values
def test_envelope_from_arducopters_defaults() -> None:
    env, missing = envelope_from_params(ARDUCOPTER_DEFAULTS)
    assert missing == ()
    got = (env.accel_xy, env.accel_z, env.jerk_xy, env.jerk_z,
           env.speed_xy, env.speed_up, env.speed_down)  # fmt: skip
    np.testing.assert_allclose(got, (2.5, 1.0, 5.0, 5.0, 10.0, 2.5, 1.5), rtol=0, atol=1e-12)
    assert env.lag_s == 0.2


def test_lean_angle_bounds_the_horizontal_acceleration() -> None:
    # Eq. E1: ANGLE_MAX 10 deg -> g tan(10 deg) = 1.729 m/s^2 < WPNAV_ACCEL 2.5.
    env, _ = envelope_from_params({**ARDUCOPTER_DEFAULTS, "ANGLE_MAX": 1000.0})
    assert env.accel_xy == pytest.approx(9.80665 * math.tan(math.radians(10.0)), rel=1e-12)
    env, _ = envelope_from_params({**ARDUCOPTER_DEFAULTS, "WPNAV_ACCEL": 800.0})
    assert env.accel_xy == pytest.approx(9.80665 * math.tan(math.radians(30.0)), rel=1e-12)


def test_missing_parameters_keep_the_missions_bounds() -> None:
    fallback = Envelope(accel_xy=2.0, accel_z=0.8, jerk_xy=3.0, lag_s=0.3)
    some = {k: ARDUCOPTER_DEFAULTS[k] for k in ("WPNAV_ACCEL_Z", "WPNAV_SPEED")}
    env, missing = envelope_from_params({**some, "PSC_JERK_XY": 0.0}, fallback)
    assert set(missing) == set(ENVELOPE_PARAMS) - set(some)  # 0 counts as not given
    assert (env.accel_xy, env.accel_z, env.jerk_xy, env.speed_xy) == (2.0, 1.0, 3.0, 10.0)
    assert math.isinf(env.jerk_z) and env.lag_s == 0.2
    env, missing = envelope_from_params({}, fallback)
    assert env == fallback and len(missing) == len(ENVELOPE_PARAMS)


@pytest.mark.parametrize(("end", "fs"), [("land", 5.0), ("rtl", 1.0), ("hold", 5.0)])
def test_gcs_failsafe_per_end_action(end: str, fs: float) -> None:
    values = failsafe_values(end, 7.0)  # type: ignore[arg-type]
    assert [(n, v) for n, v, _ in values] == [
        ("SYSID_MYGCS", 255.0), ("FS_GCS_TIMEOUT", 7.0), ("FS_GCS_ENABLE", fs)
    ]  # fmt: skip
    assert values[-1][2] == f"{'RTL' if fs == 1 else 'Land'} after 7 s without the station"


def test_fence_around_the_geofence_box_from_the_home() -> None:
    # Home 10 m east of the mission origin, 2 m below it; margin 5 m.
    values, notes = fence_values(BOX[0], BOX[1], (10.0, 0.0, -2.0), "rtl", 5.0)
    got = {n: v for n, v, _ in values}
    # Eq. F1: 30 + 5 - (-2) = 37 m above home. Eq. F2: farthest corner (-50, +-40)
    # is hypot(60, 40) = 72.111 m away, + 5 = 77.111, rounded up to 77.2 m.
    assert got == {"FENCE_TYPE": 3.0, "FENCE_ALT_MAX": 37.0, "FENCE_RADIUS": 77.2,
                   "FENCE_ACTION": 1.0, "FENCE_ENABLE": 1.0}  # fmt: skip
    assert [n for n, _, _ in values][-1] == "FENCE_ENABLE" and notes == ()
    values, _ = fence_values(BOX[0], BOX[1], (10.0, 0.0, -2.0), "hold", 5.0)
    assert dict((n, v) for n, v, _ in values)["FENCE_ACTION"] == 2.0
    # A small box: raised to ArduCopter's least radius (30 m) and ceiling (10 m).
    values, notes = fence_values((-5, -5, 0), (5, 5, 2), (0.0, 0.0, 0.0), "land", 1.0)
    got = {n: v for n, v, _ in values}
    assert (got["FENCE_RADIUS"], got["FENCE_ALT_MAX"]) == (30.0, 10.0) and len(notes) == 2


# ------------------------------------------------------ on the protocol
def test_start_up_reads_then_sets_then_fences_before_arming() -> None:
    vp, copter = make(), Copter(ARDUCOPTER_DEFAULTS)
    t = 10.0
    to_armable(vp, copter, t)
    reads, sets = copter.names("PARAM_REQUEST_READ"), copter.sets()
    # Old values first (the station's own GUID_TIMEOUT/WP_YAW_BEHAVIOR too),
    # then the envelope, then the failsafe, then the station's own sets.
    assert reads[:2] == ["GUID_TIMEOUT", "WP_YAW_BEHAVIOR"]
    assert set(ENVELOPE_PARAMS) <= set(reads) and len(reads) == 2 + 3 + 5 + 8
    assert [n for n, _ in sets[:5]] == ["SYSID_MYGCS", "FS_GCS_TIMEOUT", "FS_GCS_ENABLE",
                                        "GUID_TIMEOUT", "WP_YAW_BEHAVIOR"]  # fmt: skip
    first_set = next(i for i, m in enumerate(copter.sent) if m.name == "PARAM_SET")
    last_read = max(i for i, m in enumerate(copter.sent) if m.name == "PARAM_REQUEST_READ")
    assert last_read < first_set
    # The fence went out before the arming, and the arming waits for its echoes.
    arm_at = next(
        i
        for i, m in enumerate(copter.sent)
        if m.name == "COMMAND_LONG" and m["command"] == MAV_CMD_COMPONENT_ARM_DISARM
    )
    fence = [(str(m["param_id"]), i) for i, m in enumerate(copter.sent)
             if m.name == "PARAM_SET" and str(m["param_id"]).startswith("FENCE_")]  # fmt: skip
    assert [n for n, _ in fence] == ["FENCE_TYPE", "FENCE_ALT_MAX", "FENCE_RADIUS",
                                     "FENCE_ACTION", "FENCE_ENABLE"]  # fmt: skip
    assert all(i < arm_at for _, i in fence) and vp.phase is Phase.ARMING
    # Home at (0, 0, -2): 30 + 5 + 2 = 37 m; radius hypot(50, 40) + 5 = 69.03 -> 69.1 m.
    assert copter.params["FENCE_ALT_MAX"] == 37.0
    assert copter.params["FENCE_RADIUS"] == pytest.approx(69.1)
    assert copter.params["FENCE_ACTION"] == 2.0 and copter.params["FS_GCS_ENABLE"] == 5.0
    env = vp.envelope
    assert (env.accel_xy, env.accel_z, env.jerk_xy, env.speed_down) == (2.5, 1.0, 5.0, 1.5)
    lines = texts(vp)
    assert "vehicle 2: FS_GCS_ENABLE 0 -> 5 (Land after 5 s without the station)" in lines
    assert any(s.startswith("vehicle 2: SYSID_MYGCS 255 (unchanged") for s in lines)
    (envelope_line,) = [s for s in lines if "envelope" in s]
    assert "accel 2.50 xy 1.00 z m/s^2" in envelope_line
    assert "(from its parameters)" in envelope_line
    rec = {p["name"]: p for p in vp.vehicle_params.record()["params"]}
    assert (rec["FS_GCS_ENABLE"]["old"], rec["FS_GCS_ENABLE"]["readback"]) == (0.0, 5.0)
    assert rec["FENCE_RADIUS"]["readback"] == pytest.approx(69.1, abs=1e-5)  # float32 echo
    assert rec["GUID_TIMEOUT"]["old"] == 3.0 and rec["GUID_TIMEOUT"]["readback"] == 0.5


def test_a_different_echo_fails_the_start_up_naming_both_values() -> None:
    # The vehicle keeps FS_GCS_TIMEOUT at 5 whatever it is sent.
    vp = make(replace(ON, gcs_timeout_s=8.0))
    copter = Copter(ARDUCOPTER_DEFAULTS, clamp={"FS_GCS_TIMEOUT": 5.0})
    t = 10.0
    vp.handle_message(hb(STABILIZE), t)
    copter.serve(vp, t)
    assert vp.phase is Phase.CONFIGURING
    for _ in range(vp.config.command_attempts):  # resent on each timeout, echo still 5
        t += vp.config.command_timeout_s
        vp.handle_timer(t)
        copter.serve(vp, t)
    assert vp.phase is Phase.FAILED
    assert vp.failure == "FS_GCS_TIMEOUT: sent 8, the vehicle reports 5 (10 attempts)"
    assert copter.names("PARAM_SET").count("FS_GCS_TIMEOUT") == 10
    assert "FS_GCS_ENABLE" not in copter.names("PARAM_SET")  # never switched on


def test_a_late_answer_to_the_read_is_not_the_echo_of_the_set() -> None:
    vp, copter = make(), Copter(ARDUCOPTER_DEFAULTS)
    t = 10.0
    vp.handle_message(hb(STABILIZE), t)
    # Answer everything by hand up to the PARAM_SET of FS_GCS_ENABLE.
    for _ in range(100):
        out = vp.take_outbound()
        fs_set = [m for m in out if m.name == "PARAM_SET" and m["param_id"] == "FS_GCS_ENABLE"]
        if fs_set:
            break
        for m in out:
            copter.answer(vp, m, t)
    # The read's duplicated answer (0) arrives now: the set is still awaited...
    vp.handle_message(ParamValue(SYS, 1, "FS_GCS_ENABLE", 0.0), t)
    assert vp.take_outbound() == [] and vp.phase is Phase.CONFIGURING
    # ... its echo (5) answers it, and the queue goes on (GUID_TIMEOUT next).
    vp.handle_message(ParamValue(SYS, 1, "FS_GCS_ENABLE", 5.0), t)
    (nxt,) = vp.take_outbound()
    assert nxt.name == "PARAM_SET" and nxt["param_id"] == "GUID_TIMEOUT"


def test_a_late_answer_to_the_read_is_not_the_echo_of_the_stations_own_set() -> None:
    # The same for the station's own sets (GUID_TIMEOUT 0.5, WP_YAW_BEHAVIOR 0),
    # read first too. Before: any PARAM_VALUE of the name answered their
    # PARAM_SET, so on a duplicating link the read's late copy (3) passed for
    # the echo of a PARAM_SET the vehicle never got, and the vehicle kept
    # braking 3 s, not 0.5 s, after the setpoints stop.
    vp, copter = make(), Copter(ARDUCOPTER_DEFAULTS)
    t = 10.0
    vp.handle_message(hb(STABILIZE), t)
    for _ in range(100):
        out = vp.take_outbound()
        gt_set = [m for m in out if m.name == "PARAM_SET" and m["param_id"] == "GUID_TIMEOUT"]
        if gt_set:
            break
        for m in out:
            copter.answer(vp, m, t)
    assert gt_set and gt_set[0]["param_value"] == 0.5  # lost on its way: the vehicle keeps 3
    vp.handle_message(ParamValue(SYS, 1, "GUID_TIMEOUT", 3.0), t)  # the read's late copy
    assert vp.take_outbound() == [] and vp.phase is Phase.CONFIGURING
    t += vp.config.command_timeout_s  # no echo: sent again (attempt 2)
    vp.handle_timer(t)
    (again,) = vp.take_outbound()
    assert again.name == "PARAM_SET" and again["param_id"] == "GUID_TIMEOUT"
    copter.answer(vp, again, t)  # its echo (0.5) answers it; WP_YAW_BEHAVIOR next
    (nxt,) = vp.take_outbound()
    assert nxt.name == "PARAM_SET" and nxt["param_id"] == "WP_YAW_BEHAVIOR"
    assert copter.params["GUID_TIMEOUT"] == 0.5
    assert "vehicle 2: GUID_TIMEOUT = 0.5 s: when setpoints stop it brakes after this" in texts(vp)


def test_a_vehicle_that_answers_no_read_starts_with_the_missions_envelope() -> None:
    fallback = Envelope(accel_xy=2.0, accel_z=1.0)
    vp = make(ParamSettings(read_envelope=True, fallback=fallback))
    known = {k: v for k, v in ARDUCOPTER_DEFAULTS.items() if k not in ENVELOPE_PARAMS}
    copter = Copter(known)  # answers GUID_TIMEOUT and WP_YAW_BEHAVIOR only
    t = 10.0
    vp.handle_message(hb(STABILIZE), t)
    copter.serve(vp, t)
    for _ in range(40):
        t += vp.config.command_timeout_s
        vp.handle_message(hb(STABILIZE), t)  # its HEARTBEATs keep coming
        vp.handle_timer(t)
        copter.serve(vp, t)
        if vp.phase is not Phase.CONFIGURING:
            break
    assert vp.phase is Phase.SETTING_GUIDED  # a read never fails the start-up
    reads = copter.names("PARAM_REQUEST_READ")
    # The usual 10 sends for the first silent name, 2 for each later one.
    assert reads.count("WPNAV_ACCEL") == 10
    assert [reads.count(n) for n in ENVELOPE_PARAMS[1:]] == [2] * 7
    assert vp.envelope == fallback
    lines = texts(vp)
    assert sum("no answer to PARAM_REQUEST_READ" in s for s in lines) == 8
    rec = vp.vehicle_params.record()
    assert rec["envelope_source"] == "mission" and len(rec["envelope_unanswered"]) == 8


def test_off_by_default_the_traffic_is_as_before() -> None:
    vp, copter = make(ParamSettings()), Copter(ARDUCOPTER_DEFAULTS)
    to_armable(vp, copter, 10.0)
    assert copter.names("PARAM_REQUEST_READ") == []
    assert copter.names("PARAM_SET") == ["GUID_TIMEOUT", "WP_YAW_BEHAVIOR"]
    assert vp.envelope == Envelope()


def _fly_and_end(vp: VehicleProtocol, copter: Copter, t: float, mode: int) -> float:
    to_armable(vp, copter, t)
    vp.handle_message(hb(GUIDED, armed=True), t + 2)
    # airborne (5 m up) when the run ends: a vehicle still on the ground would
    # be disarmed instead of given the end mode (VehicleProtocol.finish)
    vp.handle_message(LocalPositionNed(SYS, 1, 2000, 0.0, 0.0, -5.0, 0.0, 0.0, 0.0), t + 2.5)
    vp.take_outbound()
    texts(vp)
    vp.finish(t + 3, mode=mode)
    copter.serve(vp, t + 3)
    vp.handle_message(hb(mode, armed=True), t + 3.5)
    assert vp.phase is Phase.ENDED
    return t + 3.5


def test_the_old_values_are_restored_once_the_end_is_confirmed() -> None:
    vp, copter = make(), Copter({**ARDUCOPTER_DEFAULTS, "FENCE_TYPE": 3.0})
    t = _fly_and_end(vp, copter, 10.0, LAND)
    before = len(copter.sent)
    assert vp.restoring
    copter.serve(vp, t)
    assert not vp.restoring
    restored = copter.sets()[-(len(copter.sent) - before) :]
    # Every changed parameter, back to its old value; FENCE_TYPE (3 already),
    # SYSID_MYGCS (255) and FS_GCS_TIMEOUT (5) were not changed, so not restored.
    assert dict(restored) == {
        "FS_GCS_ENABLE": 0.0, "GUID_TIMEOUT": 3.0, "WP_YAW_BEHAVIOR": 2.0,
        "FENCE_ALT_MAX": 100.0, "FENCE_RADIUS": 300.0, "FENCE_ACTION": 1.0, "FENCE_ENABLE": 0.0,
    }  # fmt: skip
    assert len(restored) == 7
    assert {k: v for k, v in copter.params.items() if k in ARDUCOPTER_DEFAULTS} == {
        **ARDUCOPTER_DEFAULTS, "FENCE_TYPE": 3.0
    }  # fmt: skip
    rec = {p["name"]: p for p in vp.vehicle_params.record()["params"]}
    assert rec["FS_GCS_ENABLE"]["restored"] is True and rec["FS_GCS_ENABLE"]["readback"] == 5.0
    assert rec["FENCE_TYPE"]["changed"] is False and rec["FENCE_TYPE"]["restored"] is None
    assert any(s == "vehicle 2: FS_GCS_ENABLE restored to 0" for s in texts(vp, "param"))


def test_a_vehicle_left_hovering_keeps_its_failsafe_and_fence() -> None:
    vp, copter = make(replace(ON, end="hold")), Copter(ARDUCOPTER_DEFAULTS)
    t = _fly_and_end(vp, copter, 10.0, BRAKE)
    before = len(copter.sent)
    copter.serve(vp, t)
    restored = dict(copter.sets()[-(len(copter.sent) - before) :])
    assert restored == {"GUID_TIMEOUT": 3.0, "WP_YAW_BEHAVIOR": 2.0}
    assert copter.params["FS_GCS_ENABLE"] == 5.0 and copter.params["FENCE_ENABLE"] == 1.0
    rec = {p["name"]: p for p in vp.vehicle_params.record()["params"]}
    assert rec["FS_GCS_ENABLE"]["restored"] is None
    assert rec["FS_GCS_ENABLE"]["note"].startswith("kept: the vehicle is still armed")


def test_restore_off_and_unanswered_restores_are_reported_not_fatal() -> None:
    vp, copter = make(replace(ON, restore=False)), Copter(ARDUCOPTER_DEFAULTS)
    t = _fly_and_end(vp, copter, 10.0, LAND)
    assert not vp.restoring and vp.take_outbound() == []
    rec = {p["name"]: p for p in vp.vehicle_params.record()["params"]}
    assert "restore false" in rec["FS_GCS_ENABLE"]["note"]
    # A vehicle that no longer answers: 3 sends per parameter, then reported.
    vp, copter = make(), Copter(ARDUCOPTER_DEFAULTS)
    t = _fly_and_end(vp, copter, 10.0, LAND)
    copter.silent = set(copter.params)
    copter.serve(vp, t)
    for _ in range(60):
        t += vp.config.command_timeout_s
        vp.handle_message(hb(LAND, armed=True), t)
        vp.handle_timer(t)
        copter.serve(vp, t)
    assert vp.phase is Phase.ENDED and not vp.restoring
    assert copter.names("PARAM_SET").count("FS_GCS_ENABLE") == 1 + 3
    warnings = texts(vp, "warning")
    assert "vehicle 2: FS_GCS_ENABLE not restored to 0 (no answer; the vehicle reports 5)" in (
        warnings
    )
