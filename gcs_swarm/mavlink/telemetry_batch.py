"""The telemetry table's writes of many reports at once (``TelemetryTable.write_many``),
for a link that takes many datagrams of one peer at a time
(``LinkState.receive_batch``): the checks of ``TelemetryTable.write`` on
every report first, then the writes, with the rows' columns as arrays
where they are arrays. The state it leaves is the state ``write`` of each
in turn leaves (tests/swarm/test_receive_batch.py). No I/O.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from gcs_swarm.mavlink.inbound import POSITION_LIMIT_M, SPEED_LIMIT_MPS

if TYPE_CHECKING:
    from gcs_swarm.mavlink.vehicle import VehicleProtocol

__all__ = ["RATE_WINDOW_MS", "REBOOT_MS"]

RATE_WINDOW_MS = 2000
"""Telemetry-rate window [ms of the vehicle's own time_boot_ms] (issue 15)."""
REBOOT_MS = 10_000
"""Telemetry older than the last by more than this is a reboot, not a reorder."""


_LIMITS = np.array([POSITION_LIMIT_M] * 3 + [SPEED_LIMIT_MPS] * 3)
"""``inbound.plausible``'s bounds of x, y, z [m] and vx, vy, vz [m/s]."""


class _TableBatch:
    """``TelemetryTable``'s ``write_many``, over the columns it declares
    (the table's, made in its ``__init__``)."""

    owners: list[VehicleProtocol | None]
    rows: npt.NDArray[Any]
    arrival_s: npt.NDArray[np.float64]
    fresh: list[bool]
    seen_s: list[float]
    group: list[int]
    fresh_count: int
    taken: int
    attention: list[int]
    _ms: list[int]
    _compid: list[int]
    _pend: list[bool]
    _pending: list[int]
    _fresh_rows: list[int]
    _fresh_in: list[int]
    _attached_in: list[int]
    _rate_t0: list[int | None]
    _rate_n: list[int]
    _incomplete: set[int]

    def _observe_pending(self) -> None:
        raise NotImplementedError  # TelemetryTable's

    @property
    def any_attached(self) -> bool:
        """Whether any row takes reports (its vehicle FLYING): until one
        does, ``write_many`` has nowhere to write and a batch is not tried."""
        return any(self._attached_in)

    def write_many(
        self,
        ks: Sequence[int],
        compids: Sequence[int],
        payload: npt.NDArray[Any],
        now: float,
        rx_s: float,
        quiet: Collection[int] = (),
    ) -> bool:
        """``write`` of report j into row ``ks[j]`` for every j, at once,
        when every one of them would be taken: rows ``ks`` distinct, each
        attached and with its origin, each report plausible and newer than
        the row's last; and no row of ``quiet`` ends its telemetry-rate
        window at a rate that queues something (``VehicleProtocol.rate_window_queues``:
        a caller that hands the same vehicles' other messages to
        ``recognised`` before these reports). Then the state ``write`` of
        each in turn leaves (``payload (B,)`` of ``raw_frames.LPN_PAYLOAD``:
        the payloads' very bytes go into the rows) and True; else False with
        nothing changed (the caller writes them one by one). The caller
        tells ``on_inbound`` (``write`` does it for its one)."""
        owners, pend, last_ms = self.owners, self._pend, self._ms
        ms = payload["time_boot_ms"].tolist()
        if len(set(ks)) < len(ks):
            return False
        rate_t0 = self._rate_t0
        first = len(ms)  # the first row whose last report is still pending
        for j, (k, m) in enumerate(zip(ks, ms, strict=True)):
            if owners[k] is None or 0 <= last_ms[k] - m < REBOOT_MS:
                return False
            if pend[k] and first == len(ms):
                first = j
        if self._incomplete and not self._incomplete.isdisjoint(ks):
            return False
        # inbound.plausible, column-wise: the float32s as doubles (the scalar
        # path's floats), so NaN and inf fail as the chained comparisons do.
        if not (np.abs(payload["ned"].astype(np.float64)) <= _LIMITS).all():
            return False
        if quiet:
            slot = dict(zip(ks, ms, strict=True))
            for k in quiet:
                m, t0 = slot.get(k), rate_t0[k]
                if m is not None and t0 is not None and m - t0 >= RATE_WINDOW_MS:  # m >= t0
                    vp = owners[k]
                    assert vp is not None
                    if vp.rate_window_queues(self._window_rate(k, m, t0)):
                        return False
        # write's rule: at a row whose last report is still pending, every
        # pending one is observed first (those written before it included).
        self._put(ks[:first], ms[:first], compids[:first], payload[:first], now, rx_s)
        if first < len(ms):
            self._observe_pending()
            self._put(ks[first:], ms[first:], compids[first:], payload[first:], now, rx_s)
        return True

    def _window_rate(self, k: int, m: int, t0: int) -> float:
        """Row ``k``'s telemetry rate [Hz] over its rate window from ``t0`` to
        the report at ``m`` [ms of vehicle time], that report counted."""
        return (self._rate_n[k] + 1) / ((m - t0) * 1e-3)

    def _end_window(self, k: int, m: int, t0: int) -> None:
        """Row ``k``'s rate window (from ``t0``) ends at its report at ``m``
        [ms]: the next starts there, and the protocol judges the rate
        (``VehicleProtocol.rate_window``); one that queued something waits in
        ``attention`` for its owner. ``write`` and ``write_many`` both end
        windows here."""
        rate = self._window_rate(k, m, t0)
        self._rate_t0[k], self._rate_n[k] = m, 0
        vp = self.owners[k]
        assert vp is not None
        if vp.rate_window(rate):
            self.attention.append(vp.sysid)

    def _put(self, ks: Sequence[int], ms: list[int], compids: Sequence[int],
             payload: npt.NDArray[Any], now: float, rx_s: float) -> None:  # fmt: skip
        """``write_many``'s writes (its checks passed), none of rows ``ks``
        pending: ``write``'s, its rate window's count and fresh flag written
        out again for many rows (tests/swarm/test_receive_batch.py holds the
        two to the same state)."""
        if not ks:
            return
        pend, last_ms = self._pend, self._ms
        self.rows[ks] = payload
        self.arrival_s[ks] = rx_s
        self._pending.extend(ks)
        compid_of, seen, fresh, group = self._compid, self.seen_s, self.fresh, self.group
        rate_t0, rate_n, fresh_in = self._rate_t0, self._rate_n, self._fresh_in
        new = 0
        for k, m, c in zip(ks, ms, compids, strict=True):
            pend[k] = True
            last_ms[k] = m
            compid_of[k] = c
            seen[k] = now
            t0 = rate_t0[k]  # write's rate window
            if t0 is None or m < t0:
                rate_t0[k], rate_n[k] = m, 0
            elif m - t0 < RATE_WINDOW_MS:
                rate_n[k] += 1
            else:
                self._end_window(k, m, t0)
            if not fresh[k]:
                fresh[k] = True
                self._fresh_rows.append(k)
                fresh_in[group[k]] += 1
                new += 1
        self.fresh_count += new
        self.taken += len(ms)
