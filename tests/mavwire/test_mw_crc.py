"""The MAVLink checksum of ``mavwire.crc`` against pymavlink's own: its
``x25crc`` on random bytes, and the CRC of frames its ``pack`` made. Exact
16-bit integers: no tolerance."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from mavwire import crc as mw_crc
from mavwire import crc_step, frame_crc


def _x25(body: bytes, extra: bytes) -> int:
    x = dialect.x25crc(body)
    x.accumulate(extra)
    return int(x.crc)


def _bodies(seed: int, count: int = 200) -> list[bytes]:
    rng = np.random.default_rng(seed)
    return [rng.bytes(int(n)) for n in rng.integers(0, 280, size=count)]


@pytest.mark.parametrize("fast", [True, False], ids=["fastcrc", "x25crc"])
def test_frame_crc_is_pymavlinks_x25crc_on_random_bytes(
    fast: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    if fast and mw_crc.MCRF4XX is None:
        pytest.skip("fastcrc is not installed: only the x25crc path exists here")
    if not fast:
        monkeypatch.setattr(mw_crc, "MCRF4XX", None)  # the fallback path, as without fastcrc
    rng = np.random.default_rng(7)
    for body in _bodies(16):
        extra = bytes((int(rng.integers(256)),))
        assert frame_crc(body, extra) == _x25(body, extra)
        assert frame_crc(memoryview(body), extra) == _x25(body, extra)


def test_frame_crc_checks_frames_pymavlink_packed() -> None:
    """Random HEARTBEAT and LOCAL_POSITION_NED frames from pymavlink's ``pack``:
    their last two bytes are ``frame_crc`` of the rest after the magic byte."""
    rng = np.random.default_rng(11)
    mav = dialect.MAVLink(None, 1, 1)
    for _ in range(100):
        v = rng.normal(0.0, 100.0, size=6).tolist()
        for msg in (
            dialect.MAVLink_local_position_ned_message(int(rng.integers(2**32)), *v),
            dialect.MAVLink_heartbeat_message(*rng.integers(0, 256, size=5).tolist(), 3),
        ):
            frame = bytes(msg.pack(mav))
            extra = bytes((msg.crc_extra,))
            assert frame_crc(frame[1:-2], extra) == int.from_bytes(frame[-2:], "little")


def test_crc_step_over_rows_is_frame_crc_of_each() -> None:
    """The column-wise numpy CRC (one byte of every row per step) gives, row by
    row, what ``frame_crc`` gives (equal-length rows, as the encoders use it)."""
    rng = np.random.default_rng(3)
    rows = rng.integers(0, 256, size=(50, 37), dtype=np.uint8)
    extra = 185
    crc = np.full(len(rows), mw_crc.CRC_INIT, dtype=np.uint32)
    wide = rows.astype(np.uint32)
    for j in range(rows.shape[1]):
        crc = crc_step(crc, wide[:, j])
    crc = crc_step(crc, np.full(len(rows), extra, dtype=np.uint32))
    assert crc.tolist() == [frame_crc(r.tobytes(), bytes((extra,))) for r in rows]
