"""The telemetry table (``gcs_swarm.mavlink.telemetry_table``) against the
readable reference, a ``VehicleProtocol`` fed every report by
``handle_message``: the same states, setpoints, counters and protocol state
after the same reports, and the same hand-over when the vehicle stops flying."""

from __future__ import annotations

import math
import random

import numpy as np

from gcs_swarm.mavlink.accel_clip import clip_accel_ned
from gcs_swarm.mavlink.builders import MAV_CMD_SET_MESSAGE_INTERVAL
from gcs_swarm.mavlink.inbound import (
    EkfStatus,
    ExtendedSysState,
    GpsRaw,
    Heartbeat,
    Inbound,
    LocalPositionNed,
    SysStatus,
)
from gcs_swarm.mavlink.states import Phase, ProtocolConfig
from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.mavlink.vehicle import VehicleProtocol


def _f32(x: float) -> float:
    """``x`` as a float32 holds it: what a LOCAL_POSITION_NED carries."""
    return float(np.float32(x))


def _report(sysid: int, rng: random.Random, t_ms: int | None = None) -> LocalPositionNed:
    t = rng.randrange(2**31) if t_ms is None else t_ms
    return LocalPositionNed(sysid, 1, t, *(_f32(rng.uniform(-100, 100)) for _ in range(6)))


def _ready(sysid: int, rng: random.Random) -> VehicleProtocol:
    vp = VehicleProtocol(sysid, ProtocolConfig(), goto_m=(0.0, 0.0, 0.0))
    vp.phase = Phase.READY
    vp.offset_m = np.array([rng.uniform(-50, 50) for _ in range(3)])
    vp.position = _report(sysid, rng)
    return vp


def test_mission_states_are_each_protocols_state_mission() -> None:
    rng = random.Random(1)
    ids = list(range(1, 40))
    table = TelemetryTable(ids)
    fast = [_ready(s, random.Random(s)) for s in ids]
    slow = [_ready(s, random.Random(s)) for s in ids]
    for f, s in zip(fast, slow, strict=True):
        f.begin_flying(1.0, table)
        s.begin_flying(1.0)
        pos = _report(f.sysid, rng, f.boot_ms() + 20)
        assert table.write(table.slot[f.sysid], 1, -1, pos[2:], 1.02, 1.01)
        s.handle_message(pos, 1.02)
    ks = table.slots(ids)
    pos, vel = table.mission_states(ks)
    for k, (f, s) in enumerate(zip(fast, slow, strict=True)):
        p, v = s.state_mission()
        assert pos[k].tolist() == p.tolist() and vel[k].tolist() == v.tolist()  # exact
        assert f.state_mission()[0].tolist() == p.tolist()
    assert table.mission_states(table.slots([]))[0].shape == (0, 3)


def test_answer_equals_accel_setpoint_with_its_clipping() -> None:
    rng = random.Random(2)
    rows = [[rng.uniform(-20, 20) for _ in range(3)] for _ in range(200)]
    rows += [[3000.0, -4000.0, 0.0], [math.nan, 1.0, 2.0], [math.inf, 0.0, 0.0],
             [1e200, -1e200, 3.0], [0.0, 0.0, 0.0], [-0.0, 0.0, -0.0]]  # fmt: skip
    accel = np.array(rows)
    ids = list(range(1, len(rows) + 1))
    table = TelemetryTable(ids)
    fast = [_ready(s, random.Random(s)) for s in ids]
    slow = [_ready(s, random.Random(s)) for s in ids]
    for f, s in zip(fast, slow, strict=True):
        f.begin_flying(0.0, table)
        s.begin_flying(0.0)
    got = table.answer(table.slots(ids), accel).tolist()
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


def test_answer_of_a_few_rows_is_clip_accel_neds() -> None:
    """A few rows (``answer``'s path without numpy when nothing is clipped):
    the reference's rows bit for bit, signed zeros, NaN, infinities and
    norms at and about the ceiling included, and the same rows kept."""
    rng = random.Random(5)
    edge = [0.0, -0.0, 1.0, -2.5, 998.9, 999.0, 999.5, 1000.0, -1000.0, 1000.0000001,
            1e-320, 1e154, 1e200, math.nan, math.inf, -math.inf]  # fmt: skip
    table = TelemetryTable(list(range(1, 10)))
    for _ in range(3000):
        n = rng.randrange(1, 10)
        rows = [[rng.choice(edge) if rng.random() < 0.3 else rng.uniform(-600, 600)
                 for _ in range(3)] for _ in range(n)]  # fmt: skip
        accel = np.array(rows)
        with np.errstate(over="ignore", invalid="ignore"):
            want, _ = clip_accel_ned(accel)
            got = table.answer(table.slots(list(range(1, n + 1))), accel)
        assert repr(got.tolist()) == repr(want.tolist()), rows
        assert repr(table.accel_ned[:n].tolist()) == repr(want.tolist())
        assert got.shape == want.shape and got.dtype == want.dtype


def test_table_and_protocol_leave_the_state_handle_message_leaves() -> None:
    """Reports in flight, duplicated, reordered, implausible (NaN, 1e9 m,
    300 m/s), a reboot, another system's: written into the table (the
    protocol hearing only what the table does not take) or all through
    ``handle_message``, the same state; then the same hand-over at the end."""
    rng = random.Random(3)
    table = TelemetryTable([7, 8])
    fast, slow = _ready(7, random.Random(9)), _ready(7, random.Random(9))
    fast.begin_flying(10.0, table)
    slow.begin_flying(10.0)
    t_ms = fast.boot_ms()
    now = 10.0
    taken = 0
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
        vals = [_f32(rng.uniform(-100, 100)) for _ in range(6)]
        if kind == 3:
            vals[rng.randrange(6)] = rng.choice([math.nan, math.inf, 1e9, 300.0])
        sysid = 8 if kind == 4 else 7
        pos = LocalPositionNed(sysid, 1, t, *vals)
        took = table.write(table.slot[sysid], 1, -1, pos[2:], now, now)
        if not took:
            fast.handle_message(pos, now)
        taken += took
        slow.handle_message(pos, now)
        assert took == (slow.position is pos), i
        for name in ("position", "position_at", "rejected_values", "stale_telemetry",
                     "phase", "telemetry_rate_hz", "rate_requests", "rate_low",
                     "vel_correction_ned"):  # fmt: skip
            assert getattr(fast, name) == getattr(slow, name), (i, name)
        assert fast.next_deadline() == slow.next_deadline(), i  # the watchdog's clocks
        # Only the telemetry-rate watch queues anything in flight (the same on both).
        out = fast.take_outbound()
        assert out == slow.take_outbound()
        assert all(m["command"] == MAV_CMD_SET_MESSAGE_INTERVAL for m in out)
        assert fast.take_events() == slow.take_events()
    assert fast.rejected_values > 100 and fast.stale_telemetry > 300
    assert table.taken == taken and table.fresh_count == 1
    assert fast.velocity_bias.samples == slow.velocity_bias.samples
    np.testing.assert_array_equal(table.bias_ned[0], slow.vel_correction_ned)
    # Ending: the protocol takes its row back (the zero setpoint carries its time).
    fast.finish(now)
    slow.finish(now)
    assert fast.phase is slow.phase is not Phase.FLYING
    assert table.owners[0] is None and table.fresh_count == 0
    assert fast.take_outbound() == slow.take_outbound()
    assert fast.position == slow.position and fast.next_deadline() == slow.next_deadline()
    assert not table.write(0, 1, -1, (t_ms + 20, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), now, now)


def _beat(rng: random.Random, sysid: int, change: bool) -> Heartbeat:
    """A flying ArduCopter's HEARTBEAT (GUIDED, armed, active), or with
    ``change`` one field of it changed as a vehicle's may change."""
    f = {"compid": 1, "type": 2, "autopilot": 3, "base_mode": 128 | 89, "custom_mode": 4,
         "system_status": 4}  # fmt: skip
    if change:
        name, value = rng.choice([("custom_mode", 5), ("custom_mode", 9), ("base_mode", 89),
                                  ("system_status", 5), ("compid", 2), ("type", 13),
                                  ("autopilot", 8)])  # fmt: skip
        f[name] = value
    return Heartbeat(sysid, **f)


def _wire(hb: Heartbeat) -> tuple[int, ...]:
    """``hb``'s payload in wire order, as ``RawHeartbeat.values`` holds it."""
    return (hb.custom_mode, hb.type, hb.autopilot, hb.base_mode, hb.system_status, 3)


def _status(rng: random.Random, sysid: int, change: bool) -> tuple[int, Inbound, tuple[int, ...]]:
    """A flying ArduCopter's or PX4's status message (message id, typed
    message, ``RawStatus.values``), or with ``change`` one field changed."""
    c = rng.choice([1, 1, 1, 2]) if change else 1
    v = rng.randrange(4) if change else 0
    msgid = rng.choice([1, 24, 193, 230, 245])
    if msgid == 1:
        msg: Inbound = SysStatus(sysid, c, 0x1F, 0x1F, 0x1F ^ v)
        return msgid, msg, (0x1F, 0x1F, 0x1F ^ v)
    if msgid == 24:
        msg = GpsRaw(sysid, c, 3 + v % 2, 10)
        return msgid, msg, (3 + v % 2, 10)
    if msgid == 245:
        msg = ExtendedSysState(sysid, c, 0, 2 + v)
        return msgid, msg, (0, 2 + v)
    msg = EkfStatus(sysid, c, 0x3FF ^ v)
    return msgid, msg, (0x3FF ^ v,)


def test_unchanged_heartbeats_and_status_taken_by_the_table_leave_the_protocols_state() -> None:
    """HEARTBEATs and status messages in flight among reports, mostly the
    same, sometimes one that differs (another mode, disarmed, another status,
    component or type; another EKF flag, fix, landed state, sensor health):
    those the table takes (``unchanged``: the last of its kind the protocol
    handled in FLYING, again) and the rest through ``handle_message``,
    against every one through ``handle_message``: the same state, health,
    deadlines, watchdog and hand-over, for runs that end by a change of mode
    or by silence."""
    total = ended = said = 0
    for seed in range(40):
        rng = random.Random(seed)
        table = TelemetryTable([7])
        fast, slow = _ready(7, random.Random(9)), _ready(7, random.Random(9))
        if seed % 2:  # reports may stop for longer than HEARTBEATs (3 s): the link watchdog
            fast.config = slow.config = ProtocolConfig(stale_timeout_s=9.0)
        fast.begin_flying(10.0, table)
        slow.begin_flying(10.0)
        t_ms, now, taken = fast.boot_ms(), 10.0, 0
        for i in range(600):
            now += rng.choice([0.02] * 30 + [0.3, 0.5])
            if rng.random() < (0.8 if seed % 2 == 0 or i % 200 < 100 else 0.0):
                t_ms += 20
                pos = LocalPositionNed(7, 1, t_ms, *(_f32(rng.uniform(-9, 9)) for _ in range(6)))
                if not table.write(0, 1, -1, pos[2:], now, now):
                    fast.handle_message(pos, now)
                slow.handle_message(pos, now)
            elif rng.random() < 0.4:
                hb = _beat(rng, 7, change=rng.random() < 0.01)
                took = table.unchanged(0, hb.compid, 5, 0, _wire(hb), now)
                if not took:
                    fast.handle_message(hb, now)
                taken += took
                slow.handle_message(hb, now)
            else:
                msgid, msg, values = _status(rng, 7, change=rng.random() < 0.05)
                took = table.unchanged(0, msg.compid, 5, msgid, values, now)
                if not took:
                    fast.handle_message(msg, now)
                said += took
                slow.handle_message(msg, now)
            for vp in (fast, slow):
                if vp.next_deadline() is not None and vp.next_deadline() <= now:
                    vp.handle_timer(now)
            assert fast.phase is slow.phase, (seed, i)
            assert fast.heartbeat == slow.heartbeat and fast.compid == slow.compid, (seed, i)
            assert fast._health == slow._health, (seed, i)
            assert fast.landed_state == slow.landed_state, (seed, i)
            assert fast.next_deadline() == slow.next_deadline(), (seed, i)
            assert fast.take_outbound() == slow.take_outbound(), (seed, i)
            assert fast.take_events() == slow.take_events(), (seed, i)
            if slow.phase is not Phase.FLYING:
                break
        else:  # flying still: silence, then the watchdog (its clock includes the table's)
            for vp in (fast, slow):
                while vp.phase is Phase.FLYING:
                    due = vp.next_deadline()
                    assert due is not None
                    vp.handle_timer(due)
            assert fast.phase is slow.phase
            assert fast.take_events() == slow.take_events()
        assert table.owners[0] is None  # handed back, and takes no HEARTBEAT any more
        assert not table.unchanged(0, 1, 5, 0, _wire(_beat(rng, 7, change=False)), now)
        msgid, msg, values = _status(rng, 7, change=False)
        assert not table.unchanged(0, 1, 5, msgid, values, now)
        assert fast.next_deadline() == slow.next_deadline()
        total += taken
        ended += slow.phase is not Phase.LOST
    assert total > 800 and said > 1000 and 5 <= ended <= 35  # both paths, both endings


def test_the_velocity_the_step_reads_carries_the_protocols_bias_estimate() -> None:
    """Vehicles whose velocity is reported off by a bias, a report each per
    step or two (the second before the step: taken at once), steps at random,
    a vehicle leaving and coming back: each step's states are the reference
    protocol's ``state_mission`` bit for bit, the estimates included."""
    rng = random.Random(11)
    ids = list(range(1, 25))
    table = TelemetryTable(ids)
    fast = [_ready(s, random.Random(s)) for s in ids]
    slow = [_ready(s, random.Random(s)) for s in ids]
    bias = {s: [rng.uniform(-0.1, 0.1) for _ in range(3)] for s in ids}
    pos = {s: [rng.uniform(-20, 20) for _ in range(3)] for s in ids}
    t_ms = {s: f.boot_ms() for s, f in zip(ids, fast, strict=True)}
    for f, s in zip(fast, slow, strict=True):
        f.begin_flying(1.0, table)
        s.begin_flying(1.0)
    now, steps, estimated, returned = 1.0, 0, 0, 0
    for _ in range(600):
        now += 0.02
        for s, f, ref in zip(ids, fast, slow, strict=True):
            for _ in range(rng.choice([0, 1, 1, 1, 2])):
                t_ms[s] += 10
                v = [rng.uniform(-1, 1) for _ in range(3)]
                pos[s] = [p + c * 0.01 for p, c in zip(pos[s], v, strict=True)]
                vel = (_f32(c + b) for c, b in zip(v, bias[s], strict=True))
                rep = LocalPositionNed(s, 1, t_ms[s], *map(_f32, pos[s]), *vel)
                if f.phase is Phase.FLYING:
                    assert table.write(table.slot[s], 1, -1, rep[2:], now, now)
                else:
                    f.handle_message(rep, now)
                ref.handle_message(rep, now)
        if rng.random() < 0.6:
            flying = [f.sysid for f in fast if f.phase is Phase.FLYING]
            p, v = table.mission_states(table.slots(flying))
            steps += 1
            for i, s in enumerate(flying):
                rp, rv = slow[s - 1].state_mission()
                assert p[i].tolist() == rp.tolist() and v[i].tolist() == rv.tolist(), s
                estimated += slow[s - 1].vel_correction_ned != (0.0, 0.0, 0.0)
        if rng.random() < 0.01:  # one leaves flying (its row handed back) and comes back
            k = rng.randrange(len(ids))
            for vp in (fast[k], slow[k]):
                vp._set_phase(Phase.READY, now)  # what leaving FLYING does to the row
                vp.begin_flying(now, table if vp is fast[k] else None)
            returned += 1
    for f, s in zip(fast, slow, strict=True):
        assert f.velocity_bias.samples == s.velocity_bias.samples
        assert f.velocity_bias.bias == s.velocity_bias.bias != (0.0, 0.0, 0.0)
    assert steps > 300 and estimated > 1000 and returned > 2
