"""``lane.take_stream`` (a shared endpoint's setpoints taken column-wise)
against ``EmulatorCore.receive`` of each datagram in turn.

Two real-time ``EmulatorCore``s of one configuration (four airborne
ArduCopters and a PX4 on one shared port) take the same random reads of
datagrams on a hand-advanced clock: one offers each read to
``take_stream`` first and receives each datagram only if it declines (as
``server.Emulator._on_datagrams`` does), the other receives each datagram.
The reads mix the station's stream with what the lane must refuse (NaN and
absurd values, hard downward ones that land a vehicle, another component's,
another type_mask or frame, a trimmed frame, a bad CRC, an unknown or
broadcast system id, other messages). After every read and physics step the
fleet arrays, the datagrams sent, the counters (but the one that counts the
column-wise reads) and each vehicle's held setpoint must be the same bit
for bit, and at the end every autopilot's whole state. Then each reason to
decline, one at a time, changes nothing; and over real UDP the shell reads a
network's datagrams together and takes them.
"""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import math
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import Emulator, EmulatorConfig, Impairment, VehicleSpec
from sim_vehicle.core import EmulatorCore
from sim_vehicle.impairments import Impairer
from sim_vehicle.lane import MIN_BYTES, take_stream
from sim_vehicle.link import Endpoint, bind_udp
from tests.sim_vehicle.state_bits import canon
from tests.sim_vehicle.sv_client import connect
from tests.sim_vehicle.test_sv_deferred_lane import STATION, _arrays, _clean, _Port

_GCS = mav.MAVLink(None, srcSystem=255, srcComponent=190)
_IDS = (1, 2, 3, 4, 5)
_LANE_IDS = _IDS[:4]
"""The ArduCopters: airborne in GUIDED, their lanes open at the stream's first
setpoint (the PX4, vehicle 5, hovers in HOLD: its setpoints are never the lane's)."""


def _parser(core: EmulatorCore) -> Endpoint:
    """A UDP endpoint on 127.0.0.1, for its ``parse`` alone (the shell's
    parsing and counting into ``core``'s counters; the core's port is a
    ``_Port`` that keeps what it sends)."""
    return Endpoint(sock=bind_udp("127.0.0.1", 0), shared=True, uplink=_clean(0),
                    downlink=_clean(1), on_datagram=lambda *_: None,
                    stats=core.stats.link)  # fmt: skip


def _receive(core: EmulatorCore, port: _Port, parser: Endpoint, data: bytes) -> None:
    """One datagram, as ``server.Emulator._receive`` gives it to the core."""
    core.receive(port, parser.parse(data, raw=True), STATION, None)


def _core() -> tuple[EmulatorCore, _Port]:
    specs = tuple(
        VehicleSpec(
            sysid=s,
            start_ned_m=(4.0 * s, 0.0, -1.0),
            airborne=True,
            autopilot="px4" if s == 5 else "ardupilot",
        )
        for s in _IDS
    )
    cfg = EmulatorConfig(vehicles=specs, clock="realtime", dynamics="ardupilot")
    core, port = EmulatorCore(cfg), _Port()
    core.ports.append(port)
    for spec in cfg.vehicles:
        core.add(spec, port, initial=True, enc=mav.MAVLink(None, spec.sysid, spec.compid))
    return core, port


def _setpoint(sysid: int, a: tuple[float, float, float], *, comp: int = 1, mask: int = 3135,
              frame: int = mav.MAV_FRAME_LOCAL_NED) -> bytes:  # fmt: skip
    return mav.MAVLink_set_position_target_local_ned_message(
        0, sysid, comp, frame, mask, 0, 0, 0, 0, 0, 0, *a, 0, 0
    ).pack(_GCS)


def _bad_crc(frame: bytes) -> bytes:
    return frame[:-2] + bytes((frame[-2] ^ 0x5A, frame[-1]))


_VALUE = st.one_of(
    st.tuples(*[st.floats(-4.0, 4.0)] * 3),
    st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(4.0, 9.0)),  # down hard: lands
    st.sampled_from([(math.nan, 0.0, 0.0), (0.0, 2e5, 0.0), (-0.0, -0.0, 0.0)]),
)
_ODD = st.sampled_from(["comp0", "comp7", "mask", "frame", "trimmed", "crc", "sysid9",
                        "sysid0", "heartbeat", "mode", "px4"])  # fmt: skip


def _odd(kind: str, sysid: int, a: tuple[float, float, float]) -> bytes:
    """One frame the lane must look at twice (or refuse) for vehicle ``sysid``."""
    if kind == "comp0":
        return _setpoint(sysid, a, comp=0)  # every component: the lane's too
    if kind == "comp7":
        return _setpoint(sysid, a, comp=7)
    if kind == "mask":
        return _setpoint(sysid, a, mask=3576)
    if kind == "frame":
        return _setpoint(sysid, a, frame=mav.MAV_FRAME_BODY_OFFSET_NED)
    if kind == "trimmed":  # MAV_FRAME_GLOBAL (0): MAVLink 2 trims the last byte
        return _setpoint(sysid, a, frame=0)
    if kind == "crc":
        return _bad_crc(_setpoint(sysid, a))
    if kind == "sysid9":
        return _setpoint(9, a)
    if kind == "sysid0":
        return _setpoint(0, a)
    if kind == "px4":
        return _setpoint(5, a)
    if kind == "heartbeat":
        return mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(_GCS)
    return mav.MAVLink_set_mode_message(sysid, 1, 17 if sysid % 2 else 4).pack(_GCS)


# A read: the stream (each vehicle's setpoint, in one to three datagrams), with
# sometimes one odd frame in it; or nothing (a pause). Then 1-4 physics steps.
_READ = st.tuples(
    st.sampled_from(["stream"] * 5 + ["pause"]),
    st.lists(_VALUE, min_size=len(_LANE_IDS), max_size=len(_LANE_IDS)),
    st.one_of(st.none(), st.tuples(_ODD, st.sampled_from(_IDS), st.integers(0, len(_LANE_IDS)))),
    st.integers(1, 3),
    st.integers(1, 4),
)


def _grams(values: list[Any], odd: Any, pieces: int) -> list[bytes]:
    frames = [_setpoint(s, tuple(v)) for s, v in zip(_LANE_IDS, values, strict=True)]
    if odd is not None:
        kind, sysid, at = odd
        frames.insert(at, _odd(kind, sysid, tuple(values[0])))
    cut = [len(frames) * k // pieces for k in range(pieces + 1)]
    return [b"".join(frames[a:b]) for a, b in itertools.pairwise(cut) if b > a]


def _held(core: EmulatorCore) -> list[Any]:
    return [None if v.lane_a is None else (struct.pack("<3d", *v.lane_a), v.lane_t)
            for v in core.rows]  # fmt: skip


def _counters(core: EmulatorCore) -> dict[str, int]:
    out = dataclasses.asdict(core.stats.link)
    del out["rx_stream_batched"]
    return out


@settings(max_examples=60, deadline=None)
@given(st.lists(_READ, min_size=5, max_size=40))
def test_reads_taken_column_wise_leave_the_state_of_one_datagram_at_a_time(
    plan: list[Any],
) -> None:
    (cols, cols_port), (one, one_port) = _core(), _core()
    parsers = [_parser(cols), _parser(one)]
    for kind, values, odd, pieces, steps in plan:
        grams = _grams(values, odd, pieces) if kind == "stream" else []
        if grams and not take_stream(cols, cols_port, grams, STATION):
            for g in grams:
                _receive(cols, cols_port, parsers[0], g)
        for g in grams:
            _receive(one, one_port, parsers[1], g)
        assert _held(cols) == _held(one)
        assert _counters(cols) == _counters(one)
        for _ in range(steps):
            cols.step()
            one.step()
            assert _arrays(cols) == _arrays(one), f"t = {cols.sim_time_s:.2f} s"
            assert cols_port.sent == one_port.sent, f"t = {cols.sim_time_s:.2f} s"
    cols.fold()
    one.fold()
    states = [[canon(vars(v.ap), skip={"version"}) for v in c.rows] for c in (cols, one)]
    assert states[0] == states[1]
    for p in parsers:
        p.sock.close()


def _stream(core: EmulatorCore, port: _Port, a: tuple[float, float, float]) -> bool:
    """The ArduCopters' setpoints in one datagram: taken at once, or one by one."""
    grams = [b"".join(_setpoint(s, a) for s in _LANE_IDS)]
    if take_stream(core, port, grams, STATION):
        return True
    parser = _parser(core)
    _receive(core, port, parser, grams[0])
    parser.sock.close()
    return False


def test_the_stream_is_taken_at_once_from_its_second_setpoint() -> None:
    """The first setpoint opens each vehicle's lane (its autopilot then flies
    the stream); from the second on every read is taken column-wise and
    counted, and each vehicle holds its last setpoint, as the lane does."""
    core, port = _core()
    taken = []
    for k in range(20):
        taken.append(_stream(core, port, (0.1 * k, -0.2, 0.0)))
        core.step()
    assert taken == [False] + [True] * 19
    assert core.stats.link.rx_stream_batched == 19 == core.stats.link.rx_datagrams - 1
    a = tuple(float(np.float32(x)) for x in (0.1 * 19, -0.2, 0.0))
    assert all(v.lane_a == a for v in core.rows[:4]) and core.rows[4].lane_a is None
    np.testing.assert_array_equal(core.fleet.a_ff[:4], np.tile(a, (len(_LANE_IDS), 1)))


def _declines(core: EmulatorCore, port: Any, grams: list[bytes], addr: Any = STATION) -> None:
    before = (_arrays(core), _held(core), dataclasses.asdict(core.stats.link))
    assert not take_stream(core, port, grams, addr)
    assert (_arrays(core), _held(core), dataclasses.asdict(core.stats.link)) == before


_GOOD = [_setpoint(s, (0.5, 0.5, 0.0)) for s in _LANE_IDS]


@pytest.mark.parametrize(
    "grams",
    [
        [b"".join(_GOOD[:2]) + _bad_crc(_GOOD[2])],
        [b"".join(_GOOD[:3]), _setpoint(1, (0.0, 0.0, 0.0), frame=0)],  # trimmed
        [b"".join(_GOOD) + _setpoint(9, (0.0, 0.0, 0.0))],  # nobody's on this port
        [b"".join(_GOOD) + _setpoint(5, (0.0, 0.0, 0.0))],  # the PX4's lane is closed
        [_setpoint(0, (0.0, 0.0, 0.0))],  # every vehicle of the port
        [_setpoint(1, (0.0, 0.0, 0.0), comp=7)],
        [_setpoint(1, (0.0, 0.0, 0.0), mask=3576)],
        [_setpoint(1, (0.0, 0.0, 0.0), frame=mav.MAV_FRAME_BODY_OFFSET_NED)],
        [_setpoint(1, (math.nan, 0.0, 0.0))],
        [_setpoint(1, (0.0, 0.0, 2e5))],
        [b"".join(_GOOD) + mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(_GCS)],
        [b"".join(_GOOD)[:-1]],  # a frame cut short
        [b""],
    ],
    ids=[
        "crc",
        "trimmed",
        "unknown-sysid",
        "px4",
        "broadcast",
        "component",
        "type-mask",
        "frame",
        "nan",
        "absurd",
        "heartbeat",
        "cut",
        "empty",
    ],
)
def test_a_read_with_anything_but_the_lane_s_setpoints_changes_nothing(grams: list[bytes]) -> None:
    core, port = _core()
    _stream(core, port, (0.0, 0.0, 0.0))  # the lanes open
    core.step()
    _declines(core, port, grams)


def test_the_core_or_the_port_may_decline_the_whole_read() -> None:
    """Not where a datagram is more than its setpoints: in lockstep (one may
    complete a step), through an active uplink impairment (it draws per
    datagram), signed, from a peer not yet heard or with the radio off; nor
    for a vehicle whose lane is closed (landed, or never streamed)."""
    grams = [b"".join(_GOOD)]
    core, port = _core()
    _declines(core, port, grams)  # no lane open yet
    _stream(core, port, (0.0, 0.0, 0.0))
    core.step()
    assert take_stream(core, port, grams, STATION)  # the control case
    core.step()
    _declines(core, port, grams, addr=("127.0.0.1", 14551))
    lossy = Impairer(Impairment(loss=0.1), np.random.default_rng(0))
    for name, value in (("silent", True), ("signing_key", bytes(32)), ("uplink", lossy)):
        old = getattr(port, name)
        setattr(port, name, value)
        _declines(core, port, grams)
        setattr(port, name, old)
    core.defer_stream = False
    _declines(core, port, grams)
    core.defer_stream = True
    core.lockstep = True
    _declines(core, port, grams)
    core.lockstep = False
    core.fleet.landed[2] = True
    _declines(core, port, grams)


def test_the_shell_reads_a_network_s_setpoints_together_and_takes_them() -> None:
    """Over UDP on 127.0.0.1: an emulator of 40 airborne vehicles on one
    shared port in real time; the stand-in station streams each vehicle's
    setpoint in four datagrams of 10 frames (650 bytes, under
    ``lane.MIN_BYTES``: taken only when read together), and in one round a
    COMMAND_LONG behind them. After the first round (it opens the lanes) every
    round's four datagrams are read and taken at once, the command is
    answered on its own, and each vehicle flies its last setpoint."""
    assert 10 * len(_GOOD[0]) < MIN_BYTES <= 40 * len(_GOOD[0])

    async def run() -> None:
        ids = range(1, 41)
        specs = tuple(VehicleSpec(sysid=s, start_ned_m=(2.0 * s, 0.0, -5.0), airborne=True)
                      for s in ids)  # fmt: skip
        cfg = EmulatorConfig(vehicles=specs, shared_port=0)
        async with asyncio.timeout(30), Emulator(cfg) as emu:
            c = await connect(emu.endpoints[1])
            c.heartbeat()
            await c.recv("HEARTBEAT")
            assert c.transport is not None
            link = emu.stats.link
            taken = []
            for k in range(10):
                a = (0.05 * k, -0.1, 0.0)
                frames = []
                for s in ids:
                    frames.append(c.mav.set_position_target_local_ned_encode(
                        0, s, 1, mav.MAV_FRAME_LOCAL_NED, 3135, 0, 0, 0, 0, 0, 0, *a, 0, 0
                    ).pack(c.mav))  # fmt: skip
                    c.mav.seq = (c.mav.seq + 1) % 256
                before = link.rx_stream_batched
                for j in range(0, 40, 10):  # four datagrams queued back to back
                    c.transport.sendto(b"".join(frames[j : j + 10]))
                if k == 5:
                    ack = await c.command(7, 511, 33, 1e6)  # SET_MESSAGE_INTERVAL: answered
                    assert ack.result == 0
                await emu.wait_steps(2)
                taken.append(link.rx_stream_batched - before)
            assert taken == [0] + [4] * 9, taken
            want = tuple(float(np.float32(x)) for x in a)
            np.testing.assert_array_equal(emu.core.fleet.a_ff, np.tile(want, (len(ids), 1)))
            c.close()

    asyncio.run(run())
