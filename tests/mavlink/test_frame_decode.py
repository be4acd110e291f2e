"""``frame_decode.decode_unsigned`` makes the object pymavlink's own
``MAVLink.decode`` makes, for every message of the dialect it takes: random
payloads (whole and trimmed, NaNs and strings included), good and bad CRCs."""

from __future__ import annotations

import random
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs_swarm.mavlink import frame_decode
from gcs_swarm.mavlink.frame_decode import decode_unsigned
from mavwire.crc import frame_crc

pytestmark = pytest.mark.skipif(not frame_decode._ENABLED, reason="needs pymavlink's C CRC")


def _frame(msgid: int, payload: bytes, extra: int, rng: random.Random) -> bytes:
    head = bytes((0xFD, len(payload), 0, rng.choice([0, 1]), rng.randrange(256),
                  rng.randrange(1, 256), rng.randrange(256),
                  msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16))  # fmt: skip
    crc = frame_crc(head[1:] + payload, bytes((extra,)))
    return head + payload + bytes((crc & 0xFF, crc >> 8))


def _state(m: Any) -> str:
    """Everything pymavlink's message holds, NaN-proof (repr)."""
    own = {k: v for k, v in vars(m).items() if k != "_header"}
    return repr((type(m), sorted(own.items()), sorted(vars(m.get_header()).items())))


def test_every_message_without_arrays_decodes_as_pymavlink_decodes_it() -> None:
    rng = random.Random(16)
    ref = mav.MAVLink(None, 255, 190)
    taken = 0
    for msgid, msgtype in sorted(mav.mavlink_map.items()):
        size = msgtype.unpacker.size
        for case in range(12):
            n = size if case < 6 else rng.randrange(1, size + 1)  # trimmed: MAVLink 2
            payload = bytes(rng.randrange(256) for _ in range(n))
            frame = _frame(msgid, payload, msgtype.crc_extra, rng)
            if case == 11:  # a bad CRC
                frame = frame[:-1] + bytes((frame[-1] ^ 0x21,))
            got = decode_unsigned(frame)
            if got is NotImplemented:
                assert sum(msgtype.lengths) != len(msgtype.lengths)  # arrays: pymavlink's
                break
            try:
                exp = ref.decode(bytearray(frame))
            except mav.MAVError:
                assert got is None, (msgtype.msgname, case)
                continue
            assert got is not None, (msgtype.msgname, case)
            assert _state(got) == _state(exp), (msgtype.msgname, case)
            taken += 1
    assert taken > 1000
