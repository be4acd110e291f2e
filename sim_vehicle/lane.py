"""The deferred lane, column-wise: many datagrams of the station's 50 Hz
acceleration stream taken at once.

``EmulatorCore._deliver`` holds a streamed acceleration setpoint for a
vehicle that is already flying the stream (its ``lane``): it writes the
setpoint's a_ff into the fleet row and keeps it for the autopilot's
``stream_accel`` (``_fold``). At 1,500 vehicles on shared endpoints that is
75,000 setpoints a second, each cut from its datagram, checked for its CRC,
unpacked into a ``codec.RawSetpoint`` and walked through ``_deliver``:
about 2.7 us of the emulator's CPU each (``bench_emulator.py --networks``).

``take_stream`` takes the datagrams a shared endpoint has queued from one
peer (``server.Emulator`` reads them together, ``link.Endpoint``) as one
array of frames when every frame is such a setpoint: the frames' headers
checked as columns, each CRC in C, the lane's rules (``commands.streamed_accel``:
type_mask 3135, MAV_FRAME_LOCAL_NED, this component or 0, every value
within ``SETPOINT_LIMIT``; the vehicle's lane open and not landed) as array
tests, then each vehicle's held setpoint set, in the frames' order (the
last of a vehicle's wins, as one by one). It leaves exactly the state that
``EmulatorCore.receive`` of each datagram in turn leaves (the fleet, the
vehicles' held setpoints and the counters; tests/sim_vehicle/test_sv_lane_columns.py
compares them bit for bit), or, when any datagram is not of that kind,
changes nothing and says so: the caller then receives each datagram as
before. Never in lockstep (a datagram there may complete a step) nor
through an active uplink impairment (it draws per datagram). No I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from operator import attrgetter
from typing import TYPE_CHECKING

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire.crc import row_crcs
from sim_vehicle.commands import ECHO_MASK, SETPOINT_LIMIT

if TYPE_CHECKING:
    from sim_vehicle.core import EmulatorCore
    from sim_vehicle.vehicles import Addr, Port

__all__ = ["MIN_BYTES", "MIN_FRAMES", "may_be_stream", "take_stream"]

MIN_FRAMES = 32
"""Frames read together from which ``take_stream`` is tried: its fixed
array work costs about what 15-20 setpoints one by one do (in process at
1,500 vehicles, each 20-frame datagram offered alone: 2.9 us a setpoint
against 2.5 one by one; a network's 13-14 datagrams together: 1.0-1.6). A
station's step of a 250-vehicle network is about 250 frames."""

_SP = mav.MAVLink_set_position_target_local_ned_message
_SP_ID = _SP.id  # 84: one byte on the wire, then two zeros
_EXTRA_BYTE = _SP.crc_extra
_PAYLOAD = np.dtype(
    [
        ("time_boot_ms", "<u4"),
        ("pos", "<f4", (3,)),
        ("vel", "<f4", (3,)),
        ("acc", "<f4", (3,)),
        ("yaw", "<f4"),
        ("yaw_rate", "<f4"),
        ("type_mask", "<u2"),
        ("target_system", "u1"),
        ("target_component", "u1"),
        ("coordinate_frame", "u1"),
    ]
)
"""SET_POSITION_TARGET_LOCAL_NED's payload in wire order (53 bytes)."""
assert _PAYLOAD.itemsize == _SP.unpacker.size
_SIZE = 12 + _PAYLOAD.itemsize
"""A whole untrimmed unsigned frame [bytes]: 65. The station's stream never
trims (coordinate_frame, the last byte, is 1); a trimmed frame is left to
the one-by-one path."""
MIN_BYTES = MIN_FRAMES * _SIZE
"""``MIN_FRAMES`` whole setpoint frames [bytes]: 2,080."""
_FRAME = np.dtype([("head", "u1", (10,)), ("payload", _PAYLOAD), ("crc", "<u2")])
_HEAD_AT = np.array([0, 1, 2, 7, 8, 9], dtype=np.intp)
_HEAD = np.array([0xFD, _PAYLOAD.itemsize, 0, _SP_ID, 0, 0], dtype=np.uint8)
"""Header bytes 0, 1, 2, 7, 8, 9 of every frame taken: the MAVLink 2 magic,
a whole payload, no incompatibility flag (unsigned), the message id."""
_ACCEL_ONLY = ECHO_MASK["accel"]
_LANE, _ROW = attrgetter("lane"), attrgetter("row")


def may_be_stream(data: bytes) -> bool:
    """``data`` may be a datagram of the stream (``take_stream``): whole
    frames of the setpoint's size, the first one a setpoint. The shell reads
    ahead only behind such datagrams, so that anything else (a start-up's
    commands, each of which an autopilot answers) is still handled one
    datagram at a time, between the clock's steps."""
    n = len(data)
    return n >= _SIZE and n % _SIZE == 0 and data[7] == _SP_ID


def take_stream(core: EmulatorCore, ep: Port, grams: Sequence[bytes], addr: Addr) -> bool:
    """Every datagram of ``grams`` (from ``addr``, at port ``ep``, at the
    core's sim time) taken at once, as ``core.receive`` of each in turn
    would (module docstring): True; False when one of them, or the port,
    the peer or the core's state, is not the lane's case (nothing changed)."""
    if (
        core.lockstep
        or not core.defer_stream
        or ep.silent
        or ep.signing_key is not None
        or ep.uplink.imp.active
        or addr not in ep.peers
        or (ep.out == addr and id(ep) not in core.out_heard)
        or any(len(g) % _SIZE or not g for g in grams)
    ):
        return False
    blob = b"".join(grams)
    u8 = np.frombuffer(blob, dtype=np.uint8).reshape(-1, _SIZE)
    if not (u8[:, _HEAD_AT] == _HEAD).all():
        return False
    frames = u8.view(_FRAME)[:, 0]
    if (row_crcs(u8, _EXTRA_BYTE) != frames["crc"]).any():
        return False
    pay = frames["payload"]
    vehicles, sysids = core.vehicles, ep.sysids
    try:  # 0 (every vehicle of the port) is never a vehicle's system id
        vs = [vehicles[sysids[ts]] for ts in pay["target_system"].tolist()]
    except KeyError:
        return False
    if not all(map(_LANE, vs)):
        return False
    fleet = core.fleet
    rows = list(map(_ROW, vs))
    tc = pay["target_component"]
    acc = pay["acc"].astype(np.float64)
    if (
        fleet.landed[rows].any()
        or not (pay["type_mask"] == _ACCEL_ONLY).all()
        or not (pay["coordinate_frame"] == mav.MAV_FRAME_LOCAL_NED).all()
        or not ((tc == 0) | (tc == fleet.compid[rows])).all()
        or not (np.abs(acc) <= SETPOINT_LIMIT).all()  # NaN fails too
    ):
        return False
    # commands.streamed_accel's rotation by a zero yaw, written out there as
    # (ax - 0.0 * ay, 0.0 * ax + ay, az): the same operations on the same
    # float64s, signed zeros included.
    ax, ay, az = acc[:, 0], acc[:, 1], acc[:, 2]
    north, east = ax - 0.0 * ay, 0.0 * ax + ay
    held = list(zip(north.tolist(), east.tolist(), az.tolist(), strict=True))
    now = core.sim_time_s
    for v, a in zip(vs, held, strict=True):
        v.lane_a, v.lane_t = a, now
    fleet.set_a_ff_rows(rows, np.column_stack((north, east, az)))
    stats = core.stats.link
    stats.rx_datagrams += len(grams)
    stats.rx_stream_batched += len(grams)
    return True
