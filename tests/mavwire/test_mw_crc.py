"""The MAVLink checksum of ``mavwire.crc`` against pymavlink's own: its
``x25crc`` on random bytes, and the CRC of frames its ``pack`` made; the
many-frames form (``row_crcs``, by position tables) against it row by row.
Exact 16-bit integers: no tolerance."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from mavwire import ROWS_MIN, crc_step, frame_by_frame_crcs, frame_crc, row_crcs
from mavwire import crc as mw_crc


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


@pytest.mark.parametrize("fast", [True, False], ids=["fastcrc", "x25crc"])
def test_row_crcs_is_pymavlinks_x25crc_of_each_row(
    fast: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Rows of random bytes, every frame size from the shortest (12 bytes:
    one payload byte) to the longest (267: 255 payload bytes, a body whose
    last position table starts past 65,535) and counts on both sides of
    ``ROWS_MIN`` (frame by frame below it when pymavlink's C CRC is there,
    by the tables from it on, and always by the tables without it)."""
    if fast and mw_crc.MCRF4XX is None:
        pytest.skip("fastcrc is not installed: only the tables' path exists here")
    if not fast:
        monkeypatch.setattr(mw_crc, "MCRF4XX", None)
    rng = np.random.default_rng(5)
    for size in (12, 13, 40, 52, 100, 266, 267):
        for n in (0, 1, ROWS_MIN - 1, ROWS_MIN, 250):
            rows = rng.integers(0, 256, size=(n, size), dtype=np.uint8)
            extra = int(rng.integers(256))
            got = row_crcs(rows, extra)
            assert got.dtype == np.uint16 and got.shape == (n,)
            want = [_x25(r[1:-2].tobytes(), bytes((extra,))) for r in rows]
            assert got.tolist() == want, (size, n)
            assert frame_by_frame_crcs(rows, extra) == want, (size, n)
    # A view that is not contiguous (every other row), as a gather may give.
    rows = rng.integers(0, 256, size=(2 * ROWS_MIN + 2, 40), dtype=np.uint8)
    for part in (rows[::2], rows[: ROWS_MIN - 2 : 2]):
        want = [_x25(r[1:-2].tobytes(), b"\xb9") for r in part]
        assert row_crcs(part, 0xB9).tolist() == want


def test_row_crcs_sees_each_flipped_bit() -> None:
    """One bit flipped anywhere in the CRC's span of one frame among 40
    changes that frame's CRC and no other's (the tables' path)."""
    rng = np.random.default_rng(8)
    rows = rng.integers(0, 256, size=(40, 40), dtype=np.uint8)
    base = row_crcs(rows, 185)
    for _ in range(200):
        i, col, bit = int(rng.integers(40)), int(rng.integers(1, 38)), int(rng.integers(8))
        flipped = rows.copy()
        flipped[i, col] ^= 1 << bit
        changed = np.flatnonzero(row_crcs(flipped, 185) != base).tolist()
        assert changed == [i]
