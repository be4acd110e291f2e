"""The inbound fast path of ``sim_vehicle.link`` against pymavlink's own parser.

A datagram may hold several MAVLink 2 frames (a station batches the setpoints
of one control step for one peer; ArduPilot reads UDP as a byte stream). The
endpoint decodes unsigned setpoints itself and hands every other byte to
pymavlink; whatever the mix, the messages and the counters must be what
pymavlink's ``parse_buffer`` gives for the whole datagram.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import signing
from sim_vehicle.codec import RawSetpoint
from sim_vehicle.config import Impairment
from sim_vehicle.impairments import Impairer
from sim_vehicle.link import Endpoint, _split_setpoints, bind_udp
from sim_vehicle.stats import LinkStats

SP = mav.MAVLink_set_position_target_local_ned_message
UNKNOWN_MSGID = 60000  # not in the ardupilotmega dialect
assert UNKNOWN_MSGID not in mav.mavlink_map


def _frame_v2(msgid: int, payload: bytes, seq: int, sysid: int, compid: int, extra: int) -> bytes:
    """An unsigned MAVLink 2 frame built by hand (any msgid, any payload length)."""
    body = bytes((len(payload), 0, 0, seq, sysid, compid)) + msgid.to_bytes(3, "little") + payload
    crc = mav.x25crc(body + bytes((extra,))).crc
    return b"\xfd" + body + crc.to_bytes(2, "little")


class _Frames:
    """Seeded random frames: setpoints, other messages, and damaged bytes."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.enc = mav.MAVLink(None, 255, 190)
        self.signer = signing.mavlink(255, 190, bytes(range(32)))

    def _f32(self, k: int) -> list[float]:
        vals = [float(np.float32(v)) for v in self.rng.normal(scale=50.0, size=k)]
        if self.rng.random() < 0.4:  # trailing zeros: MAVLink 2 trims the payload
            cut = int(self.rng.integers(0, k))
            vals[cut:] = [0.0] * (k - cut)
        return vals

    def setpoint(self) -> bytes:
        r, enc = self.rng, self.enc
        enc.seq = int(r.integers(0, 256))
        enc.srcSystem, enc.srcComponent = int(r.integers(1, 256)), int(r.integers(0, 256))
        msg = enc.set_position_target_local_ned_encode(
            int(r.integers(0, 2**32)), int(r.integers(0, 256)), int(r.integers(0, 256)),
            int(r.integers(0, 22)), int(r.integers(0, 4096)), *self._f32(11),
        )  # fmt: skip
        frame: bytes = msg.pack(enc)
        return frame

    def other(self) -> bytes:
        r, enc = self.rng, self.enc
        enc.seq = int(r.integers(0, 256))
        kind = int(r.integers(0, 8))
        if kind == 0:
            msg = enc.heartbeat_encode(6, 8, 0, 0, 0)
        elif kind == 1:
            msg = enc.command_long_encode(
                int(r.integers(0, 256)), 1, int(r.integers(0, 600)), 0, *self._f32(7)
            )
        elif kind == 2:
            msg = enc.param_set_encode(1, 1, b"GUID_TIMEOUT", float(r.normal()), 9)
        elif kind == 3:
            msg = enc.timesync_encode(0, int(r.integers(0, 2**62)))
        elif kind == 4:  # unknown message id: pymavlink's MAVLink_unknown
            payload = bytes(r.integers(1, 256, size=int(r.integers(1, 40)), dtype=np.uint8))
            return _frame_v2(UNKNOWN_MSGID, payload, 0, 255, 190, 0)
        elif kind == 5:  # a setpoint longer than its struct: the general parser takes it
            payload = self.setpoint()[10:-2].ljust(SP.unpacker.size, b"\x00") + b"\x01\x02"
            return _frame_v2(84, payload, 1, 255, 190, SP.crc_extra)
        elif kind == 6:  # MAVLink 1
            frame: bytes = enc.heartbeat_encode(6, 8, 0, 0, 0).pack(enc, force_mavlink1=True)
            return frame
        else:  # signed (the endpoint has no key: pymavlink decodes it without checking)
            frame = self.signer.heartbeat_encode(6, 8, 0, 0, 0).pack(self.signer)
            return frame
        frame = msg.pack(enc)
        return frame

    def damaged(self) -> bytes:
        r = self.rng
        f = bytearray(self.setpoint() if r.random() < 0.6 else self.other())
        kind = int(r.integers(0, 4))
        if kind == 0:  # truncated
            return bytes(f[: int(r.integers(1, len(f)))])
        if kind == 1:  # one byte changed (CRC, length, magic, flags, msgid, ...)
            i = int(r.integers(0, len(f)))
            f[i] = (f[i] + int(r.integers(1, 256))) % 256
            return bytes(f)
        if kind == 2:  # garbage
            return bytes(r.integers(0, 256, size=int(r.integers(1, 30)), dtype=np.uint8))
        return bytes(f[:1]) if r.random() < 0.5 else b"\xfd\x05"  # a lone start

    def datagram(self) -> bytes:
        r = self.rng
        parts = []
        for _ in range(int(r.integers(1, 9))):
            u = r.random()
            parts.append(
                self.setpoint() if u < 0.6 else self.other() if u < 0.85 else self.damaged()
            )
        return b"".join(parts)


def _reference(data: bytes) -> tuple[list[Any], int, int]:
    """pymavlink alone on one datagram: (good messages, bad frames, unknown frames)."""
    parser = signing.mavlink(0, 0, None)
    bad = 0
    try:
        msgs = parser.parse_buffer(data) or []
    except (mav.MAVError, ValueError, IndexError):
        msgs, bad = [], 1
    bad += parser.buf_len() > 0  # a truncated tail is one bad frame
    bad += sum(isinstance(m, mav.MAVLink_bad_data) for m in msgs)
    unknown = sum(isinstance(m, mav.MAVLink_unknown) for m in msgs)
    good = [m for m in msgs if not isinstance(m, mav.MAVLink_bad_data | mav.MAVLink_unknown)]
    return good, bad, unknown


def _header(m: Any) -> tuple[int, ...]:
    h = m.get_header()
    return (h.msgId, h.incompat_flags, h.compat_flags, h.mlen, h.seq, h.srcSystem, h.srcComponent)


def test_multi_frame_datagrams_decode_as_pymavlink_does() -> None:
    rng = np.random.default_rng(11)
    frames = _Frames(rng)
    sock = bind_udp("127.0.0.1", 0)
    stats = LinkStats()
    imp = Impairer(Impairment(), np.random.default_rng(0))
    ep = Endpoint(sock, False, imp, imp, lambda _e, _d, _a: None, stats)
    fast_in_batches = raw_setpoints = 0
    try:
        for _ in range(3000):
            data = frames.datagram()
            before = (stats.bad_frames, stats.unknown_frames, stats.signature_rejected)
            got = ep.parse(data)
            counts = (
                stats.bad_frames - before[0],
                stats.unknown_frames - before[1],
                stats.signature_rejected - before[2],
            )
            want, bad, unknown = _reference(data)
            assert counts == (bad, unknown, 0), data.hex()
            # raw: the same, the setpoints as RawSetpoint (the core's 50 Hz lane)
            raw = ep.parse(data, raw=True)
            assert len(raw) == len(got)
            assert [type(m) for m in got] == [type(m) for m in want], data.hex()
            for g, w, r in zip(got, want, raw, strict=True):
                assert repr(g.to_dict()) == repr(w.to_dict())  # repr: NaN equals NaN
                assert _header(g) == _header(w)
                if isinstance(r, RawSetpoint):
                    raw_setpoints += 1
                    assert r.get_msgId() == w.get_msgId() and r.target_system == w.target_system
                    r = r.message()
                assert type(r) is type(w)
                assert repr(r.to_dict()) == repr(w.to_dict()) and _header(r) == _header(w)
            pieces = _split_setpoints(data)
            if len(pieces) > 1:
                fast_in_batches += sum(not isinstance(p, bytes) for p in pieces)
    finally:
        sock.close()
    # the fast path did decode setpoints out of multi-frame datagrams (about 7000 here)
    assert fast_in_batches > 3000
    assert raw_setpoints > fast_in_batches


def test_batch_joins_frames_into_datagrams_of_the_shared_limit() -> None:
    """``Endpoint.batch``: 70 LOCAL_POSITION_NED-sized frames (40 bytes) and a
    HEARTBEAT-sized one (key 0: no telemetry) cut as ``mavwire.datagram_bounds``
    says, 30 per 1200-byte datagram, bytes in order, each with its frames'
    nonzero keys; one frame is one datagram; nothing gives nothing."""
    sock = bind_udp("127.0.0.1", 0)
    imp = Impairer(Impairment(), np.random.default_rng(0))
    ep = Endpoint(sock, False, imp, imp, lambda _e, _d, _a: None, LinkStats())
    try:
        frames = [(bytes([k]) * 40, k + 1) for k in range(70)]
        frames.insert(35, (b"\xfd" * 21, 0))
        out = ep.batch(frames)
        assert [len(d) for d, _ in out] == [1200, 1181, 440]
        assert b"".join(d for d, _ in out) == b"".join(f for f, _ in frames)
        assert [keys for _, keys in out] == [
            list(range(1, 31)),
            list(range(31, 60)),
            list(range(60, 71)),
        ]
        assert ep.batch(frames[:1]) == [(frames[0][0], [1])]
        assert ep.batch([]) == []
    finally:
        sock.close()
