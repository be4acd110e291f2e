"""``sim_vehicle.codec.pack_frame`` (the emulator's frames of its status
streams and replies) against pymavlink's own ``pack``: every message of the
dialect, random field values of each field's type (zeros often, so that
MAVLink 2's trailing-zero trimming is exercised), random sequence numbers
and ids. The same bytes, or None where pymavlink converts a field (arrays,
text) and the emulator keeps pymavlink's packing."""

from __future__ import annotations

import random
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle.codec import pack_frame

_INTS = {"int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-(2**15), 2**15 - 1),
         "uint16_t": (0, 2**16 - 1), "int32_t": (-(2**31), 2**31 - 1),
         "uint32_t": (0, 2**32 - 1), "int64_t": (-(2**63), 2**63 - 1),
         "uint64_t": (0, 2**64 - 1)}  # fmt: skip


def _value(rng: random.Random, ftype: str) -> Any:
    if rng.random() < 0.4:
        return 0.0 if ftype in ("float", "double") else 0
    if ftype in ("float", "double"):
        return rng.choice([rng.uniform(-1e3, 1e3), -0.0, 1e-40, float("inf")])
    lo, hi = _INTS[ftype]
    return rng.randint(lo, hi)


def test_pack_frame_is_pymavlinks_frame_for_every_plain_message() -> None:
    rng = random.Random(12)
    packed = declined = 0
    for cls in mav.mavlink_map.values():
        c: Any = cls
        plain = not any(c.array_lengths) and "char" not in c.fieldtypes
        for _ in range(20):
            values = {n: _value(rng, c.fieldtypes[c.fieldnames.index(n)]) if plain else None
                      for n in c.fieldnames}  # fmt: skip
            if not plain:
                assert pack_frame(_bare(c), 0, 1, 1) is None, c.msgname
                declined += 1
                break
            msg = c(**values)
            seq, sysid, compid = rng.randrange(256), rng.randrange(1, 256), rng.randrange(256)
            enc = mav.MAVLink(None, sysid, compid)
            enc.seq = seq
            assert pack_frame(msg, seq, sysid, compid) == msg.pack(enc), (c.msgname, values)
            packed += 1
    assert packed > 2000 and declined > 20  # both kinds, most of the dialect


def _bare(cls: Any) -> Any:
    """An instance of ``cls`` without calling its constructor (only its type matters)."""
    return cls.__new__(cls)
