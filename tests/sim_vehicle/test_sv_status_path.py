"""ArduCopter's status streams without a poll (``reports``, "The status path").

The station asks every ArduCopter for EKF_STATUS_REPORT, GPS_RAW_INT and
EXTENDED_SYS_STATE at 2 Hz (one bucket). Until the nineteenth session each
autopilot was polled for them, twice a second: at 1,500 vehicles about a
sixth of the emulator's samples were those polls and a twelfth the packing
of what they returned (docs/emulator.md). A row whose only due work is those
streams is now not polled: the emulator takes them (``take_fleet_streams``,
the poll's rule) and packs their frames from the autopilot's state and the
row's kinematics (``status_frame``). Checked here:

- ``status_frame`` gives the bytes pymavlink packs ``build``'s message to,
  for random positions, velocities, EKF and landed states and ids;
- two ``EmulatorCore``s, one with the path and one polling as before, take
  the same random datagrams (SET_MESSAGE_INTERVAL of these and other
  streams at several intervals, off and default; take-off, landing, mode
  changes, arming, the acceleration stream, parameters) from a boot on the
  ground: every datagram sent is the same, bit for bit, every fleet array
  but the schedule's (``deadline``, ``st_next``), and every autopilot's
  state but its poll deadline and ``version`` (which counts bumps: a poll
  folds a held setpoint of the deferred lane, one more bump);
- the path is taken (else the comparison proves nothing): hovering
  vehicles send the three streams at 2 Hz with no poll deadline before the
  next one's.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import EmulatorConfig, VehicleSpec, reports
from sim_vehicle.core import EmulatorCore
from sim_vehicle.telemetry import Kin
from tests.sim_vehicle.state_bits import canon
from tests.sim_vehicle.test_sv_deferred_lane import STATION, _messages, _Port

_GCS = mav.MAVLink(None, srcSystem=255, srcComponent=190)
EKF = mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT
GPS = mav.MAVLINK_MSG_ID_GPS_RAW_INT
EXT = mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE
STATUS = {EKF: 2.0, GPS: 2.0, EXT: 2.0}


def _core(path: bool, airborne: bool, n: int = 2) -> tuple[EmulatorCore, _Port]:
    cfg = EmulatorConfig(
        vehicles=tuple(
            VehicleSpec(
                sysid=k + 1,
                start_ned_m=(5.0 * k, 0.0, -3.0 if airborne else 0.0),
                airborne=airborne,
            )
            for k in range(n)
        ),
        clock="lockstep",
        dynamics="ardupilot",
        streams=STATUS,
        params={"DISARM_DELAY": 4.0},
    )
    core, port = EmulatorCore(cfg), _Port()
    core.status_path = path
    core.ports.append(port)
    for spec in cfg.vehicles:
        core.add(spec, port, initial=True, enc=mav.MAVLink(None, spec.sysid, spec.compid))
    return core, port


@pytest.mark.parametrize("seed", range(4))
def test_status_frames_are_pymavlinks_bytes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    core, _ = _core(True, airborne=True, n=1)
    ap = core.rows[0].ap
    for _ in range(200):
        pos = tuple(float(x) for x in rng.normal(0.0, 10.0 ** rng.integers(-1, 5), 3))
        vel = tuple(float(x) for x in rng.normal(0.0, 10.0 ** rng.integers(-3, 2), 3))
        if rng.random() < 0.1:
            vel = (0.0, -0.0, 0.0)
        ap.ekf_ready = bool(rng.random() < 0.7)
        ap.land_complete = bool(rng.random() < 0.3)
        ap._ctl = str(rng.choice(["accel", "land", "takeoff", "spool", "hold"]))
        now = float(rng.uniform(0.0, 5000.0))
        seq, sysid, compid = (int(x) for x in rng.integers([0, 1, 0], [256, 256, 256]))
        kin = Kin(pos, vel, (0.0, 0.0, 0.0), False)
        for msgid in (EKF, GPS, EXT):
            enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
            enc.seq = seq
            want = ap.build(msgid, now, kin).pack(enc)
            got = reports.status_frame(ap, msgid, now, pos, vel, (seq, sysid, compid))
            assert got == want, (msgid, pos, vel, ap.ekf_ready, ap.landed_state)


def _interval(sysid: int, msgid: int, us: float) -> bytes:
    return mav.MAVLink_command_long_message(sysid, 1, 511, 0, msgid, us, 0, 0, 0, 0, 0).pack(_GCS)


def _accel(sysid: int, a: tuple[float, float, float]) -> bytes:
    return mav.MAVLink_set_position_target_local_ned_message(
        0, sysid, 1, mav.MAV_FRAME_LOCAL_NED, 3135, 0, 0, 0, 0, 0, 0, *a, 0, 0
    ).pack(_GCS)


def _command(sysid: int, cmd: int, *p: float) -> bytes:
    args = list(p) + [0.0] * (7 - len(p))
    return mav.MAVLink_command_long_message(sysid, 1, cmd, 0, *args).pack(_GCS)


_EVENT = st.one_of(
    st.tuples(
        st.just("interval"),
        st.integers(1, 2),
        st.sampled_from(
            [
                EKF,
                GPS,
                EXT,
                EKF,
                GPS,
                EXT,
                mav.MAVLINK_MSG_ID_SYS_STATUS,
                mav.MAVLINK_MSG_ID_ATTITUDE,
            ]
        ),
        st.sampled_from([500_000.0, 500_000.0, 1_000_000.0, 250_000.0, 200_000.0, 0.0, -1.0]),
    ),
    st.tuples(st.just("mode"), st.integers(1, 2), st.sampled_from([4, 4, 9, 6, 17, 5]), st.just(0)),
    st.tuples(st.just("arm"), st.integers(1, 2), st.sampled_from([1.0, 1.0, 0.0]), st.just(0)),
    st.tuples(st.just("takeoff"), st.integers(1, 2), st.sampled_from([2.0, 5.0]), st.just(0)),
    st.tuples(st.just("param"), st.integers(1, 2), st.sampled_from([0.3, 3.0]), st.just(0)),
)
_STEP = st.tuples(
    st.sampled_from(["stream"] * 4 + ["pause"] * 3 + ["event"] * 2),
    st.tuples(*[st.floats(-2.0, 2.0)] * 3),
    _EVENT,
    st.integers(1, 60),  # steps the choice lasts
)


def _datagram(kind: str, a: Any, event: Any) -> bytes:
    if kind == "stream":
        return _accel(1, a) + _accel(2, (a[1], a[0], a[2]))
    if kind == "pause":
        return b""
    what, sysid, x, y = event
    if what == "interval":
        return _interval(sysid, x, y)
    if what == "mode":
        return mav.MAVLink_set_mode_message(sysid, 1, x).pack(_GCS)
    if what == "arm":
        return _command(sysid, 400, x)
    if what == "takeoff":
        return _command(sysid, 22, 0, 0, 0, 0, 0, 0, x)
    return mav.MAVLink_param_set_message(sysid, 1, b"GUID_TIMEOUT", x, 9).pack(_GCS)


_Z = (0.0, 0.0, 0.0)


def _s(kind: str, steps: int, event: Any = ("mode", 1, 4, 0), a: Any = _Z) -> Any:
    return (kind, a, event, steps)


_UP = [_s("pause", 60), _s("pause", 60), _s("pause", 60),  # boot; EKF ready after 2 s
       _s("event", 1, ("mode", 1, 4, 0)), _s("event", 1, ("mode", 2, 4, 0)),
       _s("event", 1, ("arm", 1, 1.0, 0)), _s("event", 1, ("arm", 2, 1.0, 0)),
       _s("event", 1, ("takeoff", 1, 5.0, 0)), _s("event", 1, ("takeoff", 2, 2.0, 0))]  # fmt: skip
"""From a boot on the ground: the EKF ready, GUIDED, armed, taking off."""


def _arrays(core: EmulatorCore, skip: set[str]) -> dict[str, bytes]:
    items = vars(core.fleet).items()
    return {k: x.tobytes() for k, x in items if isinstance(x, np.ndarray) and k not in skip}


@settings(max_examples=40, deadline=None)
@given(st.booleans(), st.lists(_STEP, min_size=3, max_size=25))
# from a boot on the ground: GUIDED, armed, off the ground, then streams,
# a landing and the bucket moved to 1 Hz and back
@example(
    False,
    [
        *_UP,
        *[_s("pause", 60)] * 5,
        _s("stream", 60, a=(0.5, 0.0, -0.2)),
        _s("event", 1, ("interval", 1, GPS, 1_000_000.0)),
        _s("event", 1, ("mode", 2, 9, 0)),
        *[_s("pause", 60)] * 5,
        _s("event", 1, ("interval", 1, GPS, 500_000.0)),
        *[_s("pause", 60)] * 8,
    ],
)
# the same, and the plan the generator starts from on the ground
@example(False, [*_UP, *[_s("stream", 60, a=(0.1, 0.2, 0.0))] * 4])  # fmt: skip
def test_the_status_path_sends_what_the_polls_sent(airborne: bool, plan: list[Any]) -> None:
    (fast, fast_port), (slow, slow_port) = _core(True, airborne), _core(False, airborne)
    parsers = [mav.MAVLink(None), mav.MAVLink(None)]
    skip = {"deadline", "st_next"}
    for kind, a, event, steps in plan:
        for _ in range(steps if kind != "event" else 1):
            data = _datagram(kind, a, event)
            for core, port, parser in (
                (fast, fast_port, parsers[0]),
                (slow, slow_port, parsers[1]),
            ):
                if data:
                    core.receive(port, _messages(data, parser), STATION, None)
                core.step()
            assert fast_port.sent == slow_port.sent, f"t = {fast.sim_time_s:.3f} s"
            arrays = [_arrays(c, skip) for c in (fast, slow)]
            assert arrays[0] == arrays[1], f"t = {fast.sim_time_s:.3f} s"
    fast.fold()
    slow.fold()
    # ``version`` counts bumps: a poll folds a held setpoint (one more bump)
    skip_ap = {"deadline", "fleet_streams", "version"}
    states = [[canon(vars(v.ap), skip=skip_ap) for v in c.rows] for c in (fast, slow)]
    assert states[0] == states[1]


def test_hovering_vehicles_send_the_bucket_without_a_poll() -> None:
    """40 vehicles hovering in GUIDED: each sends the three streams every
    0.5 s, while its poll deadline lies past the next bucket (nothing else
    is due): the status path, not the poll, sent them."""
    core, port = _core(True, airborne=True, n=40)
    parser = mav.MAVLink(None)
    for _ in range(round(2.0 / core.dt)):  # the first bucket from the poll (its plan at add)
        core.step()
    port.sent.clear()
    counts: dict[tuple[int, int], int] = {}
    for _ in range(round(10.0 / core.dt)):
        core.step()
        f = core.fleet
        assert np.isfinite(f.st_next).all() and np.all(f.deadline > f.st_next)
        for data in port.sent:
            for m in parser.parse_buffer(data) or []:
                if m.get_msgId() in STATUS:
                    key = (m.get_srcSystem(), m.get_msgId())
                    counts[key] = counts.get(key, 0) + 1
        port.sent.clear()
    assert set(counts) == {(s, m) for s in range(1, 41) for m in STATUS}
    assert set(counts.values()) == {20}, counts  # 2 Hz for 10 s
    assert all(math.isinf(v.ap.deadline) or v.ap.deadline > 12.0 for v in core.rows)
