"""The emulator core's deferred lane against every setpoint taken at once.

Two ``EmulatorCore``s of the same configuration (two ArduCopters sharing
one port, airborne a metre up, shaping on) take the same random sequence
of datagrams on a hand-advanced clock: the station's acceleration stream
(ordinary values, hard downward ones that land a vehicle, NaN and absurd
ones, another component's), pauses longer than GUID_TIMEOUT (a brake,
then the stream again), GUID_TIMEOUT changed in flight, mode changes,
position targets, the GCS HEARTBEAT to every vehicle of the port (which
does not fold a held setpoint: it commutes with one), arming and
disarming; with the GCS failsafe off, and on at 0.3 s (the pauses set it
off; the HEARTBEATs plan its check). One core holds the streamed setpoints it may
(``defer_stream``, ``EmulatorCore._deliver``), the other calls each
vehicle's autopilot for every one, as before the lane. After every
physics step every fleet array and every datagram the two sent must be
the same bit for bit, and at the end (``fold``) every autopilot's whole
state (floats by their bits) but ``version``, which counts bumps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import EmulatorConfig, Impairment, VehicleSpec
from sim_vehicle.core import EmulatorCore
from sim_vehicle.impairments import Impairer
from sim_vehicle.link import _split_setpoints
from tests.sim_vehicle.state_bits import canon

STATION = ("127.0.0.1", 14550)
_GCS = mav.MAVLink(None, srcSystem=255, srcComponent=190)


def _clean(seed: int) -> Impairer:
    return Impairer(Impairment(), np.random.default_rng(seed))


@dataclass(eq=False)
class _Port:
    """A ``core.Port`` that keeps what it sends (no socket)."""

    shared: bool = True
    uplink: Impairer = field(default_factory=lambda: _clean(0))
    downlink: Impairer = field(default_factory=lambda: _clean(1))
    out: tuple[str, int] | None = STATION
    sysids: dict[int, int] = field(default_factory=dict)
    peers: dict[tuple[str, int], None] = field(default_factory=lambda: {STATION: None})
    outbox: list[tuple[bytes, int]] = field(default_factory=list)
    signing_key: bytes | None = None
    silent: bool = False
    sent: list[bytes] = field(default_factory=list)

    def sendto(self, data: bytes, addr: tuple[str, int]) -> None:
        self.sent.append(data)

    def close(self) -> None:
        pass


def _core(defer: bool, fs_gcs: int = 0) -> tuple[EmulatorCore, _Port]:
    cfg = EmulatorConfig(
        vehicles=(
            VehicleSpec(sysid=1, start_ned_m=(0.0, 0.0, -1.0), airborne=True),
            VehicleSpec(sysid=2, start_ned_m=(5.0, 0.0, -1.0), airborne=True),
        ),
        clock="lockstep",
        dynamics="ardupilot",
        streams={mav.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 1.0},
        params={"FS_GCS_ENABLE": fs_gcs, "FS_GCS_TIMEOUT": 0.3},
    )
    core, port = EmulatorCore(cfg), _Port()
    core.defer_stream = defer
    core.ports.append(port)
    for spec in cfg.vehicles:
        core.add(spec, port, initial=True, enc=mav.MAVLink(None, spec.sysid, spec.compid))
    return core, port


def _accel(sysid: int, a: tuple[float, float, float], comp: int = 1) -> bytes:
    return mav.MAVLink_set_position_target_local_ned_message(
        0, sysid, comp, mav.MAV_FRAME_LOCAL_NED, 3135, 0, 0, 0, 0, 0, 0, *a, 0, 0
    ).pack(_GCS)


_VALUE = st.one_of(
    st.tuples(*[st.floats(-4.0, 4.0)] * 3),
    st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(4.0, 9.0)),  # down hard: lands
    st.sampled_from([(math.nan, 0.0, 0.0), (0.0, 2e5, 0.0), (-0.0, -0.0, 0.0)]),
)
_EVENT = st.one_of(
    st.tuples(st.just("timeout"), st.integers(1, 2), st.sampled_from([0.1, 0.3, 3.0])),
    st.tuples(st.just("mode"), st.integers(1, 2), st.sampled_from([4, 4, 17, 9, 5])),
    st.tuples(st.just("pos"), st.integers(1, 2), st.floats(-3.0, -0.5)),
    st.tuples(st.just("arm"), st.integers(1, 2), st.sampled_from([0.0, 1.0])),
    st.tuples(st.just("heartbeat"), st.just(0), st.just(0)),
    st.tuples(st.just("other"), st.integers(1, 2), st.just(0)),
)
_STEP = st.tuples(
    st.sampled_from(["stream"] * 6 + ["pause"] * 2 + ["event"]),
    _VALUE,
    _EVENT,
    st.integers(1, 25),  # steps the choice lasts
)


def _datagram(kind: str, value: Any, event: Any) -> bytes:
    if kind == "stream":
        return _accel(1, value) + _accel(2, (value[1], value[0], value[2]))
    if kind == "pause":
        return b""
    what, sysid, x = event
    if what == "timeout":
        return mav.MAVLink_param_set_message(sysid, 1, b"GUID_TIMEOUT", x, 9).pack(_GCS)
    if what == "mode":
        return mav.MAVLink_set_mode_message(sysid, 1, x).pack(_GCS)
    if what == "pos":
        return mav.MAVLink_set_position_target_local_ned_message(
            0, sysid, 1, mav.MAV_FRAME_LOCAL_NED, 3576, 0.0, 0.0, x, 0, 0, 0, 0, 0, 0, 0, 0
        ).pack(_GCS)
    if what == "arm":
        return mav.MAVLink_command_long_message(sysid, 1, 400, 0, x, 0, 0, 0, 0, 0, 0).pack(_GCS)
    if what == "heartbeat":
        return mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(_GCS)
    return _accel(sysid, (0.0, 3.0, 0.0), comp=7)  # for another component


def _messages(data: bytes, parser: Any) -> list[Any]:
    msgs: list[Any] = []
    for piece in _split_setpoints(data):
        msgs.extend(parser.parse_buffer(piece) or [] if isinstance(piece, bytes) else [piece])
    return msgs


def _arrays(core: EmulatorCore) -> dict[str, bytes]:
    return {k: a.tobytes() for k, a in vars(core.fleet).items() if isinstance(a, np.ndarray)}


_Z = (0.0, 0.0, 0.0)
_NO = ("heartbeat", 0, 0)


def _s(kind: str, steps: int, value: Any = _Z, event: Any = _NO) -> Any:
    return (kind, value, event, steps)


@settings(max_examples=60, deadline=None)
@given(st.lists(_STEP, min_size=5, max_size=30))
# GUID_TIMEOUT lowered in flight, then a pause before the next poll: the
# stream's next setpoint must lower the deadline, or the brake comes late.
@example([_s("stream", 25), _s("event", 1, event=("timeout", 1, 0.1)), _s("stream", 3),
          _s("pause", 20), _s("stream", 10)])  # fmt: skip
# another component's setpoint is not this vehicle's
@example([_s("stream", 10), _s("event", 1, event=("other", 1, 0)), _s("stream", 5)])
# landed while streaming: the lane must not fly a landed vehicle
@example([_s("stream", 25, (0.0, 0.0, 8.0)), _s("stream", 25, (0.0, 0.0, 8.0)),
          _s("stream", 25, (0.0, 0.0, -3.0)), _s("stream", 25, (1.0, 0.0, -3.0))])  # fmt: skip
# GUID_TIMEOUT's brake and hold, then the stream again; BRAKE and GUIDED
@example([_s("stream", 10), _s("pause", 25), _s("pause", 25), _s("pause", 25), _s("pause", 25),
          _s("stream", 10, (1.0, 0.0, 0.0)), _s("event", 1, event=("mode", 1, 17)),
          _s("stream", 10), _s("event", 1, event=("mode", 1, 4)), _s("stream", 10),
          _s("event", 1, event=("arm", 2, 0.0)), _s("stream", 10)])  # fmt: skip
@pytest.mark.parametrize("fs_gcs", [0, 1])
def test_held_setpoints_fly_as_setpoints_taken_at_once(fs_gcs: int, plan: list[Any]) -> None:
    (lane, lane_port), (direct, direct_port) = _core(True, fs_gcs), _core(False, fs_gcs)
    parsers = [mav.MAVLink(None), mav.MAVLink(None)]
    for kind, value, event, steps in plan:
        for _ in range(steps if kind != "event" else 1):
            data = _datagram(kind, value, event)
            pairs = ((lane, lane_port, parsers[0]), (direct, direct_port, parsers[1]))
            for core, port, parser in pairs:
                if data:
                    core.receive(port, _messages(data, parser), STATION, None)
                core.step()
            assert _arrays(lane) == _arrays(direct), f"t = {lane.sim_time_s:.2f} s"
            assert lane_port.sent == direct_port.sent, f"t = {lane.sim_time_s:.2f} s"
    lane.fold()
    states = [[canon(vars(v.ap), skip={"version"}) for v in c.rows] for c in (lane, direct)]
    assert states[0] == states[1]
    assert all(v.lane_a is None for v in direct.rows)


def test_the_stream_is_held_where_the_lane_is_open() -> None:
    """The lane does take the stream (else the comparison above proves nothing):
    every setpoint after the first of a stream is held, and none for a landed
    vehicle."""
    core, port = _core(True)
    parser = mav.MAVLink(None)
    held = []
    for _ in range(50):
        core.receive(port, _messages(_accel(1, (0.0, 0.0, 0.0)), parser), STATION, None)
        held.append(core.rows[0].lane_a is not None)
        core.step()
    assert held == [False] + [True] * 49
    for _ in range(150):  # down hard until it lands: the lane closes
        core.receive(port, _messages(_accel(1, (0.0, 0.0, 8.0)), parser), STATION, None)
        core.step()
    assert core.fleet.landed[0] and core.rows[0].lane_a is None
