"""The flying vehicles' telemetry, column by column: the hot path's one owner.

A FLYING vehicle's LOCAL_POSITION_NED (50 Hz per vehicle) does not go
through its ``VehicleProtocol``: the codec's raw decoder unpacks the frame
(``Codec.decode(raw_positions=True)``), the link state checks who sent it
(``swarm/link_state.py``) and ``TelemetryTable.write`` stores it in that
vehicle's row; the control step reads the rows as arrays
(``mission_states``, ``boot_ms``, ``arrival_s``) and answers through
``answer`` (docs/architecture.md, "From a datagram to a setpoint").

The protocol hears only what changes its phase or its counters:

- a report the table does not take (implausible numbers, a duplicate, a
  reordered or older one) goes on to ``VehicleProtocol.handle_message``,
  which counts it (``rejected_values``, ``stale_telemetry``) exactly as
  before;
- the telemetry-rate window (every ``RATE_WINDOW_MS`` of vehicle time):
  ``VehicleProtocol.rate_window``, which may ask for the interval again;
- a HEARTBEAT or a status message (``inbound.STATUS_FIELDS``: SYS_STATUS,
  GPS_RAW_INT, EKF_STATUS_REPORT, ESTIMATOR_STATUS, EXTENDED_SYS_STATE):
  only one that differs from the last of its kind its FLYING protocol
  handled (``message_seen``) goes on to it; an unchanged one (the same
  component and the fields its typed message holds) would change nothing
  there but the time the vehicle was last heard, so the row keeps that
  time (``unchanged``, ``heard_s``, ``said_s``);
- the watchdog and everything else that reads the vehicle's latest report
  (``position``, ``position_at``, ``last_accel_ned``) read this table's row
  while the vehicle is attached; leaving FLYING, the protocol takes its row
  back (``VehicleProtocol.begin_flying`` attaches, its phase change
  detaches).

The checks are ``VehicleProtocol._on_position``'s FLYING branch and
``inbound.plausible``, which stay the readable reference:
``tests/mavlink/test_telemetry_table.py`` feeds both the same reports and
compares the state. No I/O, no clock: ``now`` is an argument.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Collection, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.velocity_bias import BiasBank
from gcs_swarm.mavlink.accel_clip import SMALL_ROWS, clip_accel_ned, unclipped_ned_small
from gcs_swarm.mavlink.inbound import (
    POSITION_LIMIT_M,
    SPEED_LIMIT_MPS,
    STATUS_FIELDS,
    Heartbeat,
    LocalPositionNed,
    seen_key,
)
from gcs_swarm.mavlink.inbound import Inbound as Message
from gcs_swarm.mavlink.raw_frames import LPN_PAYLOAD
from gcs_swarm.mavlink.telemetry_batch import RATE_WINDOW_MS, REBOOT_MS, _TableBatch

if TYPE_CHECKING:
    from gcs_swarm.control.velocity_bias import VelocityBiasObserver
    from gcs_swarm.mavlink.vehicle import VehicleProtocol

__all__ = ["RATE_WINDOW_MS", "REBOOT_MS", "TelemetryTable"]

FloatArray = npt.NDArray[np.float64]

_ROW = struct.Struct("<I6f")
"""LOCAL_POSITION_NED's payload in wire order: time_boot_ms [ms], x, y, z [m],
vx, vy, vz [m/s] NED (28 bytes)."""
_ROW_SIZE = _ROW.size
_PACK_ROW = _ROW.pack_into
_ROW_DTYPE = LPN_PAYLOAD
assert _ROW_DTYPE.itemsize == _ROW_SIZE
_LPN_ID = 32
"""LOCAL_POSITION_NED's message id."""
_HB_ID = 0
"""HEARTBEAT's message id."""
_STATUS_TYPE = {i: t for i, (t, _) in STATUS_FIELDS.items()}
"""The typed message of each status message id."""
_STATE_COLS = np.array([1, 0, 2, 4, 3, 5], dtype=np.intp)
"""The NED row's columns (x, y, z, vx, vy, vz) in mission-frame order:
north, east, down -> east, north, up."""
_STATE_SIGN = np.array([1.0, 1.0, -1.0, 1.0, 1.0, -1.0])
"""Down -> up (a sign flip: exact)."""
_NO_REPORT = -(1 << 62)
"""``time_boot_ms`` of a row with no report yet: every report is newer."""

Inbound = Callable[[int, int, int, int], None]
"""``inbound(sysid, compid, seq, msgid)``: the flight recorder's counts."""


class TelemetryTable(_TableBatch):
    """One row per vehicle of ``sysids`` (a slot each, fixed for the run).

    Columns (row k is vehicle ``sysids[k]``):
    ``rows["time_boot_ms"]`` (N,) and ``rows["ned"]`` (N, 6) the last report
    taken (float32 as on the wire: x, y, z [m], vx, vy, vz [m/s] NED);
    ``arrival_s`` (N,) when it arrived [s]; ``fresh`` (N flags, a list: set
    per report) taken since the last step; ``offset_m`` (N, 3) the vehicle's
    EKF origin in the mission frame; ``bias_ned`` (N, 3) the velocity-bias correction [m/s] NED;
    ``accel_ned`` (N, 3) the last acceleration setpoint [m/s^2] NED.
    ``owners[k]`` is the attached (FLYING) protocol, else None: only
    attached rows take reports.
    """

    def __init__(self, sysids: Sequence[int], groups: Sequence[int] | None = None) -> None:
        self.sysids = tuple(sysids)
        self.slot = {s: k for k, s in enumerate(self.sysids)}
        n = len(self.sysids)
        self.group = [0] * n if groups is None else [int(g) for g in groups]
        """Each row's group (its network, for a step per network's reports:
        ``complete_groups``), 0 .. G - 1."""
        self._attached_in = [0] * (max(self.group, default=0) + 1)
        self._fresh_in = [0] * len(self._attached_in)
        self._buf = bytearray(n * _ROW.size)
        self.rows: npt.NDArray[Any] = np.frombuffer(self._buf, dtype=_ROW_DTYPE)
        self.arrival_s = np.full(n, -math.inf)
        self.fresh = [False] * n
        self._fresh_rows: list[int] = []
        """The rows taken since the last ``take_fresh``, in the order taken."""
        self.offset_m = np.zeros((n, 3))
        self.bias_ned = np.zeros((n, 3))
        self.accel_ned = np.zeros((n, 3))
        self._adjust = np.zeros((n, 6))
        """What ``mission_states`` adds to each row's reordered, sign-flipped
        report: the offset [m] and minus the bias [m/s] in the mission frame
        (kept with ``offset_m`` and ``bias_ned``)."""
        self.owners: list[VehicleProtocol | None] = [None] * n
        self.seen_s = [-math.inf] * n
        """When each row's last report was handled [s] (the stale watchdog's clock)."""
        self.heard_s = [-math.inf] * n
        """When each row last took an unchanged HEARTBEAT [s] (``unchanged``: the
        link watchdog's clock, with the protocol's own)."""
        self.said_s = [-math.inf] * n
        """When each row last took an unchanged status message [s] (the same)."""
        self.fresh_count = 0
        """Rows taken since the last ``take_fresh``."""
        self.taken = 0
        """Reports taken since the owner last read it (the owner resets it)."""
        self.attention: list[int] = []
        """System ids whose protocol queued something (the rate window); the
        owner services them and clears the list."""
        self.on_inbound: Inbound | None = None
        """Called with the header of every report ``write`` takes (``seq >= 0``)."""
        self._ms = [_NO_REPORT] * n
        self._compid = [1] * n
        self._bias = BiasBank(n)
        """The attached rows' velocity-bias observers, fed at the control step."""
        self._pending: list[int] = []
        """Rows whose report the observer has not taken yet (``_observe_pending``)."""
        self._pend = [False] * n
        self._corr: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * n
        self._correcting = [False] * n  # the attached observer's settings.correct
        self._rate_t0: list[int | None] = [None] * n
        self._rate_n = [0] * n
        self._incomplete: set[int] = set()
        self._seen: list[dict[type, tuple[int, ...]] | None] = [None] * n
        """Per row, by typed message (``inbound.seen_key``): (compid, its fields)
        of the HEARTBEAT and each status message the row's protocol last
        handled in FLYING (``message_seen``); None while not attached."""

    # ------------------------------------------------------- attach/detach
    def attach(self, vp: VehicleProtocol) -> int:
        """Vehicle ``vp`` starts FLYING: its row takes its reports from now
        on, starting from its latest (``VehicleProtocol.begin_flying``).
        Returns its slot."""
        k = self.slot[vp.sysid]
        if self.owners[k] is None:
            self._attached_in[self.group[k]] += 1
        pos = vp.position
        if pos is None:
            self._ms[k] = _NO_REPORT
            _ROW.pack_into(self._buf, k * _ROW.size, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        else:
            self._ms[k] = pos.time_boot_ms
            self._compid[k] = pos.compid
            _ROW.pack_into(self._buf, k * _ROW.size, *pos[2:])
        self.seen_s[k] = vp.position_at
        obs = vp.velocity_bias
        self._bias.attach(k, obs)
        self._correcting[k] = obs.settings.correct
        self._corr[k] = c = obs.correction
        self._set_bias(k, c)
        self.accel_ned[k] = vp.last_accel_ned
        self._rate_t0[k], self._rate_n[k] = None, 0
        self._seen[k] = {}  # its first HEARTBEAT and status in FLYING go to the protocol
        self.heard_s[k] = self.said_s[k] = -math.inf
        self.owners[k] = vp
        self.set_offset(k, vp.offset_m)
        if pos is None:
            self._incomplete.add(k)
        return k

    def detach(self, k: int) -> None:
        """Row ``k`` stops taking reports (its vehicle left FLYING): it is
        no longer fresh; the protocol has read back what it needs."""
        if self.owners[k] is not None:
            self._attached_in[self.group[k]] -= 1
        if self._pend[k]:
            self._observe_pending()
        self._bias.detach(k)
        self.owners[k] = None
        self._seen[k] = None
        self._incomplete.discard(k)
        if self.fresh[k]:
            self.fresh[k] = False
            self._fresh_rows.remove(k)
            self.fresh_count -= 1
            self._fresh_in[self.group[k]] -= 1

    def set_offset(self, k: int, offset_m: FloatArray | None) -> None:
        """Row ``k``'s EKF origin in the mission frame [m] (None: not known)."""
        if offset_m is None:
            self.offset_m[k] = math.nan
            self._adjust[k, :3] = math.nan
            self._incomplete.add(k)
        else:
            self.offset_m[k] = offset_m
            self._adjust[k, :3] = self.offset_m[k]
            if self._ms[k] != _NO_REPORT:
                self._incomplete.discard(k)

    def _set_bias(self, k: int, c: tuple[float, float, float]) -> None:
        """Row ``k``'s velocity-bias correction [m/s] NED (``bias_ned``)."""
        self.bias_ned[k] = c
        # mission_states' vel = (v_e - b_e, v_n - b_n, -v_d + b_d): minus the bias
        # reordered, with down's sign flipped twice.
        adj = self._adjust
        adj[k, 3], adj[k, 4], adj[k, 5] = -c[1], -c[0], c[2]

    # ------------------------------------------------------- velocity bias
    def observer(self, k: int) -> VelocityBiasObserver | None:
        """Row ``k``'s velocity-bias observer with every report the row has
        taken (None when no vehicle is attached)."""
        if self._pend[k]:
            self._observe_pending()
        return self._bias.sync(k)

    def _observe_pending(self) -> None:
        """The observers take every report waiting, as arrays (``BiasBank``),
        each row's in the order it came (one each: a row's next report
        takes the waiting ones first)."""
        ks, self._pending = self._pending, []
        pend = self._pend
        for k in ks:
            pend[k] = False
        rec = self.rows[ks]
        reports = np.empty((len(ks), 7))
        reports[:, 0] = rec["time_boot_ms"]
        reports[:, 0] *= 1e-3  # ms * 1e-3 as the observer's update takes it: the same float
        reports[:, 1:] = rec["ned"]
        for k in self._bias.update(ks, reports):
            self._new_estimate(k)

    def _new_estimate(self, k: int) -> None:
        if self._correcting[k]:  # else the zeros set at attach stand (obs.correction)
            obs = self._bias.observers[k]
            assert obs is not None
            c = obs.bias
            if c is not self._corr[k]:  # a new estimate (every window / 20)
                self._corr[k] = c
                self._set_bias(k, c)

    # --------------------------------------------------------------- rows
    def position(self, k: int) -> LocalPositionNed | None:
        """Row ``k``'s last report, as ``VehicleProtocol.position`` holds one."""
        if self._ms[k] == _NO_REPORT:
            return None
        values = _ROW.unpack_from(self._buf, k * _ROW.size)
        return LocalPositionNed(self.sysids[k], self._compid[k], *values)

    def ned_positions(self, ks: npt.NDArray[np.intp]) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
        """Rows ``ks``' last reported positions ``(K, 3)`` [m] NED (NaN where a
        row has no report) and which rows are attached (their protocol reads
        its position from here): ``position`` for many rows at once."""
        ms = self._ms
        owners = self.owners
        kl = ks.tolist()
        have = np.array([ms[k] != _NO_REPORT for k in kl], dtype=bool)
        attached = np.array([owners[k] is not None for k in kl], dtype=bool)
        ned = self.rows["ned"][ks, :3].astype(np.float64)
        ned[~have] = math.nan
        return ned, attached

    def boot_ms(self, k: int) -> int:
        """Row ``k``'s last report's ``time_boot_ms`` (0 before any)."""
        ms = self._ms[k]
        return 0 if ms == _NO_REPORT else ms

    def boot_ms_of(self, ks: npt.NDArray[np.intp]) -> list[int]:
        """``boot_ms`` of each of rows ``ks``."""
        ms = self._ms
        return [0 if m == _NO_REPORT else m for m in map(ms.__getitem__, ks.tolist())]

    def write(
        self,
        k: int,
        compid: int,
        seq: int,
        values: tuple[Any, ...],
        now: float,
        rx_s: float,
    ) -> bool:
        """Take one LOCAL_POSITION_NED of row ``k``'s vehicle (``values``: the
        payload in wire order, (time_boot_ms, x, y, z, vx, vy, vz)) handled at
        ``now`` [s], arrived at ``rx_s`` [s]. True if it is now the row's
        report; False if the row has no attached vehicle, or the numbers are
        implausible, or it is not newer than the last (the caller hands it to
        the protocol, which counts it). ``seq >= 0``: the frame's sequence
        number, for ``on_inbound`` (called for a report taken; one not taken
        goes on as a message, counted where messages are)."""
        # 50 Hz per vehicle: each list attribute read once, the struct's method
        # bound at import; the checks and their order are the reference's.
        vp = self.owners[k]
        if vp is None:
            return False
        ms, x, y, z, vx, vy, vz = values
        # inbound.plausible, written out (chained comparisons are False for NaN, inf).
        p, v = POSITION_LIMIT_M, SPEED_LIMIT_MPS
        if not (-p <= x <= p and -p <= y <= p and -p <= z <= p
                and -v <= vx <= v and -v <= vy <= v and -v <= vz <= v):  # fmt: skip
            return False
        last_ms = self._ms
        if 0 <= last_ms[k] - ms < REBOOT_MS:
            return False  # a duplicated or reordered frame: the protocol counts it
        # The velocity-bias observers take the reports at the next control step,
        # many rows at once (_observe_pending); if this row's last is still
        # waiting (no step since), every waiting one is taken now.
        pend = self._pend
        if pend[k]:
            self._observe_pending()
        pend[k] = True
        self._pending.append(k)
        _PACK_ROW(self._buf, k * _ROW_SIZE, *values)
        last_ms[k] = ms
        self._compid[k] = compid
        self.seen_s[k] = now
        self.arrival_s[k] = rx_s
        # VehicleProtocol._count_report, column-wise: the window's report count.
        rate_t0 = self._rate_t0
        t0 = rate_t0[k]
        if t0 is None or ms < t0:
            rate_t0[k], self._rate_n[k] = ms, 0
        elif ms - t0 < RATE_WINDOW_MS:
            self._rate_n[k] += 1
        else:
            self._end_window(k, ms, t0)
        if self._incomplete and k in self._incomplete and not math.isnan(self.offset_m[k, 0]):
            self._incomplete.discard(k)  # the first report of a row attached without one
        fresh = self.fresh
        if not fresh[k]:
            fresh[k] = True
            self._fresh_rows.append(k)
            self.fresh_count += 1
            self._fresh_in[self.group[k]] += 1
        self.taken += 1
        if seq >= 0 and self.on_inbound is not None:
            self.on_inbound(self.sysids[k], compid, seq, _LPN_ID)
        return True

    def message_seen(self, k: int, msg: Message) -> None:
        """Row ``k``'s protocol handled ``msg``, a HEARTBEAT or a status
        message, in FLYING and is still FLYING (``VehicleProtocol``): the same
        message again would change nothing there but the time the vehicle was
        heard (``unchanged``)."""
        seen, key = self._seen[k], seen_key(msg)
        if seen is not None and key is not None:
            seen[key[0]] = key[1]

    def unchanged(self, k: int, compid: int, seq: int, msgid: int, values: tuple[int, ...],
                  now: float) -> bool:  # fmt: skip
        """Take one HEARTBEAT (``msgid`` 0, ``values`` its payload in wire
        order: ``codec.RawHeartbeat``) or status message (``codec.RawStatus``)
        of row ``k``'s vehicle handled at ``now`` [s] if it is the one of its
        kind the protocol last handled in FLYING: then only the time it was
        heard moves (``heard_s`` for a HEARTBEAT, ``said_s``), which is all
        the protocol would change (in FLYING its HEARTBEAT rules keep it
        flying and queue nothing, and a status message only sets the health
        field it carries). False (the caller hands it to the protocol):
        another one, a row not attached, or one whose protocol has something
        queued (``attention``: the protocol is serviced after its next
        message, as before). ``seq``: the frame's sequence number, for
        ``on_inbound``."""
        times = self.recognised(k, compid, msgid, values)
        if times is None:
            return False
        times[k] = now
        if self.on_inbound is not None:
            self.on_inbound(self.sysids[k], compid, seq, msgid)
        return True

    def recognised(
        self, k: int, compid: int, msgid: int, values: tuple[int, ...]
    ) -> list[float] | None:
        """``unchanged``'s test, changing nothing: the column whose row ``k``
        it would set to ``now`` (``heard_s`` or ``said_s``), or None when it
        would return False."""
        seen = self._seen[k]
        if seen is None:
            return None
        if msgid == _HB_ID:
            last, times = seen.get(Heartbeat), self.heard_s
            values = values[:5]  # not mavlink_version, which Heartbeat does not hold
        else:
            last, times = seen.get(_STATUS_TYPE[msgid]), self.said_s
        if last != (compid, *values) or (self.attention and self.sysids[k] in self.attention):
            return None
        return times

    def take_fresh(self, groups: Collection[int] | None = None) -> dict[int, int]:
        """The fresh rows as {sysid: time_boot_ms}, and none fresh after;
        with ``groups``, only those groups' rows (the others stay fresh)."""
        if not self.fresh_count:
            return {}
        sysids, ms, flags = self.sysids, self._ms, self.fresh
        rows = self._fresh_rows
        if groups is not None:
            group = self.group
            rows = []
            rest: list[int] = []
            for k in self._fresh_rows:
                (rows if group[k] in groups else rest).append(k)
            self._fresh_rows = rest
        rows.sort()  # in row order, as the column was read
        fresh = {sysids[k]: ms[k] for k in rows}
        for k in rows:
            flags[k] = False
        if groups is None:
            rows.clear()
            self.fresh_count = 0
            self._fresh_in = [0] * len(self._fresh_in)
        else:
            self.fresh_count -= len(rows)
            for g in groups:
                self._fresh_in[g] = 0
        return fresh

    def take_complete(self) -> dict[int, int]:
        """``take_fresh`` of the groups whose every attached row is fresh
        (``complete_groups``); {} when there is none."""
        groups = self.complete_groups()
        return self.take_fresh(set(groups)) if groups else {}

    def complete_groups(self) -> list[int]:
        """The groups whose every attached row is fresh (at least one attached)."""
        return [g for g, (a, f) in enumerate(zip(self._attached_in, self._fresh_in, strict=True))
                if a and f >= a]  # fmt: skip

    # ------------------------------------------------------- control step
    def slots(self, sysids: Sequence[int]) -> npt.NDArray[np.intp]:
        """The rows of ``sysids``, in that order."""
        slot = self.slot
        return np.array([slot[s] for s in sysids], dtype=np.intp)

    def mission_states(self, ks: npt.NDArray[np.intp]) -> tuple[FloatArray, FloatArray]:
        """Positions [m] and velocities [m/s] ``(N, 3)`` in the mission frame
        of rows ``ks``: p = (e, n, -d) + offset, v = (v_e, v_n, -v_d) less
        the velocity bias (formation-law.md s1, docs/velocity-bias.md), the
        numbers ``VehicleProtocol.state_mission`` gives. ``RuntimeError`` if
        one has no report or origin."""
        n = len(ks)
        if n == 0:
            return np.zeros((0, 3)), np.zeros((0, 3))
        if self._pending:
            self._observe_pending()
        if self._incomplete:
            for k in ks.tolist():
                if k in self._incomplete:
                    raise RuntimeError(f"vehicle {self.sysids[k]} has no position or origin yet")
        # One array op each for all six columns. Bit for bit the column-wise
        # reading: -d + o is (d * -1) + o; b_d - v_d is (v_d * -1) + b_d (a sum
        # commutes, signed zeros included); v_e - b_e is v_e + (-b_e).
        state = self.rows["ned"].take(ks, axis=0).take(_STATE_COLS, axis=1).astype(np.float64)
        state *= _STATE_SIGN
        state += self._adjust[ks]
        return state[:, :3], state[:, 3:]

    def answer(self, ks: npt.NDArray[np.intp], accel_mps2: FloatArray) -> FloatArray:
        """The NED accelerations [m/s^2] ``(K, 3)`` sent to rows ``ks`` for
        mission-frame ``accel_mps2`` (``clip_accel_ned``, as
        ``VehicleProtocol.accel_setpoint``): kept in ``accel_ned``, a clipped
        row counted in its protocol's ``clipped_setpoints``."""
        ned = unclipped_ned_small(accel_mps2) if len(ks) < SMALL_ROWS else None
        if ned is not None:  # nothing to clip: the same rows as clip_accel_ned's
            self.accel_ned[ks] = ned
            return ned
        ned, clipped = clip_accel_ned(accel_mps2)
        if clipped.any():
            for j in np.flatnonzero(clipped).tolist():
                vp = self.owners[int(ks[j])]
                if vp is not None:
                    vp.clipped_setpoints += 1
        self.accel_ned[ks] = ned
        return ned
