"""``mavwire.FrameBuilder`` gives pymavlink's own bytes: column-wise
(``build``) and one frame at a time (``pack``), for seeded random values that
include zeros at the payload's end (MAVLink 2 trims trailing zero bytes, so
frames of one batch differ in length), an all-zero payload (one byte kept),
sequence numbers past 255, a 24-bit message id, and with the C CRC or the
numpy column-wise CRC."""

from __future__ import annotations

import struct
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire import HEADER_BYTES, FrameBuilder
from mavwire import framing as fr

_LPN = mav.MAVLink_local_position_ned_message
_SP = mav.MAVLink_set_position_target_local_ned_message
_LPN_PAYLOAD = np.dtype([("time_boot_ms", "<u4"), ("pos", "<f4", (3,)), ("vel", "<f4", (3,))])
_SP_PAYLOAD = np.dtype([
    ("time_boot_ms", "<u4"), ("pos", "<f4", (3,)), ("vel", "<f4", (3,)), ("acc", "<f4", (3,)),
    ("yaw", "<f4"), ("yaw_rate", "<f4"), ("type_mask", "<u2"), ("target", "u1", (2,)),
    ("coordinate_frame", "u1"),
])  # fmt: skip


_XYZ = ("x", "y", "z", "vx", "vy", "vz", "afx", "afy", "afz")


def _ref(msg: Any, seq: int, sysid: int, compid: int) -> bytes:
    enc = mav.MAVLink(None, sysid, compid)
    enc.seq = seq % 256
    return bytes(msg.pack(enc))


def _sparse(rng: np.random.Generator, shape: tuple[int, ...], scale: float) -> Any:
    """Random values, about a third of them zero (and some -0.0)."""
    x = rng.normal(size=shape) * scale
    x[rng.random(shape) < 0.33] = 0.0
    x[rng.random(shape) < 0.05] = -0.0
    return x


def _lpn_case(rng: np.random.Generator, n: int) -> tuple[dict[str, Any], Any, Any, Any]:
    t = rng.integers(0, 2**32, n)
    t[rng.random(n) < 0.3] = 0
    pos, vel = _sparse(rng, (n, 3), 50.0), _sparse(rng, (n, 3), 2.0)
    vel[rng.random(n) < 0.3] = 0.0  # the last 12 bytes zero: trimmed
    pos[rng.random(n) < 0.1] = 0.0
    vel[0] = pos[0] = 0.0
    t[0] = 0  # an all-zero payload keeps one byte
    seq = rng.integers(0, 600, n)
    sysid, compid = rng.integers(1, 256, n), rng.integers(0, 256, n)
    return {"time_boot_ms": t, "pos": pos, "vel": vel}, seq, sysid, compid


@pytest.mark.parametrize("n", [1, 2, 9, 64, 300])
@pytest.mark.parametrize("c_crc", [True, False], ids=["c-crc", "numpy-crc"])
def test_lpn_batches_are_pymavlinks_bytes(n: int, c_crc: bool, monkeypatch: Any) -> None:
    if not c_crc:
        monkeypatch.setattr(fr, "MCRF4XX", None)
    elif fr.MCRF4XX is None:
        pytest.skip("pymavlink's C CRC (fastcrc) is not installed")
    rng = np.random.default_rng(n)
    b = FrameBuilder(_LPN.id, _LPN.crc_extra, _LPN_PAYLOAD)
    for _ in range(5):
        cols, seq, sysid, compid = _lpn_case(rng, n)
        batch = b.build(seq, sysid, compid, cols)
        want = [
            _ref(_LPN(int(t), *map(float, p), *map(float, v)), int(s), int(si), int(ci))
            for t, p, v, s, si, ci in zip(cols["time_boot_ms"], cols["pos"], cols["vel"],
                                           seq, sysid, compid, strict=True)
        ]  # fmt: skip
        assert batch.tolist() == want
        assert batch.tobytes() == b"".join(want)
        assert batch.lengths.tolist() == [len(w) for w in want]
        assert not batch.full  # the first payload is all zero
        assert min(batch.lengths) == HEADER_BYTES + 1 + 2
        for row, e in zip(batch.rows, batch.lengths, strict=True):
            assert not row[e:].any()  # zero after each frame's end


@pytest.mark.parametrize("c_crc", [True, False], ids=["c-crc", "numpy-crc"])
def test_setpoint_batches_are_pymavlinks_bytes(c_crc: bool, monkeypatch: Any) -> None:
    """Every field set, one column given for all rows (``yaw``), one left out
    (``yaw_rate``: zero), and rows with and without a trailing zero byte."""
    if not c_crc:
        monkeypatch.setattr(fr, "MCRF4XX", None)
    elif fr.MCRF4XX is None:
        pytest.skip("pymavlink's C CRC (fastcrc) is not installed")
    rng = np.random.default_rng(5)
    b = FrameBuilder(_SP.id, _SP.crc_extra, _SP_PAYLOAD)
    for n in (1, 7, 40, 251):
        t = rng.integers(0, 2**32, n)
        pos, vel, acc = (_sparse(rng, (n, 3), 9.0) for _ in range(3))
        mask = rng.integers(0, 2**16, n)
        target = rng.integers(0, 256, (n, 2))
        frame = rng.integers(0, 3, n)  # 0: the last byte is zero, trimmed
        seq = rng.integers(0, 256, n)
        cols = {"time_boot_ms": t, "pos": pos, "vel": vel, "acc": acc, "yaw": 0.5,
                "type_mask": mask, "target": target, "coordinate_frame": frame}  # fmt: skip
        batch = b.build(seq, 255, 190, cols)
        want = [
            _ref(_SP(time_boot_ms=int(t[i]), target_system=int(target[i, 0]),
                     target_component=int(target[i, 1]), coordinate_frame=int(frame[i]),
                     type_mask=int(mask[i]), **dict(zip(_XYZ, map(float, [*pos[i], *vel[i],
                     *acc[i]]), strict=True)), yaw=0.5, yaw_rate=0.0),
                 int(seq[i]), 255, 190)
            for i in range(n)
        ]  # fmt: skip
        assert batch.tolist() == want, n
        assert batch.tobytes() == b"".join(want)
        assert batch.full == all(frame != 0)
    full = b.build([3, 4], 1, 1, {"coordinate_frame": 1})
    assert full.full and full.lengths.tolist() == [12 + _SP.unpacker.size] * 2


def test_one_frame_pack_is_what_build_gives() -> None:
    """``pack`` of a ``struct``-packed payload against ``build`` of one row and
    pymavlink, with a 24-bit message id (the bytes after the id's low byte)."""
    rng = np.random.default_rng(9)
    b = FrameBuilder(_LPN.id, _LPN.crc_extra, _LPN_PAYLOAD)
    pack = struct.Struct("<Iffffff").pack
    for _ in range(300):
        cols, seq, sysid, compid = _lpn_case(rng, 2)
        t, p, v = int(cols["time_boot_ms"][1]), cols["pos"][1].tolist(), cols["vel"][1].tolist()
        s, si, ci = int(seq[1]), int(sysid[1]), int(compid[1])
        one = b.pack(s, si, ci, pack(t, *p, *v))
        assert one == _ref(_LPN(t, *p, *v), s, si, ci)
        assert one == b.build([s], si, ci, {k: c[1:] for k, c in cols.items()}).tobytes()
    wide = FrameBuilder(0x01_23_45, 7, np.dtype([("a", "<u2")]))
    f = wide.build([0], 1, 1, {"a": [0x0102]}).tobytes()
    assert f[7:10] == bytes((0x45, 0x23, 0x01)) and f == wide.pack(0, 1, 1, b"\x02\x01")
    assert len(wide.build([], 1, 1, {}).tobytes()) == 0


def test_payload_layouts_are_checked() -> None:
    with pytest.raises(ValueError, match="little-endian"):
        FrameBuilder(1, 1, np.dtype([("a", ">u4")]))
    with pytest.raises(ValueError, match="packed"):
        FrameBuilder(1, 1, np.dtype([("a", "u1"), ("b", "<u4")], align=True))
    with pytest.raises(ValueError, match="out of range"):
        FrameBuilder(1 << 24, 1, _LPN_PAYLOAD)
    for cls, dtype in ((_LPN, _LPN_PAYLOAD), (_SP, _SP_PAYLOAD)):  # the layouts the ends use
        assert dtype.itemsize == cls.unpacker.size
