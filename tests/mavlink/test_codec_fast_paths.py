"""The codec's fast paths (benchmarks/README.md, "station capacity") give
exactly what pymavlink gives: LOCAL_POSITION_NED decoded without pymavlink's
byte-wise parser, and SET_POSITION_TARGET_LOCAL_NED packed without a message
object. Seeded random datagrams mixing good reports, other messages, MAVLink
1 frames, garbage, bad CRCs and truncated frames are decoded both ways; the
messages (type, fields, header, raw bytes) and the counters must agree."""

from __future__ import annotations

import random
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import (
    SETPOINT_FIELDS,
    Codec,
    MessageSpec,
    RawHeartbeat,
    RawPosition,
    RawStatus,
)
from gcs_swarm.mavlink.inbound import STATUS_FIELDS, from_pymavlink, seen_key


def _frame(rng: random.Random, kind: str, sysid: int, seq: int) -> bytes:
    enc = mav.MAVLink(None, sysid, 1)
    enc.seq = seq
    if kind == "lpn":
        vals = [rng.choice([0.0, rng.uniform(-100, 100)]) for _ in range(6)]
        t = rng.choice([0, rng.randrange(2**32)])
        return bytes(enc.local_position_ned_encode(t, *vals).pack(enc))
    if kind == "hb":
        return bytes(enc.heartbeat_encode(2, 3, 81, 4, 4).pack(enc))
    if kind == "ekf":
        return bytes(
            enc.ekf_status_report_encode(rng.randrange(1024), 0.1, 0.0, 0.2, 0.0, 0.0).pack(enc)
        )
    if kind == "gps":
        return bytes(enc.gps_raw_int_encode(0, 3, 1, 2, 3, 4, 5, 6, 7, rng.randrange(20)).pack(enc))
    if kind == "sys":
        m = enc.sys_status_encode(*(rng.randrange(2**31) for _ in range(3)), 500, 12000, -1, 90,
                                  0, 0, 0, 0, 0, 0)  # fmt: skip
        return bytes(m.pack(enc))
    if kind == "est":
        m = enc.estimator_status_encode(rng.randrange(2**40), rng.randrange(2**16),
                                        *(rng.uniform(0, 1) for _ in range(8)))  # fmt: skip
        return bytes(m.pack(enc))
    if kind == "ess":
        return bytes(enc.extended_sys_state_encode(rng.randrange(5), rng.randrange(5)).pack(enc))
    if kind == "ack":
        return bytes(enc.command_ack_encode(rng.randrange(600), rng.randrange(5)).pack(enc))
    if kind == "text":
        return bytes(enc.statustext_encode(6, b"PreArm: " + bytes(rng.randrange(20))).pack(enc))
    if kind == "unknown":  # a well-formed frame of an id the dialect does not know
        f = bytearray(_frame(rng, "hb", sysid, seq))
        f[7:10] = (0x60, 0xEA, 0x00)
        return bytes(f)
    if kind == "v1":
        return bytes(enc.heartbeat_encode(2, 3, 81, 4, 4).pack(enc, force_mavlink1=True))
    if kind == "garbage":
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
    if kind == "badcrc":
        f = bytearray(_frame(rng, "lpn", sysid, seq))
        f[-1] ^= 0x55
        return bytes(f)
    assert kind == "trunc"
    return _frame(rng, "lpn", sysid, seq)[: rng.randrange(1, 20)]


def _values(spec: MessageSpec) -> tuple[Any, ...]:
    """A setpoint spec's field values in wire order (``encode_setpoint``'s input)."""
    return tuple(spec.fields[name] for name in SETPOINT_FIELDS)


def _view(m: Any) -> tuple[Any, ...]:
    h = m.get_header()
    return (type(m).__name__, m.to_dict(), (h.srcSystem, h.srcComponent, h.seq, h.msgId),
            bytes(m.get_msgbuf()), bytes(m.get_payload() or b""))  # fmt: skip


def test_fast_decode_equals_pymavlinks_parser_on_3000_mixed_datagrams() -> None:
    rng = random.Random(3)
    kinds = ["lpn"] * 6 + ["hb", "ekf", "gps", "ack", "text", "unknown"]
    kinds += ["v1", "garbage", "badcrc", "trunc"]
    fast_n = 0
    for _ in range(3000):
        parts = [rng.choice(kinds) for _ in range(rng.randrange(1, 8))]
        data = b"".join(_frame(rng, k, rng.randrange(1, 255), rng.randrange(256)) for k in parts)
        fast, slow = Codec(), Codec()
        got = fast.decode(data)
        ref = slow._parse(data, datagram=True)  # pymavlink's parser, the reference
        slow.stats.received += len(ref)
        assert [_view(m) for m in got] == [_view(m) for m in ref], parts
        assert vars(fast.stats) == vars(slow.stats), parts
        fast_n += sum(1 for m in got if m.get_type() == "LOCAL_POSITION_NED")
    assert fast_n > 3500  # the fast path was really exercised


def test_fast_setpoint_encode_equals_pymavlink_pack_on_5000_setpoints() -> None:
    rng = random.Random(5)

    def v() -> float:
        return rng.choice([0.0, -0.0, rng.uniform(-50, 50), 1e-40])

    for _ in range(5000):
        c = Codec(sysid=rng.randrange(1, 256), compid=rng.randrange(256))
        c._mav.seq = rng.randrange(256)
        ref = mav.MAVLink(None, c.sysid, c.compid)
        ref.seq = c._mav.seq
        a = (v(), v(), v())
        kind = rng.randrange(3)
        if kind == 0:
            t = rng.choice([0, rng.randrange(2**32)])
            spec = b.accel_setpoint(rng.randrange(256), rng.randrange(256), t, a)
        elif kind == 1:
            t = rng.randrange(2**32)
            spec = b.position_setpoint(rng.randrange(256), rng.randrange(256), t, a)
        else:
            spec = b.accel_setpoint(0, 0, 0, (0.0, 0.0, 0.0))
        got = c.encode(spec)
        exp = bytes(ref.set_position_target_local_ned_encode(**dict(spec.fields)).pack(ref))
        assert got == exp, spec
        assert c._mav.seq == (ref.seq + 1) % 256


def test_raw_positions_carry_what_pymavlinks_parser_gives() -> None:
    """``decode(raw_positions=True)``: the same messages and counters, each
    unsigned LOCAL_POSITION_NED as a ``RawPosition`` (each HEARTBEAT as a
    ``RawHeartbeat``, each status message as a ``RawStatus``) holding the
    header ids, the frame's bytes and the field values pymavlink decodes
    (a status message's: those its typed message keeps, as ``seen_key``)."""
    rng = random.Random(4)
    kinds = ["lpn"] * 6 + ["hb", "ekf", "gps", "sys", "est", "ess", "ack", "text", "unknown"]
    kinds += ["v1", "garbage", "badcrc", "trunc"]
    raw_n = hb_n = status_n = 0
    for _ in range(1500):
        parts = [rng.choice(kinds) for _ in range(rng.randrange(1, 8))]
        data = b"".join(_frame(rng, k, rng.randrange(1, 255), rng.randrange(256)) for k in parts)
        fast, slow = Codec(), Codec()
        got = fast.decode(data, raw_positions=True)
        ref = slow._parse(data, datagram=True)
        slow.stats.received += len(ref)
        assert len(got) == len(ref), parts
        for g, m in zip(got, ref, strict=True):
            if isinstance(g, RawPosition):
                h = m.get_header()
                assert (g.sysid, g.compid, g.seq) == (h.srcSystem, h.srcComponent, h.seq)
                assert g.frame == bytes(m.get_msgbuf())
                names = ("time_boot_ms", "x", "y", "z", "vx", "vy", "vz")
                assert g.values == tuple(getattr(m, f) for f in names)
                assert _view(fast.message(g)) == _view(m)  # pymavlink's own message of it
                raw_n += 1
            elif isinstance(g, RawHeartbeat):
                h = m.get_header()
                assert (g.sysid, g.compid, g.seq) == (h.srcSystem, h.srcComponent, h.seq)
                assert g.frame == bytes(m.get_msgbuf())
                names = ("custom_mode", "type", "autopilot", "base_mode", "system_status",
                         "mavlink_version")  # fmt: skip
                assert g.values == tuple(getattr(m, f) for f in names)
                assert _view(fast.message(g)) == _view(m)
                hb_n += 1
            elif isinstance(g, RawStatus):
                h = m.get_header()
                assert (g.sysid, g.compid, g.seq) == (h.srcSystem, h.srcComponent, h.seq)
                assert g.frame == bytes(m.get_msgbuf()) and g.frame[7] == m.get_msgId()
                kind, names = STATUS_FIELDS[m.get_msgId()]
                assert g.values == tuple(getattr(m, f) for f in names)
                # What the table compares is what the protocol's typed message holds.
                typed = from_pymavlink(m)
                assert seen_key(typed) == (kind, (g.compid, *g.values))  # type: ignore[arg-type]
                assert _view(fast.message(g)) == _view(m)
                status_n += 1
            else:
                assert _view(g) == _view(m)
        assert vars(fast.stats) == vars(slow.stats), parts
    # (frames after a bad one take the general parser)
    assert raw_n > 1000 and hb_n > 100 and status_n > 400


def test_setpoint_values_encode_to_the_same_bytes_as_the_spec() -> None:
    """``encode_setpoint`` of a setpoint's wire-order values is ``encode`` of its spec
    byte for byte unsigned; signed, both decode to the same fields."""
    rng = random.Random(6)
    for _ in range(2000):
        a = (rng.uniform(-50, 50), rng.choice([0.0, -0.0, 3.5]), rng.uniform(-1, 1))
        args = (rng.randrange(256), rng.randrange(256), rng.randrange(2**32), a)
        one, two = Codec(), Codec()
        one._mav.seq = two._mav.seq = rng.randrange(256)
        assert one.encode_setpoint(_values(b.accel_setpoint(*args))) == two.encode(
            b.accel_setpoint(*args)
        )
        assert one.stats == two.stats
    key = bytes(range(32))
    signed = Codec(signing_key=key, unix_s=1.8e9)
    frame = signed.encode_setpoint(_values(b.accel_setpoint(3, 1, 1234, (1.0, -2.0, 0.5))))
    (msg,) = Codec(signing_key=key, unix_s=1.8e9).decode(frame)
    assert msg.get_signed()
    want = b.accel_setpoint(3, 1, 1234, (1.0, -2.0, 0.5)).fields
    assert {k: getattr(msg, k) for k in want} == dict(want)


def test_velocity_rows_are_the_same_bytes_as_one_frame_at_a_time_and_as_pymavlink() -> None:
    """Rows with a velocity (type_mask 3079, Eq. V1) mixed with acceleration-only
    rows (3135) in one call: the same bytes as ``encode_setpoint`` of
    ``vel_accel_setpoint``/``accel_setpoint`` frame by frame, below and above
    the batch size; and one such frame decodes in pymavlink to the fields sent."""
    rng = random.Random(11)
    for k in (1, 5, 8, 9, 40):
        for _ in range(10):
            one, many = Codec(), Codec()
            one._mav.seq = many._mav.seq = rng.randrange(256)
            targets = [(rng.randrange(1, 255), 1) for _ in range(k)]
            boot = [rng.randrange(2**32) for _ in range(k)]
            acc = np.array([[rng.uniform(-5, 5) for _ in range(3)] for _ in range(k)])
            vel = np.array([[rng.uniform(-9, 9) for _ in range(3)] for _ in range(k)])
            with_vel = [rng.random() < 0.5 for _ in range(k)]
            masks = [b.TYPE_MASK_VEL_ACCEL if w else b.TYPE_MASK_ACCEL for w in with_vel]
            sent_vel = np.where(np.array(with_vel)[:, None], vel, 0.0)
            want = b"".join(
                one.encode_setpoint(_values(
                    b.vel_accel_setpoint(ts, tc, t, tuple(v), tuple(a)) if w
                    else b.accel_setpoint(ts, tc, t, tuple(a))
                ))
                for (ts, tc), t, v, a, w in zip(targets, boot, vel.tolist(), acc.tolist(),
                                                with_vel, strict=True)
            )  # fmt: skip
            got, size = many.encode_accel_setpoints(
                targets, boot, acc, type_mask=masks, coordinate_frame=b.MAV_FRAME_LOCAL_NED,
                vel_ned=sent_vel,
            )  # fmt: skip
            assert got == want and size * k == len(want), k
            assert many._mav.seq == one._mav.seq and many.stats == one.stats
    frame, _ = Codec().encode_accel_setpoints(
        [(3, 1)] * 9, [1234] * 9, np.tile([0.5, -0.25, 1.0], (9, 1)),
        type_mask=b.TYPE_MASK_VEL_ACCEL, coordinate_frame=b.MAV_FRAME_LOCAL_NED,
        vel_ned=np.tile([1.5, -2.0, 0.25], (9, 1)),
    )  # fmt: skip
    msgs = mav.MAVLink(None).parse_buffer(frame)
    assert msgs is not None and len(msgs) == 9
    m = msgs[0]
    assert (m.type_mask, m.coordinate_frame, m.target_system) == (3079, 1, 3)
    assert (m.vx, m.vy, m.vz, m.afx, m.afy, m.afz) == (1.5, -2.0, 0.25, 0.5, -0.25, 1.0)
    assert (m.x, m.y, m.z, m.yaw, m.yaw_rate) == (0.0,) * 5


def test_accel_setpoint_batch_is_the_same_bytes_as_one_frame_at_a_time() -> None:
    """``encode_accel_setpoints`` (column-wise, for a formation) against
    ``encode_setpoint`` frame by frame: same bytes, sequence numbers and
    counters, below and above the batch size, with -0.0, float32 denormals
    and rounding, seq wrapping; values float32 cannot hold raise as before."""
    rng = random.Random(7)

    def v() -> float:
        return rng.choice([0.0, -0.0, 1e-40, -3e-39, rng.uniform(-1000, 1000), 1 / 3])

    for k in (1, 3, 7, 8, 9, 30, 250, 251):
        for _ in range(20):
            one, many = Codec(), Codec()
            one._mav.seq = many._mav.seq = rng.randrange(256)
            targets = [(rng.randrange(256), rng.randrange(256)) for _ in range(k)]
            boot = [rng.choice([0, rng.randrange(2**32), 2**32 + 5]) for _ in range(k)]
            acc = np.array([[v(), v(), v()] for _ in range(k)])
            want = b"".join(
                one.encode_setpoint(_values(b.accel_setpoint(ts, tc, t, (a[0], a[1], a[2]))))
                for (ts, tc), t, a in zip(targets, boot, acc.tolist(), strict=True)
            )
            got, size = many.encode_accel_setpoints(
                targets, boot, acc, type_mask=b.TYPE_MASK_ACCEL,
                coordinate_frame=b.MAV_FRAME_LOCAL_NED,
            )  # fmt: skip
            assert got == want and size * k == len(want), k
            assert many._mav.seq == one._mav.seq and many.stats == one.stats
    with pytest.raises(OverflowError):
        Codec().encode_accel_setpoints([(1, 1)] * 9, [0] * 9, np.full((9, 3), 1e39),
                                       type_mask=b.TYPE_MASK_ACCEL, coordinate_frame=1)  # fmt: skip
    # A frame that cannot be packed after two that can: those two are counted, as
    # frame by frame (the link counts the step's setpoints unencodable).
    one, many = Codec(), Codec()
    acc = np.array([[1.0, 2.0, 3.0], [0.5, 0.0, -1.0], [1e39, 0.0, 0.0]])
    for a in acc.tolist()[:2]:
        one.encode_setpoint(_values(b.accel_setpoint(1, 1, 0, (a[0], a[1], a[2]))))
    with pytest.raises(OverflowError):
        many.encode_accel_setpoints([(1, 1)] * 3, [0] * 3, acc, type_mask=b.TYPE_MASK_ACCEL,
                                    coordinate_frame=1)  # fmt: skip
    assert many._mav.seq == one._mav.seq == 2 and many.stats == one.stats
