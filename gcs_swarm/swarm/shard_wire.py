"""What a link shard and its controller exchange each step, as bytes. NO I/O.

docs/architecture.md, "Scaled out: shards". Two per-step messages, each a
fixed 24-byte header and raw little-endian columns (numpy buffers, no
per-vehicle objects, no pickling), so a step of K vehicles costs:

- ``StateBatch`` (shard -> controller): the shard's flying vehicles in key
  order: key ``int32``, ``time_boot_ms`` of a fresh report ``int64`` (-1:
  not fresh since the last step), position [m] and velocity [m/s] in the
  mission frame ``float64 (K, 3)`` each: ``STATE_BYTES_PER_VEHICLE`` = 60.
  Once the controller has answered one of its batches, a shard sends only
  the rows that differ from that batch (``changes``: the fresh ones, and
  any other whose position or velocity bits moved), naming it as ``base``;
  the controller fills in the rest from the batch it holds (``expand``),
  so it steps on exactly the whole batch. With a step per network a
  shard's batch then carries one or two networks' rows, not all of its
  networks' (at 1,500 vehicles in six networks on one shard, measured
  23.6-27.1 kB instead of 90 kB: benchmarks/README.md);
- ``SetpointReply`` (controller -> shard): the mission time [s] of the step
  and, for the vehicles it answers, key ``int32`` and acceleration
  [m/s^2, mission frame] ``float64 (K, 3)``: ``REPLY_BYTES_PER_VEHICLE`` = 28.

Floats cross as float64 bit patterns, so a sharded flight computes exactly
the numbers an unsharded one does (the lockstep test compares to 1e-9 m).
Everything else (hello, assignment, ready, start, end, heartbeats, the
shard's final report) is small JSON, sent a few times per run or at 10 Hz;
a heartbeat carries the keep-out columns (Eq. K1) of the vehicles the shard
calls lost (``keep_out``) and of those out of the formation, heard and in
the air (``keep_live``), each ``{"key": [cx, cy, cz, hx, hy, hz]}``
(``keep_out_json``).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.params import Box
from gcs_swarm.errors import LinkError

__all__ = [
    "HEADER_BYTES",
    "REPLY_BYTES_PER_VEHICLE",
    "STATE_BYTES_PER_VEHICLE",
    "SetpointReply",
    "StateBatch",
    "changes",
    "decode_reply",
    "decode_state",
    "encode_reply",
    "encode_state",
    "expand",
    "keep_out_from_json",
    "keep_out_json",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

_HEADER = struct.Struct("<4sHHIIQ")
"""magic, kind, shard index, sequence number, vehicle count, 64-bit field
(a state: its ``base`` + 1, 0 for a whole batch; a reply: the mission
time's float64 bits)."""
HEADER_BYTES = _HEADER.size
_MAGIC = b"GSSH"
_STATE, _REPLY = 1, 2
STATE_BYTES_PER_VEHICLE = 4 + 8 + 24 + 24
REPLY_BYTES_PER_VEHICLE = 4 + 24


class StateBatch(NamedTuple):
    """One shard's flying vehicles at one step (module docstring): row k is
    vehicle ``keys[k]``; ``boot_ms[k]`` its fresh report's ``time_boot_ms``
    or -1; ``pos_m``/``vel_mps`` ``(K, 3)`` mission frame. ``base``: -1 for
    every flying vehicle; otherwise the ``seq`` of the batch whose other
    rows these update (``changes``, ``expand``)."""

    shard: int
    seq: int
    keys: npt.NDArray[np.int32]
    boot_ms: IntArray
    pos_m: FloatArray
    vel_mps: FloatArray
    base: int = -1

    def fresh(self) -> dict[int, int]:
        """The fresh reports as ``SwarmCore.take_step`` gives them (key -> ms),
        in the batch's order (a network's step: a sixth of a 1,500-vehicle
        batch, picked out before anything becomes a Python int)."""
        at = np.flatnonzero(self.boot_ms >= 0)
        return dict(zip(self.keys[at].tolist(), self.boot_ms[at].tolist(), strict=True))


class SetpointReply(NamedTuple):
    """The controller's answer to one shard for one step: mission time
    ``t_s`` [s], and ``accel_mps2 (K, 3)`` [m/s^2, mission frame] for
    ``keys``; ``seq`` is the shard's latest state batch the step used."""

    shard: int
    seq: int
    t_s: float
    keys: npt.NDArray[np.int32]
    accel_mps2: FloatArray


def encode_state(batch: StateBatch) -> bytes:
    n = len(batch.keys)
    head = _HEADER.pack(_MAGIC, _STATE, batch.shard, batch.seq, n, batch.base + 1)
    return b"".join(
        (
            head,
            np.ascontiguousarray(batch.keys, dtype="<i4").tobytes(),
            np.ascontiguousarray(batch.boot_ms, dtype="<i8").tobytes(),
            np.ascontiguousarray(batch.pos_m, dtype="<f8").tobytes(),
            np.ascontiguousarray(batch.vel_mps, dtype="<f8").tobytes(),
        )
    )


def encode_reply(reply: SetpointReply) -> bytes:
    n = len(reply.keys)
    (bits,) = struct.unpack("<Q", struct.pack("<d", reply.t_s))
    head = _HEADER.pack(_MAGIC, _REPLY, reply.shard, reply.seq, n, bits)
    return b"".join(
        (
            head,
            np.ascontiguousarray(reply.keys, dtype="<i4").tobytes(),
            np.ascontiguousarray(reply.accel_mps2, dtype="<f8").tobytes(),
        )
    )


def _header(data: bytes, kind: int, per_vehicle: int) -> tuple[int, int, int, int]:
    if len(data) < HEADER_BYTES:
        raise LinkError(f"shard message of {len(data)} bytes: shorter than its header")
    magic, got, shard, seq, n, bits = _HEADER.unpack_from(data)
    if magic != _MAGIC or got != kind:
        raise LinkError(f"not a shard message of kind {kind}: {bytes(data[:6])!r}")
    if len(data) != HEADER_BYTES + n * per_vehicle:
        raise LinkError(
            f"shard message: {n} vehicles need {HEADER_BYTES + n * per_vehicle} bytes,"
            f" got {len(data)}"
        )
    return shard, seq, n, bits


def decode_state(data: bytes) -> StateBatch:
    """``encode_state``'s bytes back; ``LinkError`` when they are not one."""
    shard, seq, n, base = _header(data, _STATE, STATE_BYTES_PER_VEHICLE)
    o = HEADER_BYTES
    keys = np.frombuffer(data, dtype="<i4", count=n, offset=o).astype(np.int32)
    o += 4 * n
    ms = np.frombuffer(data, dtype="<i8", count=n, offset=o).astype(np.int64)
    o += 8 * n
    pos = np.frombuffer(data, dtype="<f8", count=3 * n, offset=o).reshape(n, 3).copy()
    o += 24 * n
    vel = np.frombuffer(data, dtype="<f8", count=3 * n, offset=o).reshape(n, 3).copy()
    return StateBatch(shard, seq, keys, ms, pos, vel, base - 1)


def _moved(a: FloatArray, b: FloatArray) -> npt.NDArray[np.bool_]:
    """Where the float64 bits differ (a NaN kept is unchanged, 0.0 to -0.0 a change)."""
    # A view of the same item size needs no copy (a shard's columns are slices).
    moved: npt.NDArray[np.bool_] = a.view(np.int64) != b.view(np.int64)
    return moved


def changes(batch: StateBatch, since: StateBatch) -> StateBatch:
    """The rows of ``batch`` a controller holding ``since`` (a whole batch of
    the same vehicles, ``keys`` equal) needs: the fresh ones and those whose
    position or velocity bits differ from ``since``'s, with ``base``
    ``since.seq`` (module docstring)."""
    rows = np.flatnonzero(
        (batch.boot_ms >= 0)
        | _moved(batch.pos_m, since.pos_m).any(axis=1)
        | _moved(batch.vel_mps, since.vel_mps).any(axis=1)
    )
    return StateBatch(batch.shard, batch.seq, batch.keys[rows], batch.boot_ms[rows],
                      batch.pos_m[rows], batch.vel_mps[rows], since.seq)  # fmt: skip


def expand(batch: StateBatch, held: StateBatch | None) -> StateBatch | None:
    """``batch`` as the whole batch it stands for: itself when whole; a
    ``changes`` batch laid over ``held`` (the whole batch the controller
    last took from that shard), every other row as ``held`` has it and not
    fresh. None when ``held`` cannot be its base (none, older than its
    ``base``, not older than ``batch``, or without one of its vehicles):
    a batch out of order or of another run, dropped by the caller."""
    if batch.base < 0:
        return batch
    if held is None or not batch.base <= held.seq < batch.seq:
        return None
    keys = held.keys
    if len(batch.keys):
        if not len(keys):
            return None
        at = np.minimum(np.searchsorted(keys, batch.keys), len(keys) - 1)
        if not np.array_equal(keys[at], batch.keys):
            return None
    else:
        at = np.zeros(0, dtype=np.intp)
    boot_ms = np.full(len(keys), -1, dtype=np.int64)
    boot_ms[at] = batch.boot_ms
    pos, vel = held.pos_m.copy(), held.vel_mps.copy()
    pos[at] = batch.pos_m
    vel[at] = batch.vel_mps
    return StateBatch(batch.shard, batch.seq, keys, boot_ms, pos, vel)


def decode_reply(data: bytes) -> SetpointReply:
    """``encode_reply``'s bytes back; ``LinkError`` when they are not one."""
    shard, seq, n, bits = _header(data, _REPLY, REPLY_BYTES_PER_VEHICLE)
    (t_s,) = struct.unpack("<d", struct.pack("<Q", bits))
    o = HEADER_BYTES
    keys = np.frombuffer(data, dtype="<i4", count=n, offset=o).astype(np.int32)
    o += 4 * n
    accel = np.frombuffer(data, dtype="<f8", count=3 * n, offset=o).reshape(n, 3).copy()
    return SetpointReply(shard, seq, float(t_s), keys, accel)


def keep_out_json(boxes: Mapping[int, Box]) -> dict[str, list[float]]:
    """A heartbeat's keep-out columns, by key (module docstring)."""
    return {str(k): [*b.centre, *b.half_extents] for k, b in boxes.items()}


def keep_out_from_json(data: Any) -> dict[int, Box] | None:
    """``keep_out_json``'s value back (None: a heartbeat without it);
    ``LinkError`` when it is not one."""
    if data is None:
        return None
    try:
        out = {}
        for k, v in dict(data).items():
            x = [float(c) for c in v]
            if len(x) != 6:
                raise ValueError(f"{len(x)} numbers")
            out[int(k)] = Box(centre=(x[0], x[1], x[2]), half_extents=(x[3], x[4], x[5]))
        return out
    except (TypeError, ValueError) as err:
        raise LinkError(f"shard heartbeat: keep_out is not a set of columns ({err})") from None
