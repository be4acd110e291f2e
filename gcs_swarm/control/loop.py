"""One control step of the station: vehicle time, the law, the limits.

``ControlLoop`` holds the ``SwarmController`` (Eqs. 12-13 and 27-30 from
``gcs_swarm.control.law``) and the ``SafetyFilter`` (limits and safety of
formation-law.md section 11), and keeps the mission clock in VEHICLE time:
at each step it advances by the median of the fresh vehicles' increments of
``time_boot_ms`` (formation-law.md section 4: the leader is integrated in the
time the telemetry carries, so lockstep and speed-up fly like real time).
Positions and velocities come in and accelerations go out in the mission
frame; the NED edge is ``gcs_swarm.mavlink``. No asyncio here; the look-ahead
job is handed to the caller to run in a worker thread.

Vehicle envelope (docs/vehicle-envelope.md): the command path is law ->
safety filter (planning within the envelope from each vehicle's last
command) -> ``CommandShaper`` (|a_xy| <= accel_xy, |a_z| <= accel_z, and the
jerk per step), so what is sent is what the vehicle will do. The envelope
is the mission's ``limits.envelope`` until ``set_envelope`` (the station,
after reading the vehicles' parameters at start-up) tightens it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.cutoff import DENSE_SHARE, neighbour_pairs
from gcs_swarm.control.envelope import CommandShaper
from gcs_swarm.control.formation_rows import SMALL_N
from gcs_swarm.control.law import ControlOutput, SwarmController
from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult
from gcs_swarm.control.obstacles import box_signed_distance
from gcs_swarm.control.params import Box, Envelope, LawConfig
from gcs_swarm.control.safety import SafetyFilter, SafetyReport, SafetyStats, filter_acts

__all__ = ["ControlLoop", "StepResult"]

FloatArray = npt.NDArray[np.float64]

MAX_CLOCK_JUMP_S = 1.0
"""Largest mission-clock advance of one step [s]: a vehicle reboot or a long
telemetry gap must not fling the virtual leader ahead."""


@dataclass(frozen=True)
class StepResult:
    """One step: the input positions ``pos_m (N, 3)`` and ``accel_mps2 (N, 3)``
    after limits/safety, in ``ids`` order, mission frame; the law's raw output;
    the filter's report (None when the filter is the identity); radii [m] to
    the leader and the minimum pairwise separation [m] at the input state."""

    t_s: float
    ids: tuple[int, ...]
    pos_m: FloatArray
    accel_mps2: FloatArray
    law: ControlOutput
    safety: SafetyReport | None
    radii_m: FloatArray
    min_separation_m: float


_JUMP_MS = round(MAX_CLOCK_JUMP_S * 1000)


class ControlLoop:
    """The law plus limits, stepped on telemetry in vehicle time."""

    def __init__(
        self, law: LawConfig, charges: Mapping[int, float], rate_hz: float, *, defer: bool = True
    ) -> None:
        self.config = law
        self.charges = dict(charges)
        self.controller = SwarmController(law, t0=0.0, defer_lookahead=defer)
        self.rate_hz = rate_hz
        self.envelope: Envelope = law.limits.envelope
        """The vehicle envelope the commands are planned and shaped within."""
        self.safety = SafetyFilter(law.limits, law.safety, law.obstacles, dt=1.0 / rate_hz)
        self.shaper = CommandShaper(self.envelope, 1.0 / rate_hz)
        self.safety_stats = SafetyStats()
        # A disabled filter with no finite limit is the identity (safety.py): skip it.
        self.filtering: bool = filter_acts(law.limits, law.safety)
        self.t_s = 0.0
        self.steps = 0
        self.min_separation_m = math.inf
        self.peak_accel_mps2 = 0.0
        """Largest commanded |a| [m/s^2] (after limits) of any step so far."""
        self.min_clearance_m = math.inf
        """Smallest signed distance [m] of any vehicle to any box seen at a
        step (negative: inside; the paper's Eq. 27 can cut corners, s11)."""
        self.keep_out: dict[int, Box] = {}
        """Keep-out columns of vehicles that left unheard, by key (``keep_out_of``)."""
        self.live_keep_out: dict[int, Box] = {}
        """Columns of vehicles out of the formation that are still heard, in
        the air, at their latest reports (``set_live_keep_out``, every step)."""
        self._kept: set[int] = set()
        self.min_keep_out_m = math.inf
        """Smallest signed distance [m] of any member to a keep-out column at a
        step (the filter keeps ``safety.separation``)."""
        self._boot_ms: dict[int, int] = {}
        """Each vehicle's last time_boot_ms."""
        self._offset_ms: dict[int, int] = {}
        """time_boot_ms - mission time [ms], per vehicle (``advance_clock``)."""
        self._t_ms = 0
        """The mission clock in whole ms (vehicle time's resolution)."""
        self.last: StepResult | None = None
        self._q_ids: tuple[int, ...] | None = None
        self._q = np.zeros(0)
        """The charges of the vehicles ``_q_ids``, in that order (``command``)."""
        self._rows_since = 0
        """Rows stepped since the separation was last taken (``account``)."""

    def advance_clock(self, boot_ms: Mapping[int, int]) -> float:
        """Advance the mission clock to the fresh vehicles' ``time_boot_ms``.

        Each vehicle's boot clock maps to mission time by an offset [ms] fixed
        when it is first seen (new, returning after ``forget``, or rebooted:
        time going back); it then adds nothing. The clock moves to the median
        (low) of the fresh vehicles' mapped times, never back; a vehicle whose
        clock leaps ahead by more than ``MAX_CLOCK_JUMP_S`` since its last
        report counts only that much. Steps that see different subsets of the
        vehicles (late or reordered telemetry) therefore cannot push the
        clock past vehicle time, which summing per-step increments did.
        Returns the mission time [s].
        """
        jump_ms = _JUMP_MS
        mapped = []
        seen, offset, t_ms = self._boot_ms, self._offset_ms, self._t_ms
        get = seen.get
        for sysid, ms in boot_ms.items():
            last = get(sysid)
            seen[sysid] = ms
            if last is None or ms < last:
                offset[sysid] = ms - t_ms
                continue
            if ms - last > jump_ms:
                offset[sysid] += ms - last - jump_ms
            mapped.append(ms - offset[sysid])
        if mapped:
            mapped.sort()  # statistics.median_low, without its copy and checks
            self._t_ms = max(t_ms, mapped[(len(mapped) - 1) // 2])
            self.t_s = self._t_ms * 1e-3
        return self.t_s

    def set_envelope(self, envelope: Envelope) -> Envelope:
        """Plan and shape within ``envelope`` from now on: the tightest over
        the vehicles, as read from their parameters at start-up; it is
        tightened with the mission's ``limits.envelope`` (``Envelope.tighter``).
        Call before the formation starts (the filter and shaper restart).
        Returns the envelope in force."""
        env = envelope.tighter(self.config.limits.envelope)
        self.envelope = env
        limits = replace(self.config.limits, envelope=env)
        law = self.config
        self.safety = SafetyFilter(limits, law.safety, law.obstacles, dt=1.0 / self.rate_hz)
        self.shaper = CommandShaper(env, 1.0 / self.rate_hz)
        self._apply_keep_out()
        return env

    def keep_out_of(self, key: int, box: Box) -> None:
        """Vehicle ``key`` left unheard: the members keep the safety separation
        from ``box`` (Eq. K1, ``keep_out.lost_column``) until ``release``."""
        self.keep_out[key] = box
        self._apply_keep_out()

    def release(self, key: int) -> bool:
        """Vehicle ``key``'s keep-out ends (it is heard again); False if it had none."""
        if self.keep_out.pop(key, None) is None:
            return False
        self._apply_keep_out()
        return True

    def set_live_keep_out(self, boxes: Mapping[int, Box]) -> None:
        """The columns of vehicles out of the formation but heard and in the
        air, by key, from this step on (replacing the last step's)."""
        if not boxes and not self.live_keep_out:
            return  # the usual case: nothing to rebuild
        self.live_keep_out = dict(boxes)
        self._apply_keep_out()

    @property
    def keep_outs_taken(self) -> int:
        """Vehicles whose box the members have kept out of so far."""
        return len(self._kept)

    def _apply_keep_out(self) -> None:
        kept = {**self.live_keep_out, **self.keep_out}
        self._kept |= kept.keys()
        self.safety.set_keep_out(tuple(kept.values()))

    def forget(self, sysid: int) -> None:
        """A vehicle left: its next telemetry maps its clock afresh, and its
        next command starts from hover (``CommandShaper.forget``)."""
        self._boot_ms.pop(sysid, None)
        self.shaper.forget(sysid)

    def step(self, ids: Sequence[int], pos_m: FloatArray, vel_mps: FloatArray) -> StepResult:
        """The limited accelerations for ``ids`` at their mission-frame states:
        ``command`` then ``account``."""
        out, accel, report = self.command(ids, pos_m, vel_mps)
        return self.account(ids, pos_m, out, accel, report)

    def command(
        self,
        ids: Sequence[int],
        pos_m: FloatArray,
        vel_mps: FloatArray,
        rows: npt.NDArray[np.int64] | None = None,
    ) -> tuple[ControlOutput, FloatArray, SafetyReport | None]:
        """What goes out this step: the law's output, the accelerations after
        limits/safety (N, 3), and the filter's report (None when it is the
        identity). The station sends these before ``account``'s bookkeeping.

        ``rows`` (indices into ``ids``): a step that answers only those
        vehicles, each against every vehicle's state (docs/formation-law.md
        section 3b): the accelerations and the report are theirs, ``(R, 3)``
        and R long. The filter's answer for one vehicle depends on the states,
        its own desired command and every vehicle's last command sent, not on
        the others' desired commands (safety.py: a pair's work is split in
        halves), so the whole swarm is filtered with zeros for the others and
        the rows kept: exact, at the whole filter's cost. The last commands
        are the latest sent, this period's for the vehicles stepped before."""
        key = tuple(ids)
        # the same vehicles every step but a join or a leave (mostly the same tuple)
        if self._q_ids is not key and self._q_ids != key:
            self._q = np.array([self.charges[i] for i in key], dtype=np.float64)
            self._q_ids = key
        q = self._q
        out = self.controller.step(self.t_s, ids, pos_m, vel_mps, q, rows)
        accel, report = out.accel_mps2, None
        if self.filtering:
            prev = self.shaper.previous(ids) if self.shaper.active else None
            a_des = accel
            if rows is not None:
                a_des = np.zeros((len(key), 3))
                a_des[rows] = accel
            accel, report = self.safety.filter(pos_m, vel_mps, a_des, ids=ids, prev_accel_mps2=prev)
            if rows is not None:
                accel = accel[rows]
                report = SafetyReport(*(getattr(report, f.name)[rows] for f in fields(report)))
            self.safety_stats.update(report)
        sent = key if rows is None else [key[i] for i in rows.tolist()]
        return out, self.shaper.shape(sent, accel), report

    def account(
        self,
        ids: Sequence[int],
        pos_m: FloatArray,
        out: ControlOutput,
        accel: FloatArray,
        report: SafetyReport | None,
    ) -> StepResult:
        """The step's figures (radii, separation, peak |a|, clearance), kept as
        ``last`` and in the running extremes; counts the step.

        Steps of some rows (``out.rows``, ``command``) take the peak and the
        clearance of their rows, and the separation once as many rows as
        vehicles have been stepped since it was last taken (about once a
        period: the whole swarm's at that step's states, not six times a
        period at 1,500 vehicles on six networks; from the cut-off's
        neighbour list when it holds it); ``last`` holds every
        vehicle's latest command (the rows' from this step) and the
        separation last taken."""
        rows = out.rows
        radii = np.linalg.norm(pos_m - out.leader_pos_m, axis=1)
        if rows is None:
            sep = _min_separation(pos_m)
        else:
            self._rows_since += len(rows)
            sep = self.last.min_separation_m if self.last is not None else math.inf
            if self._rows_since >= len(ids):
                self._rows_since = 0
                near = self.controller.closest_pair_m(ids, pos_m)
                sep = _min_separation(pos_m) if near is None else near
        self.min_separation_m = min(self.min_separation_m, sep)
        if len(accel):
            peak = float(np.sqrt((accel**2).sum(axis=1)).max())
            self.peak_accel_mps2 = max(self.peak_accel_mps2, peak)
        obstacles = self.controller.obstacles
        if obstacles.count and len(accel):
            at = pos_m if rows is None else pos_m[rows]
            clearance = float(box_signed_distance(at, obstacles).min())
            self.min_clearance_m = min(self.min_clearance_m, clearance)
        if report is not None and len(accel):  # keep-out boxes act only through the filter
            self.min_keep_out_m = min(self.min_keep_out_m, float(report.min_keep_out_m.min()))
        key = tuple(ids)
        if rows is not None:
            accel = self._latest(key, rows, accel)
        self.steps += 1
        self.last = StepResult(self.t_s, key, pos_m.copy(), accel, out, report, radii, sep)
        return self.last

    def _latest(
        self, key: tuple[int, ...], rows: npt.NDArray[np.int64], accel: FloatArray
    ) -> FloatArray:
        """Every vehicle's latest command (N, 3) in ``key`` order: the rows'
        from ``accel``, the others' from ``last`` (zeros for a vehicle not
        commanded yet)."""
        last = self.last
        if last is not None and last.ids == key:
            out = last.accel_mps2.copy()
        else:
            before = {} if last is None else dict(zip(last.ids, last.accel_mps2, strict=True))
            zero = np.zeros(3)
            out = np.array([before.get(i, zero) for i in key], dtype=np.float64).reshape(-1, 3)
        out[rows] = accel
        return out

    def pending_lookahead(self) -> LookaheadJob | None:
        return self.controller.pending_lookahead()

    def resolve_lookahead(self, job: LookaheadJob, result: LookaheadResult) -> None:
        self.controller.resolve_lookahead(job, result)

    def slot_m(self, start_m: Sequence[float], leader_m: FloatArray | None = None) -> FloatArray:
        """Where a vehicle readied mid-mission should fly to [m]: its start
        position carried along with the virtual leader since the start (the
        leader at ``leader_m`` [m] when given: a link shard's, which runs no
        law, is its controller's)."""
        start = np.asarray(start_m, dtype=np.float64)
        leader0 = np.asarray(self.config.leader.start, dtype=np.float64)
        leader = self.controller.leader_pos_m if leader_m is None else leader_m
        return start - leader0 + leader

    def formation_radius_m(self) -> float:
        """The farthest member's distance [m] from the leader at the last step
        (0 before one, or with nobody flying)."""
        last = self.last
        return float(last.radii_m.max()) if last is not None and len(last.ids) else 0.0

    def rejoin_m(
        self,
        start_m: Sequence[float],
        leader_m: FloatArray | None = None,
        radius_m: float | None = None,
    ) -> FloatArray:
        """Where a vehicle readied again mid-mission flies before it rejoins
        [m]: on the ray from the leader through its slot (``slot_m``), at the
        safety separation (``Safety.separation``) beyond the farther of its
        slot and the farthest member (``radius_m``, by default
        ``formation_radius_m``; a link shard's is its controller's). Every
        member is then at least that separation from the point (triangle
        inequality), though its old slot may be taken: the others re-formed
        without it. The law pulls it in from there (docs/formation-law.md
        section 9)."""
        leader = self.controller.leader_pos_m if leader_m is None else leader_m
        leader0 = np.asarray(self.config.leader.start, dtype=np.float64)
        offset = np.asarray(start_m, dtype=np.float64) - leader0  # slot_m less the leader
        dist = float(np.linalg.norm(offset))
        ray = offset / dist if dist > 1e-9 else np.array([0.0, 0.0, 1.0])
        radius = self.formation_radius_m() if radius_m is None else radius_m
        return leader + ray * (max(dist, radius) + self.config.safety.separation)


_GRAM_FROM_N = 48
"""From this many vehicles the minimum separation is searched with one Gram
product (O(N^2) memory of floats, not N x N x 3 differences)."""

_CELLS_FROM_N = 400
"""From this many vehicles it is searched on a cell list instead (O(N log N)):
the Gram product's N x N floats grow as N^2 (best of 7 on 2026-12-03, a
jittered 3 m grid: 0.10 ms at N = 250, 0.31 at 400, 2.4 at 1000, 4.8 at
1500) where the cells take 0.21, 0.29, 1.0 and 1.1 ms; on a sphere the same
within 0.8 ms. The two cross near 400."""

_PROBES = 8
"""Vehicles whose nearest neighbour bounds the cell list's search radius."""


def _min_separation(pos_m: FloatArray) -> float:
    """Smallest pairwise distance [m] of ``pos_m (N, 3)``, inf below two vehicles.

    Small swarms: every difference directly. Large swarms: squared distances
    from one augmented Gram product of the centred positions (``[c, |c|^2, 1]``
    times ``[-2 c, 1, |c|^2]``, as the repulsion's blocks) pick the rows whose
    nearest neighbour could be the nearest pair (within the product's
    rounding bound of the smallest), then those rows' candidate pairs, whose
    distances are computed directly: the same float either way. A swarm in
    flight has one or two such rows; an exact grid (``bench_core.py``) ties
    every row, and then every tied pair is computed.
    """
    n = pos_m.shape[0]
    if n < 2:
        return math.inf
    if n < SMALL_N:  # pair by pair in floats: 15 pairs at N = 6 beat five numpy calls
        return _min_separation_floats(pos_m.tolist())
    if n >= _CELLS_FROM_N:
        sep = _min_separation_cells(pos_m)
        if sep is not None:
            return sep
    if n < _GRAM_FROM_N:
        # Every ordered pair: d_ij and d_ji are the same sums of the same squares,
        # and sqrt is monotonic, so this is the smallest of the upper triangle.
        d = pos_m[:, None, :] - pos_m[None, :, :]
        d2 = np.einsum("ijk,ijk->ij", d, d)
        np.fill_diagonal(d2, np.inf)
        return math.sqrt(float(d2.min()))
    c = pos_m - pos_m.mean(axis=0)
    sq = np.einsum("ij,ij->i", c, c)
    left = np.empty((n, 5))
    left[:, :3], left[:, 3], left[:, 4] = c, sq, 1.0
    right = np.empty((n, 5))
    right[:, :3], right[:, 3], right[:, 4] = c, 1.0, sq
    right[:, :3] *= -2.0
    d2 = left @ right.T  # |c_i|^2 + |c_j|^2 - 2 c_i . c_j
    np.fill_diagonal(d2, np.inf)
    row_min = d2.min(axis=1)
    # |error| of each entry <= ~8 eps (|c_i|^2 + |c_j|^2 + 2 |c_i| |c_j|) <= 32 eps
    # max |c|^2, twice over (the smallest entry and the true nearest pair's): keep
    # every pair that could be the true minimum.
    tol = 64.0 * np.finfo(np.float64).eps * 2.0 * float(sq.max()) + 1e-300
    limit = float(row_min.min()) + tol
    rows = np.flatnonzero(row_min <= limit)
    i, j = np.nonzero((d2 if len(rows) == n else d2[rows]) <= limit)
    diff = pos_m[rows[i]] - pos_m[j]
    return float(np.sqrt(np.einsum("ij,ij->i", diff, diff)).min())


def _min_separation_floats(pos: list[list[float]]) -> float:
    """The direct search's float for a few rows given as lists: each pair's
    squared distance summed as numpy's ``einsum`` sums three products,
    ``(x^2 + z^2) + y^2`` (the order ``formation_rows`` also relies on), so
    the minimum and its root are the same bits; NaN if a distance is NaN, as
    numpy's ``min`` gives."""
    best = math.inf
    n = len(pos)
    for a in range(n):
        xa, ya, za = pos[a]
        for b in range(a + 1, n):
            xb, yb, zb = pos[b]
            dx, dy, dz = xa - xb, ya - yb, za - zb
            r2 = (dx * dx + dz * dz) + dy * dy
            if r2 < best:
                best = r2
            elif r2 != r2:
                return math.nan
    return math.sqrt(best)


def _min_separation_cells(pos_m: FloatArray) -> float | None:
    """``_min_separation`` of a large swarm on a cell list, or None when the
    cells would test more than ``DENSE_SHARE`` of all pairs (a clump: the
    Gram product is cheaper there).

    The smallest nearest-neighbour distance of ``_PROBES`` vehicles spread
    over the rows bounds the answer from above (the nearest pair is no
    farther apart than any vehicle and its neighbour), so every pair at
    least as close as the nearest lies within that radius and
    ``cutoff.neighbour_pairs`` finds it, on cells of that side; the
    candidates' distances are then computed as the other paths compute
    them: the same float.
    """
    n = pos_m.shape[0]
    rows = np.arange(0, n, n // _PROBES)[:_PROBES]
    d = pos_m[rows][:, None, :] - pos_m[None, :, :]
    d2 = np.einsum("ijk,ijk->ij", d, d)
    d2[np.arange(len(rows)), rows] = np.inf  # not the probe itself
    bound2 = float(d2.min())
    if bound2 == 0.0:
        return 0.0  # two vehicles at the same point
    # Strictly inside the cut-off, with room for the rounding of its square.
    radius = math.sqrt(bound2) * (1.0 + 1e-6)
    pairs = neighbour_pairs(pos_m, radius, max_candidates=int(DENSE_SHARE * n * (n - 1) / 2))
    if pairs is None:
        return None
    i, j = pairs[0], pairs[1]
    diff = pos_m[i] - pos_m[j]
    return float(np.sqrt(np.einsum("ij,ij->i", diff, diff)).min())
