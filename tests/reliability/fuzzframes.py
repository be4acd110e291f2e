"""A seeded generator of hostile MAVLink datagrams for the fuzz tests.

Each datagram is one of: random bytes; a valid frame (of a message the
receiver uses, with field values drawn from finite, huge, NaN and infinite
numbers and random integers); that frame truncated, with a flipped bit, with a
wrong length byte, with a wrong CRC; a frame of an unknown message id; a
MAVLink 1 frame; or several of these joined. Pure: bytes only, no I/O.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

__all__ = ["STATION_INBOUND", "VEHICLE_INBOUND", "datagrams"]

#: What the station reads (telemetry) and what the emulator reads (commands).
STATION_INBOUND = (
    "HEARTBEAT", "LOCAL_POSITION_NED", "COMMAND_ACK", "STATUSTEXT", "GPS_GLOBAL_ORIGIN",
    "EKF_STATUS_REPORT", "GPS_RAW_INT", "PARAM_VALUE", "POSITION_TARGET_LOCAL_NED",
)  # fmt: skip
VEHICLE_INBOUND = (
    "HEARTBEAT", "SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG", "COMMAND_INT", "SET_MODE",
    "PARAM_SET", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "REQUEST_DATA_STREAM",
    "MISSION_REQUEST_LIST",
)  # fmt: skip

_ODD_FLOATS = (math.nan, math.inf, -math.inf, 1e30, -1e30, 3.0e38, 1e-40, 0.0, -0.0)
_COMMANDS = (511, 512, 176, 400, 22, 21, 20, 31000, 0, 65535)
_FORMATS = {
    "float": "f", "double": "d", "int8_t": "b", "uint8_t": "B", "int16_t": "h",
    "uint16_t": "H", "int32_t": "i", "uint32_t": "I", "int64_t": "q", "uint64_t": "Q",
    "uint8_t_mavlink_version": "B",
}  # fmt: skip
_PARAMS = (b"GUID_TIMEOUT", b"WP_YAW_BEHAVIOR", b"SIM_ACC_TAU", b"NOPE", b"\xff\xfe", b"")


def _value(rng: np.random.Generator, fmt: str, name: str, odd: float) -> Any:
    """One field value of struct type ``fmt``: mostly plausible, ``odd`` of them hostile."""
    hostile = rng.random() < odd
    if fmt in "fd":
        if hostile:
            return _ODD_FLOATS[rng.integers(len(_ODD_FLOATS))]
        return float(rng.normal(0.0, 20.0))
    if fmt == "c" or fmt.endswith("s"):
        if name == "param_id":
            return _PARAMS[rng.integers(len(_PARAMS))]
        n = int(fmt[:-1]) if fmt[:-1] else 1
        return bytes(rng.integers(0, 256, size=int(rng.integers(0, n + 1)), dtype=np.uint8))
    bits = struct.calcsize("<" + fmt) * 8
    signed = fmt.islower()
    if name == "command" and not hostile:
        return _COMMANDS[rng.integers(len(_COMMANDS))]
    if name in ("target_system", "target_component") and not hostile:
        return int(rng.integers(0, 3))
    if name == "custom_mode" and not hostile:
        return int(rng.integers(0, 28))
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if hostile:
        return int((lo, hi, 0, -1 if signed else hi)[rng.integers(4)])
    return int(rng.integers(max(lo, -1000), min(hi, 1000) + 1))


def valid_frame(
    rng: np.random.Generator, names: tuple[str, ...], sysid: int, *, odd: float = 0.2
) -> bytes:
    """One well-formed, correctly signed-off (CRC) frame of a message in ``names``."""
    name = names[rng.integers(len(names))]
    cls = getattr(mav, "MAVLink_" + name.lower() + "_message")
    values = []
    for field, fmt_type in zip(cls.fieldnames, cls.fieldtypes, strict=True):
        length = cls.array_lengths[cls.ordered_fieldnames.index(field)]
        fmt = _FORMATS[fmt_type] if fmt_type != "char" else f"{max(length, 1)}s"
        if length and fmt_type != "char":
            values.append([_value(rng, fmt, field, odd) for _ in range(length)])
        else:
            values.append(_value(rng, fmt, field, odd))
    msg = cls(*values)
    enc = mav.MAVLink(None, sysid, 1)
    enc.seq = int(rng.integers(256))
    return bytes(msg.pack(enc))


def _crc(data: bytes, extra: int) -> bytes:
    crc = mav.x25crc(data)
    crc.accumulate(bytes((extra,)))
    return struct.pack("<H", crc.crc)


def _mutate(rng: np.random.Generator, frame: bytes) -> bytes:
    kind = int(rng.integers(6))
    b = bytearray(frame)
    if kind == 0:  # truncated
        return bytes(b[: int(rng.integers(1, len(b)))])
    if kind == 1:  # one bit flipped anywhere (header, payload or CRC)
        i = int(rng.integers(len(b)))
        b[i] ^= 1 << int(rng.integers(8))
        return bytes(b)
    if kind == 2:  # wrong length byte
        b[1] = int(rng.integers(256))
        return bytes(b)
    if kind == 3:  # wrong CRC
        b[-1] ^= 0xFF
        return bytes(b)
    if kind == 4:  # unknown message id, CRC computed as if it were known
        payload = bytes(b[10:-2])
        msgid = int(rng.integers(20000, 1 << 24))
        hdr = bytes((0xFD, len(payload), 0, 0, b[4], b[5], b[6])) + msgid.to_bytes(3, "little")
        return hdr + payload + _crc(hdr[1:] + payload, int(rng.integers(256)))
    # extra garbage before and after a good frame
    pre = bytes(rng.integers(0, 256, size=int(rng.integers(0, 20)), dtype=np.uint8))
    post = bytes(rng.integers(0, 256, size=int(rng.integers(0, 20)), dtype=np.uint8))
    return pre + frame + post


def _v1(rng: np.random.Generator, sysid: int) -> bytes:
    """A MAVLink 1 frame (0xFE) of random id and payload: CRC right only by chance."""
    n = int(rng.integers(0, 40))
    body = bytes((n, int(rng.integers(256)), sysid, 1, int(rng.integers(256))))
    payload = bytes(rng.integers(0, 256, size=n, dtype=np.uint8))
    return b"\xfe" + body + payload + _crc(body + payload, int(rng.integers(256)))


def datagrams(seed: int, count: int, names: tuple[str, ...], sysid: int) -> Iterator[bytes]:
    """``count`` hostile datagrams, reproducible from ``seed``; about a quarter
    are valid frames (half of those with hostile values), so the receiver's
    state machines get exercised too."""
    rng = np.random.default_rng(seed)
    pool = [valid_frame(rng, names, sysid) for _ in range(512)]
    for _ in range(count):
        r = rng.random()
        if r < 0.10:
            yield bytes(rng.integers(0, 256, size=int(rng.integers(0, 300)), dtype=np.uint8))
        elif r < 0.35:
            yield valid_frame(rng, names, sysid, odd=0.5 if rng.random() < 0.5 else 0.0)
        elif r < 0.85:
            yield _mutate(rng, pool[rng.integers(len(pool))])
        elif r < 0.90:
            yield _v1(rng, sysid)
        else:
            parts = [pool[rng.integers(len(pool))] for _ in range(int(rng.integers(2, 5)))]
            if rng.random() < 0.5:
                parts[int(rng.integers(len(parts)))] = _mutate(rng, parts[0])
            yield b"".join(parts)
