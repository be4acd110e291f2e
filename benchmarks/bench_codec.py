"""The codec floor: pymavlink's cost per vehicle per control cycle.

Run from the repository root: ``python benchmarks/bench_codec.py`` (about 10 s).

A pymavlink-based station must, for every vehicle and every cycle, at least
decode one LOCAL_POSITION_NED and encode one SET_POSITION_TARGET_LOCAL_NED.
This measures exactly that with the generated ``ardupilotmega`` dialect (the
cheapest pymavlink path: ``parse_buffer`` on a one-frame datagram, then
``set_position_target_local_ned_encode(...).pack``), and the same two steps
through the station's own code (``Codec.decode`` + ``from_pymavlink`` and
``VehicleProtocol.accel_setpoint`` + ``Codec.encode``). Medians of 7 rounds.

Before timing, ``check_identity`` confirms on 500 seeded cases that the
station's LOCAL_POSITION_NED and setpoint fast paths (``gcs_swarm.mavlink.codec``)
give exactly pymavlink's messages and bytes.

Then the frames' CRCs, many at once by position tables
(``mavwire.crc.table_crcs``) against pymavlink's C CRC called frame by frame,
per batch of 8 to 250 frames of LOCAL_POSITION_NED's 40 bytes (the
decoders' and encoders' batches; checked equal first): where the two cross
is ``mavwire.crc.ROWS_MIN``.

``floor_us`` is printed last as ``FLOOR_US=<value>`` so that other
benchmarks (``bench_station.py``) can quote the ratio to it.
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

ROUNDS = 7
CALLS = 20_000


def _median_us(fn: Callable[[], object], calls: int = CALLS) -> tuple[float, float, float]:
    """(median, min, max) over ROUNDS of the mean cost of one call [us]."""
    per = []
    for _ in range(ROUNDS):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        per.append((time.perf_counter() - t0) / calls * 1e6)
    return statistics.median(per), min(per), max(per)


def lpn_frame() -> bytes:
    enc = mav.MAVLink(None, 7, 1)
    return bytes(enc.local_position_ned_encode(123456, 1.5, -2.25, -10.0, 0.1, 0.2, -0.3).pack(enc))


def check_identity(cases: int = 500) -> None:
    """The station's fast paths give pymavlink's bytes and messages (seeded)."""
    import random

    from gcs_swarm.mavlink import builders as b
    from gcs_swarm.mavlink.codec import Codec

    rng = random.Random(8)
    for _ in range(cases):
        sysid, seq = rng.randrange(1, 255), rng.randrange(256)
        ref = mav.MAVLink(None, sysid, 1)
        ref.seq = seq
        vals = [rng.choice([0.0, rng.uniform(-99, 99)]) for _ in range(6)]
        frame = bytes(ref.local_position_ned_encode(rng.randrange(2**32), *vals).pack(ref))
        hb = bytes(ref.heartbeat_encode(2, 3, 81, 4, 4).pack(ref))
        data = frame + hb + frame
        fast, slow = Codec(), mav.MAVLink(None, 255, 190)
        got = [(m.get_type(), m.to_dict(), bytes(m.get_msgbuf())) for m in fast.decode(data)]
        want = [(m.get_type(), m.to_dict(), bytes(m.get_msgbuf())) for m in slow.parse_buffer(data)]
        assert got == want, (got, want)
        acc = (rng.uniform(-9, 9), 0.0, rng.uniform(-9, 9))
        spec = b.accel_setpoint(sysid, 1, rng.randrange(2**32), acc)
        codec, enc = Codec(), mav.MAVLink(None, 255, 190)
        codec._mav.seq = enc.seq = seq
        want_sp = bytes(enc.set_position_target_local_ned_encode(**dict(spec.fields)).pack(enc))
        assert codec.encode(spec) == want_sp


def main() -> float:
    check_identity()
    frame = lpn_frame()
    dec = mav.MAVLink(None, 255, 190)
    dec.robust_parsing = True
    enc = mav.MAVLink(None, 255, 190)

    def py_decode() -> object:
        return dec.parse_buffer(frame)

    def py_encode() -> object:
        msg = enc.set_position_target_local_ned_encode(
            123456, 7, 1, 1, 3135, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, -0.25, 0.125, 0.0, 0.0
        )
        return msg.pack(enc)

    from gcs_swarm.mavlink.codec import Codec
    from gcs_swarm.mavlink.inbound import LocalPositionNed, from_pymavlink
    from gcs_swarm.mavlink.states import ProtocolConfig
    from gcs_swarm.mavlink.vehicle import VehicleProtocol

    codec = Codec()
    vp = VehicleProtocol(7, ProtocolConfig(), goto_m=(0.0, 0.0, 0.0))

    def gcs_decode() -> object:
        return [from_pymavlink(m) for m in codec.decode(frame)]

    def gcs_decode_raw() -> object:  # the raw decoder, the telemetry table's input
        return [LocalPositionNed(r.sysid, r.compid, *r.values)
                for r in codec.decode(frame, raw_positions=True)]  # fmt: skip

    accel = (0.5, -0.25, 0.125)

    def gcs_encode() -> object:
        return codec.encode(vp.accel_setpoint(accel))

    step = 250  # the station frames a whole step's setpoints at once
    targets = [(s % 250 + 1, 1) for s in range(step)]
    boots = [123456] * step
    acc = np.tile(np.array(accel), (step, 1))

    def gcs_encode_step() -> object:
        return codec.encode_accel_setpoints(targets, boots, acc, type_mask=3135, coordinate_frame=1)

    rows = [
        ("pymavlink decode LOCAL_POSITION_NED (parse_buffer)", py_decode, 1),
        ("pymavlink encode SET_POSITION_TARGET_LOCAL_NED (_encode + pack)", py_encode, 1),
        ("station decode (Codec.decode + from_pymavlink)", gcs_decode, 1),
        ("station encode (accel_setpoint + Codec.encode)", gcs_encode, 1),
        ("station hot decode (raw tuple + LocalPositionNed)", gcs_decode_raw, 1),
        (f"station hot encode (encode_accel_setpoints, per frame of {step})", gcs_encode_step,
         step),
    ]  # fmt: skip
    print(f"codec floor, median of {ROUNDS} x {CALLS} calls (us per call, [min..max])")
    res = {}
    for name, fn, per in rows:
        med, lo, hi = (x / per for x in _median_us(fn, CALLS // per))
        res[name] = med
        print(f"  {name:66s} {med:7.2f}  [{lo:.2f}..{hi:.2f}]", flush=True)
    floor = rows[0][0], rows[1][0]
    floor_us = res[floor[0]] + res[floor[1]]
    station_us = res[rows[2][0]] + res[rows[3][0]]
    hot_us = res[rows[4][0]] + res[rows[5][0]]
    print(f"pymavlink floor per vehicle per cycle: {floor_us:.1f} us "
          f"-> {1e6 / floor_us / 50:.0f} vehicles at 50 Hz on one core")  # fmt: skip
    print(f"station codec path per vehicle per cycle: {station_us:.1f} us "
          f"({station_us / floor_us:.2f} x floor)")  # fmt: skip
    print(f"station hot path (flying, a whole step framed at once): {hot_us:.1f} us "
          f"({hot_us / floor_us:.2f} x floor)")  # fmt: skip
    crc_batches()
    print(f"FLOOR_US={floor_us:.2f}")
    return floor_us


def crc_batches() -> None:
    """The position tables against pymavlink's C CRC frame by frame."""
    from mavwire.crc import MCRF4XX, frame_by_frame_crcs, table_crcs

    if MCRF4XX is None:
        print("frames' CRCs: pymavlink's C CRC (fastcrc) is not installed; not compared")
        return
    print(f"frames' CRCs, 40-byte frames, median of {ROUNDS} rounds (us per batch, [min..max])")
    rng = np.random.default_rng(1)
    for n in (8, 16, 20, 32, 250):
        rows = rng.integers(0, 256, size=(n, 40), dtype=np.uint8)
        assert table_crcs(rows, 185).tolist() == frame_by_frame_crcs(rows, 185)
        line = []
        for fn in (frame_by_frame_crcs, table_crcs):
            med, lo, hi = _median_us(lambda fn=fn, rows=rows: fn(rows, 185), 2_000)
            line.append(f"{med:7.2f} [{lo:.2f}..{hi:.2f}]")
        print(f"  {n:3d} frames: frame by frame {line[0]}, position tables {line[1]}", flush=True)


if __name__ == "__main__":
    main()
