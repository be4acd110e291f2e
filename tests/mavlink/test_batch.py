"""The station's whole-formation paths (``gcs_swarm.mavlink.batch`` and
``VehicleProtocol.flying_position``) give what the one-vehicle paths give:
the same states, the same setpoint fields and counters, the same protocol
state after the same reports."""

from __future__ import annotations

import math
import random

import numpy as np

from gcs_swarm.mavlink.batch import accel_ned, mission_states
from gcs_swarm.mavlink.builders import MAV_CMD_SET_MESSAGE_INTERVAL
from gcs_swarm.mavlink.inbound import LocalPositionNed
from gcs_swarm.mavlink.states import Phase, ProtocolConfig
from gcs_swarm.mavlink.vehicle import VehicleProtocol


def _flying(sysid: int, rng: random.Random) -> VehicleProtocol:
    vp = VehicleProtocol(sysid, ProtocolConfig(), goto_m=(0.0, 0.0, 0.0))
    vp.phase = Phase.FLYING
    vp.offset_m = np.array([rng.uniform(-50, 50) for _ in range(3)])
    vp.position = LocalPositionNed(sysid, 1, rng.randrange(2**31),
                                   *(rng.uniform(-100, 100) for _ in range(6)))  # fmt: skip
    return vp


def test_mission_states_stack_state_mission() -> None:
    rng = random.Random(1)
    vps = [_flying(s, rng) for s in range(1, 40)]
    pos, vel = mission_states(vps)
    for k, vp in enumerate(vps):
        p, v = vp.state_mission()
        assert pos[k].tolist() == p.tolist() and vel[k].tolist() == v.tolist()  # exact
    assert mission_states([])[0].shape == (0, 3)


def test_accel_ned_equals_accel_setpoint_with_its_clipping() -> None:
    rng = random.Random(2)
    rows = [[rng.uniform(-20, 20) for _ in range(3)] for _ in range(200)]
    rows += [[3000.0, -4000.0, 0.0], [math.nan, 1.0, 2.0], [math.inf, 0.0, 0.0],
             [1e200, -1e200, 3.0], [0.0, 0.0, 0.0], [-0.0, 0.0, -0.0]]  # fmt: skip
    accel = np.array(rows)
    fast = [_flying(s % 250 + 1, random.Random(s)) for s in range(len(rows))]
    slow = [_flying(s % 250 + 1, random.Random(s)) for s in range(len(rows))]
    got = accel_ned(fast, accel).tolist()
    assert len(got) == len(rows)
    for k, (f, s) in enumerate(zip(fast, slow, strict=True)):
        with np.errstate(over="ignore"):  # 1e200^2: the reference path's overflow warning
            spec = s.accel_setpoint(accel[k])
        want = [spec.fields[name] for name in ("afx", "afy", "afz")]
        # repr: tells -0.0 from 0.0 (different bytes on the wire).
        assert repr(got[k]) == repr(want), rows[k]
        assert f.boot_ms() == spec.fields["time_boot_ms"]
        assert f.clipped_setpoints == s.clipped_setpoints
        assert f.last_accel_ned.tolist() == s.last_accel_ned.tolist()
    assert sum(f.clipped_setpoints for f in fast) == 4  # 3000/-4000, NaN, inf, 1e200
    assert accel[200].tolist() == [3000.0, -4000.0, 0.0]  # the caller's array is not clipped


def test_flying_position_leaves_the_protocol_as_handle_message_does() -> None:
    """Reports in flight, duplicated, reordered, implausible (NaN, 1e9 m,
    300 m/s), a reboot, another system's: both paths, same state."""
    rng = random.Random(3)
    fast, slow = _flying(7, rng), _flying(7, random.Random(3))
    t_ms = fast.position.time_boot_ms if fast.position else 0
    now = 10.0
    for i in range(3000):
        now += 0.02
        kind = rng.randrange(12)
        if kind == 0:
            t = t_ms  # duplicate
        elif kind == 1:
            t = t_ms - rng.randrange(1, 500)  # reordered
        elif kind == 2:
            t = max(0, t_ms - 20_000)  # a reboot: time going far back
        else:
            t = t_ms = t_ms + 20
        vals = [rng.uniform(-100, 100) for _ in range(6)]
        if kind == 3:
            vals[rng.randrange(6)] = rng.choice([math.nan, math.inf, 1e9, 300.0])
        sysid = 8 if kind == 4 else 7
        pos = LocalPositionNed(sysid, 1, t, *vals)
        took = fast.flying_position(pos, now)
        slow.handle_message(pos, now)
        assert took == (slow.position is pos), i
        for name in ("position", "position_at", "rejected_values", "stale_telemetry", "phase",
                     "_heard_at", "telemetry_rate_hz", "rate_requests", "rate_low"):  # fmt: skip
            assert getattr(fast, name) == getattr(slow, name), (i, name)
        # Only the telemetry-rate watch queues anything in flight (the same on both).
        out = fast.take_outbound()
        assert out == slow.take_outbound()
        assert all(m["command"] == MAV_CMD_SET_MESSAGE_INTERVAL for m in out)
        assert fast.take_events() == slow.take_events()
    assert fast.rejected_values > 100 and fast.stale_telemetry > 300
