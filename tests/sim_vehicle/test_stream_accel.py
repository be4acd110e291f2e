"""The streamed setpoint's fast lane (``commands.stream_accel``) against ``dispatch``.

Two autopilots of the same spec take the same random sequence of setpoints
(every type_mask, frame, target and value class the station or a stranger
could send, NaN and out-of-range included), mode changes, touch-downs and
GUID_TIMEOUT changes: one through ``stream_accel`` first and ``handle`` when
it declines, the other through ``handle`` alone, which is what the
emulator did for every message before the lane. After every step their
whole state must be the same bit for bit (floats compared by their bits,
so a 0.0 for a -0.0 fails), and the lane must have been taken. ``raw``:
the lane reads the setpoint from its packed frame's fields
(``codec.RawSetpoint``, ``stream_accel_fields``), as the emulator's core
does, and the message it declines is the one the frame decodes to.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import EmulatorConfig, VehicleSpec
from sim_vehicle.autopilot import Autopilot
from sim_vehicle.codec import decode_setpoint
from sim_vehicle.commands import stream_accel, stream_accel_fields
from sim_vehicle.telemetry import Kin
from sim_vehicle.vehicles import autopilot_for

DT = 0.02


def _canon(x: Any, depth: int = 0) -> Any:
    """A value comparable bit for bit: floats as their hex, containers and
    plain objects by their contents (the autopilot's whole state)."""
    if depth > 6:
        return repr(type(x))
    if isinstance(x, float):
        return ("f", x.hex() if math.isfinite(x) else repr(x))
    if isinstance(x, (str, int, bool, type(None))):
        return x
    if isinstance(x, dict):
        return {k: _canon(v, depth + 1) for k, v in x.items()}
    if isinstance(x, (list, tuple, deque)):
        return (type(x).__name__, [_canon(v, depth + 1) for v in x])
    if isinstance(x, (set, frozenset)):
        return sorted(repr(v) for v in x)
    if hasattr(x, "__dict__"):
        return (type(x).__name__, _canon(vars(x), depth + 1))
    return repr(x)


def _state(ap: Autopilot) -> Any:
    return _canon(vars(ap))


_MASKS = [3135, 3135 | mav.POSITION_TARGET_TYPEMASK_FORCE_SET, 3079, 3576, 3072, 0, 3135 & ~1024]
_FRAMES = [mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_OFFSET_NED, mav.MAV_FRAME_BODY_NED,
           mav.MAV_FRAME_BODY_OFFSET_NED, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT]  # fmt: skip
_VALUES = st.one_of(
    st.floats(-20.0, 20.0),
    st.sampled_from([0.0, -0.0, -1.5, math.nan, math.inf, -math.inf, 1e5, -1e5, 1.0000001e5]),
)

# The station's own message (3135, LOCAL_NED, to it) most often: the lane's case.
_setpoint = st.tuples(
    st.just("sp"),
    st.one_of(st.just(3135), st.sampled_from(_MASKS)),
    st.one_of(st.just(mav.MAV_FRAME_LOCAL_NED), st.sampled_from(_FRAMES)),
    st.tuples(_VALUES, _VALUES, _VALUES),
    st.sampled_from([0, 1, 1, 1, 2]),  # target system: broadcast, it, another
    st.sampled_from([0, 1, 1, 1, 7]),  # target component
)
_op = st.one_of(
    _setpoint,
    _setpoint,
    _setpoint,
    st.tuples(st.just("mode"), st.sampled_from([4, 4, 5, 6, 9])),
    st.tuples(st.just("landed"), st.booleans()),
    st.tuples(st.just("guid_timeout"), st.sampled_from([0.05, 0.5, 3.0])),
    st.tuples(st.just("poll")),
)


def _message(op: tuple[Any, ...]) -> mav.MAVLink_set_position_target_local_ned_message:
    _, mask, frame, (ax, ay, az), ts, tc = op
    return mav.MAVLink_set_position_target_local_ned_message(
        1000, ts, tc, frame, mask, 1.0, -2.0, -3.0, 0.5, 0.0, -0.1, ax, ay, az, 0.3, 0.0
    )


_LOCAL = mav.MAV_FRAME_LOCAL_NED
_ENCODER = mav.MAVLink(None, srcSystem=255, srcComponent=190)


@settings(max_examples=300, deadline=None)
@given(
    autopilot=st.sampled_from(["ardupilot", "px4"]),
    ops=st.lists(_op, min_size=1, max_size=60),
    raw=st.booleans(),
)
# Signed zeros: the frame's rotation by yaw 0 turns (-0.0, y < 0) into (0.0, y).
@example(autopilot="ardupilot", ops=[("sp", 3135, _LOCAL, (-0.0, -1.5, 0.0), 1, 1)], raw=False)
@example(autopilot="ardupilot", ops=[("sp", 3135, _LOCAL, (2.0, -0.0, -0.0), 0, 0)], raw=True)
# Touched down, then the stream: ignored.
@example(
    autopilot="ardupilot", ops=[("landed", True), ("sp", 3135, _LOCAL, (1.0, 0, 0), 1, 1)], raw=True
)
# Beyond SETPOINT_LIMIT, and NaN: rejected and counted.
@example(autopilot="ardupilot", ops=[("sp", 3135, _LOCAL, (1.0000001e5, 0, 0), 1, 1),
                                     ("sp", 3135, _LOCAL, (math.nan, 0, 0), 0, 1)],
         raw=True)  # fmt: skip
def test_the_fast_lane_leaves_the_autopilot_as_dispatch_does(
    autopilot: str, ops: list[tuple[Any, ...]], raw: bool
) -> None:
    cfg = EmulatorConfig(dynamics="ardupilot")
    spec = VehicleSpec(sysid=1, start_ned_m=(0.0, 0.0, -10.0), airborne=True,
                       autopilot=autopilot)  # type: ignore[arg-type]  # fmt: skip
    fast, slow = autopilot_for(cfg, spec, 0.0), autopilot_for(cfg, spec, 0.0)
    assert _state(fast) == _state(slow)
    landed, now = False, 0.0
    for op in ops:
        now += DT
        kin = Kin((0.0, 0.0, -10.0), (0.5, 0.0, 0.0), (0.0, 0.0, 0.0), landed)
        if op[0] == "sp":
            msg = _message(op)
            if raw:  # as the emulator's core takes it: from the frame's fields
                sp = decode_setpoint(msg.pack(_ENCODER), 0, len(msg.get_payload()))
                assert sp is not None
                msg, f = sp.message(), sp.f
                taken = stream_accel_fields(
                    fast, f[12], f[15], f[13], f[14], f[7], f[8], f[9], now, landed
                )
            else:
                taken = stream_accel(fast, msg, now, landed)
            if not taken:
                assert fast.handle(msg, now, kin) == []
            assert slow.handle(msg, now, kin) == []
        elif op[0] == "mode":
            assert fast.set_mode(op[1], now, kin) == slow.set_mode(op[1], now, kin)
        elif op[0] == "landed":
            landed = op[1]
        elif op[0] == "guid_timeout":
            for ap in (fast, slow):
                ap.params.set("GUID_TIMEOUT", op[1])
                ap.refresh(now, kin)
        else:
            for ap in (fast, slow):
                ap.poll(now, kin)
        assert _state(fast) == _state(slow), op


def test_the_fast_lane_takes_the_stations_stream_on_both_autopilots() -> None:
    """The case it is for: the station's own message, GUIDED (PX4: OFFBOARD,
    after the pre-stream), armed, in the air. It is taken, and the target's
    feed-forward is the setpoint's acceleration."""
    cfg = EmulatorConfig(dynamics="ardupilot")
    for autopilot in ("ardupilot", "px4"):
        spec = VehicleSpec(sysid=1, start_ned_m=(0.0, 0.0, -10.0), airborne=True,
                           autopilot=autopilot)  # type: ignore[arg-type]  # fmt: skip
        ap = autopilot_for(cfg, spec, 0.0)
        kin = Kin((0.0, 0.0, -10.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False)
        msg = _message(("sp", 3135, mav.MAV_FRAME_LOCAL_NED, (0.25, -0.5, 0.125), 1, 1))
        now = 0.0
        for _ in range(10):  # PX4 asks for a stream before OFFBOARD
            now += DT
            ap.handle(msg, now, kin)
        assert ap.set_mode(4, now, kin), autopilot
        taken = 0
        for _ in range(100):
            now += DT
            taken += stream_accel(ap, msg, now, False)
            ap.poll(now, kin)
        assert taken == 100, autopilot
        assert ap.target.a_ff == (0.25, -0.5, 0.125), autopilot
