"""The emulator's 1 Hz HEARTBEAT as a fleet stream (``schedule.due_heartbeats``,
``Fleet.heartbeat_frames``, ``codec.heartbeat_frames``).

Until the eighteenth session each autopilot's ``poll`` sent its HEARTBEAT, so
with ``heartbeats: together`` every autopilot of a network was polled in one
step each second: 3.0-3.3 ms for 250 vehicles against 0.49 ms for the other
steps (in process), 4.5-7.7 ms in the 1,500-vehicle benchmark, where six
networks' seconds put the emulator more than a period behind
(benchmarks/README.md). The HEARTBEAT is now a stream of the fleet, as
LOCAL_POSITION_NED is: its fields are copied from ``Autopilot.heartbeat()``
into the row when the mode or arming changes (``EmulatorCore.sync``), and the
due rows' frames are built at once, before the step's polls (each HEARTBEAT
of the state before them). Checked here:

- the frames, column-wise and one by one, are pymavlink's bytes for random
  fields, sequence numbers and ids;
- in a core, each HEARTBEAT sent is pymavlink's pack of its autopilot's
  ``heartbeat()`` at that instant, for ArduCopter and PX4, through mode
  changes, arming, a take-off, a landing and a disarm;
- the second's HEARTBEATs poll no autopilot with nothing due;
- what the 1 Hz poll used to catch within a second is now planned when the
  state changes (``Autopilot._replan``): the auto-disarm after arming on the
  ground, the GCS failsafe after the first GCS HEARTBEAT, the fence enabled
  in flight.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import EmulatorConfig, VehicleSpec
from sim_vehicle.autopilot import Autopilot
from sim_vehicle.codec import HEARTBEAT_FIELDS, encode_heartbeats, heartbeat_frames_small
from sim_vehicle.config import DEFAULT_ORIGIN
from sim_vehicle.core import EmulatorCore
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin
from tests.sim_vehicle.test_sv_deferred_lane import STATION, _Port

_GCS = mav.MAVLink(None, srcSystem=255, srcComponent=190)
HB = mav.MAVLINK_MSG_ID_HEARTBEAT


def _pymavlink(seq: int, sysid: int, compid: int, fields: Any) -> bytes:
    enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    enc.seq = seq
    custom, type_, autopilot, base, status, version = fields
    return mav.MAVLink_heartbeat_message(type_, autopilot, base, custom, status, version).pack(enc)


@pytest.mark.parametrize("n", [1, 5, 31, 32, 250])
def test_frames_are_pymavlinks_bytes_column_wise_and_one_by_one(n: int) -> None:
    rng = np.random.default_rng(n)
    seq = rng.integers(0, 256, n)
    sysid = rng.integers(1, 256, n)
    compid = rng.integers(0, 256, n)
    fields = np.column_stack(
        [rng.integers(0, 2**32, n)] + [rng.integers(0, 256, n) for _ in range(5)]
    )
    fields[: n // 2, 5] = 0  # a zero last field: MAVLink 2 trims the payload
    fields[: n // 4, 1:] = 0
    want = [
        _pymavlink(*map(int, (s, i, c)), f.tolist())
        for s, i, c, f in zip(seq, sysid, compid, fields, strict=True)
    ]
    assert encode_heartbeats(seq, sysid, compid, fields) == want
    small = heartbeat_frames_small(seq.tolist(), sysid.tolist(), compid.tolist(), fields.tolist())
    assert small == want
    assert len(HEARTBEAT_FIELDS) == fields.shape[1]


def _core(
    n: int, autopilot: Literal["ardupilot", "px4"], airborne: bool
) -> tuple[EmulatorCore, _Port]:
    specs = tuple(
        VehicleSpec(
            sysid=s,
            start_ned_m=(3.0 * s, 0.0, -5.0 if airborne else 0.0),
            airborne=airborne,
            autopilot=autopilot,
        )
        for s in range(1, n + 1)
    )
    prearm = {"SIM_PREARM_S": 0.5}  # PX4's pre-arm checks
    cfg = EmulatorConfig(
        vehicles=specs, clock="realtime", ekf_ready_s=0.5, boot_s=0.0, params=prearm
    )
    core, port = EmulatorCore(cfg), _Port()
    core.ports.append(port)
    for spec in cfg.vehicles:
        core.add(spec, port, initial=True, enc=mav.MAVLink(None, spec.sysid, spec.compid))
    return core, port


def _send(core: EmulatorCore, port: _Port, msg: Any) -> None:
    core.receive(port, mav.MAVLink(None).parse_buffer(msg.pack(_GCS)) or [], STATION, None)


def _cmd(sysid: int, command: int, *p: float) -> Any:
    args = [*p, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
    return mav.MAVLink_command_long_message(sysid, 1, command, 0, *args)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
@pytest.mark.parametrize("n", [3, 40])  # one by one, and column-wise
def test_each_heartbeat_is_its_autopilots_at_that_instant(
    autopilot: Literal["ardupilot", "px4"], n: int
) -> None:
    core, port = _core(n, autopilot, airborne=False)
    guided = 4
    # (step, message): GUIDED, arm, take off, LAND for some, BRAKE, disarm
    plan: dict[int, list[Any]] = {
        40: [mav.MAVLink_set_mode_message(0, 1, guided)],
        60: [_cmd(0, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)],
        70: [_cmd(0, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 3.0)],
        260: [mav.MAVLink_set_mode_message(2, 1, 9), mav.MAVLink_set_mode_message(3, 1, 17)],
        330: [_cmd(1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 21196.0)],
    }
    parser = mav.MAVLink(None)
    seen: dict[int, set[tuple[int, ...]]] = {}
    for k in range(600):
        for msg in plan.get(k, []):
            _send(core, port, msg)
        # what each autopilot's HEARTBEAT is now: the stream sends it before the polls
        expect = {v.spec.sysid: (v, v.ap.heartbeat()) for v in core.rows}
        seqs = {v.spec.sysid: int(core.fleet.seq[v.row]) for v in core.rows}
        before = len(port.sent)
        core.step()
        for data in port.sent[before:]:
            i = 0
            while i < len(data):
                end = i + 12 + data[i + 1]
                frame = data[i:end]
                m = parser.parse_buffer(frame)[0]
                i = end
                if m.get_msgId() != HB:
                    continue
                sysid = m.get_srcSystem()
                v, hb = expect[sysid]
                enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=v.spec.compid)
                enc.seq = seqs[sysid]
                assert frame == hb.pack(enc), (k, sysid)
                seqs[sysid] = (seqs[sysid] + 1) & 0xFF
                seen.setdefault(sysid, set()).add(tuple(getattr(m, f) for f in HEARTBEAT_FIELDS))
    armed = mav.MAV_MODE_FLAG_SAFETY_ARMED
    for sysid in range(1, n + 1):
        # 12 s: 12 HEARTBEATs each, of disarmed and armed states alike
        assert any(f[3] & armed for f in seen[sysid]) and any(not f[3] & armed for f in seen[sysid])
    assert len({f for s in seen.values() for f in s}) >= 4  # modes and arming states apart


def test_the_seconds_heartbeats_poll_no_autopilot_with_nothing_due() -> None:
    core, port = _core(250, "ardupilot", airborne=True)
    for _ in range(60):
        core.step()
    hovering = core.fleet.deadline
    assert np.isinf(hovering).all()  # holding, unarmed fence, no stream: nothing to poll for
    before = len(port.sent)
    for _ in range(50):  # one second: each vehicle's HEARTBEAT once
        core.step()
    parser = mav.MAVLink(None)
    beats = [m for d in port.sent[before:] for m in parser.parse_buffer(d) or []]
    assert sorted(m.get_srcSystem() for m in beats if m.get_msgId() == HB) == list(range(1, 251))


GROUND = Kin((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), True)
AIR = Kin((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False)


def _arm(ap: Autopilot, now: float, kin: Kin) -> None:
    ack = ap.handle(_cmd(1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, 21196.0), now, kin)
    assert ack[-1].result == mav.MAV_RESULT_ACCEPTED and ap.armed


def test_a_state_change_plans_its_own_poll() -> None:
    # armed on the ground: DISARM_DELAY after the arming
    ap = Autopilot(1, DEFAULT_ORIGIN, ParamStore({"SIM_EKF_DELAY": 0, "DISARM_DELAY": 4}), 0.0)
    ap.poll(0.0, GROUND)
    assert ap.deadline == np.inf
    _arm(ap, 2.0, GROUND)
    assert ap.deadline == pytest.approx(6.0)
    # the first GCS HEARTBEAT of an armed vehicle: the failsafe's check
    ap = Autopilot(1, DEFAULT_ORIGIN, ParamStore({"FS_GCS_ENABLE": 1, "FS_GCS_TIMEOUT": 5}), 0.0,
                   airborne_at=AIR.pos)  # fmt: skip
    ap.poll(0.0, AIR)
    assert ap.deadline == np.inf
    gcs_hb = mav.MAVLink(None).parse_buffer(
        mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(_GCS)
    )
    ap.handle(gcs_hb[0], 1.0, AIR)
    assert ap.deadline == pytest.approx(6.0, abs=2e-3)
    assert ap.poll(6.01, AIR)[-1].get_type() == "STATUSTEXT"  # "GCS Failsafe" on time
    # the fence enabled in flight: checked from the next step on
    ap = Autopilot(1, DEFAULT_ORIGIN, ParamStore(), 0.0, airborne_at=AIR.pos)
    ap.poll(0.0, AIR)
    assert ap.deadline == np.inf
    ap.handle(mav.MAVLink_param_set_message(1, 1, b"FENCE_ENABLE", 1.0, 2), 3.0, AIR)
    assert ap.deadline == 3.0
