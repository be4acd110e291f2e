"""One control step of the swarm without I/O: the law over the flying
vehicles' fresh reports, and each link's setpoints (``SwarmCore.control_step``
calls ``run_step`` once the events of the step's time have run).

The path (docs/architecture.md, "From a datagram to a setpoint", steps 4-5):
the mission-frame states read from the telemetry table
(``TelemetryTable.mission_states``), the delay compensator's prediction when
there is one, ``ControlLoop.command`` (the leader, the law, the safety
filter, the shaper), the checks that end a mission as failed, then the
setpoints: mission frame -> NED (``TelemetryTable.answer``), Eq. V1 for
velocity-tracked vehicles
(docs/setpoints.md), written link by link before the bookkeeping, so that
a setpoint's latency does not include it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from gcs_swarm.errors import SwarmError
from gcs_swarm.mavlink.states import INCOMING_PHASES, Phase
from gcs_swarm.swarm.departures import describe, live_columns

if TYPE_CHECKING:
    from gcs_swarm.control.law import ControlOutput
    from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult
    from gcs_swarm.control.loop import ControlLoop
    from gcs_swarm.control.safety_stats import SafetyReport
    from gcs_swarm.mavlink.telemetry_table import TelemetryTable
    from gcs_swarm.report.record import FlightRecorder
    from gcs_swarm.swarm.core import SwarmCore

__all__ = [
    "LEADER_BOUND",
    "READYING",
    "Commanding",
    "FlyingOrder",
    "SetpointBatch",
    "Write",
    "answer",
    "command",
    "flying_states",
    "resolve_lookahead",
    "run_step",
    "send_rejoiners",
]

FloatArray = npt.NDArray[np.float64]

READYING = INCOMING_PHASES
"""The phases of a vehicle on its way into the formation (``mavlink.states``)."""

LEADER_BOUND = 1.0e7
"""Largest leader coordinate [m] or velocity component [m/s] taken as finite:
beyond the Earth's size the mission's flat local frame means nothing, and
the law's squares of such numbers overflow."""


class SetpointBatch(NamedTuple):
    """One step's setpoints for one link (``Link.send_accel_setpoints``'s
    arguments): row k to vehicle ``sysids[k]``, NED."""

    sysids: list[int]
    compids: list[int]
    time_boot_ms: list[int]
    accel_ned: FloatArray
    since_s: list[float | None]
    vel_ned: FloatArray | None


Write = Callable[[str, SetpointBatch | None], None]
"""Called by ``control_step`` for each link, in the mission's order, before
the step's bookkeeping: its setpoints, or None (write what is queued)."""


class FlyingOrder:
    """The flying vehicles in key order (also as ``keys``, the read-only int32
    array a link shard's state batches carry), their telemetry rows and each
    one's index in that order: a step reads them every time (six times a
    period with a step per network), and they change only on a join or a
    leave."""

    __slots__ = ("_of", "ids", "index", "keys", "ks")

    def __init__(self) -> None:
        self._of: frozenset[int] = frozenset()
        self.ids: tuple[int, ...] = ()
        self.keys: npt.NDArray[np.int32] = np.zeros(0, dtype=np.int32)
        self.ks: npt.NDArray[np.intp] = np.zeros(0, dtype=np.intp)
        self.index: dict[int, int] = {}

    def update(self, flying: set[int], table: TelemetryTable) -> None:
        """Follow ``flying`` (a set compare when it did not change)."""
        if flying != self._of:
            self._of = frozenset(flying)
            self.ids = tuple(sorted(flying))
            self.keys = np.array(self.ids, dtype=np.int32)
            self.keys.flags.writeable = False  # shared by every batch of these vehicles
            self.ks = table.slots(self.ids)
            self.index = {s: i for i, s in enumerate(self.ids)}


def run_step(core: SwarmCore, fresh: dict[int, int], t: float, now: float, write: Write) -> None:
    """The law at mission time ``t`` [s] (wall ``now`` [s]) over ``core``'s
    flying vehicles, answering those in ``fresh`` (sysid -> report time)."""
    order = core.order
    order.update(core.flying, core.table)
    ids = order.ids
    if ids:
        # The members keep out of those that left but fly on, heard (Eq. K1).
        live = live_columns(core, now)
        sep = core.control.config.safety.separation
        for key in sorted(live.keys() - core.control.live_keep_out.keys()):
            core.note(describe(core.labels[key], live[key], sep, heard=True))
        core.control.set_live_keep_out(live)
        ks, pos, vel = flying_states(core, ids, now, order.ks)
        index = order.index
        fresh_rows = np.sort(np.fromiter((index[s] for s in fresh if s in index), dtype=np.int64))
        rows = None if len(fresh_rows) == len(ids) else fresh_rows  # None: every one
        # A step of one network's reports commands its rows only (section 3b);
        # the whole-swarm step computes everyone's and answers the fresh ones.
        some = rows if core.config.step_per_network else None
        commanded = command(core, ids, pos, vel, t, fresh.keys(), some)
        if commanded is None:
            return
        out, accel, report = commanded
        if rows is None:  # every one: no copies
            answer(core, ids, ks, accel, now, t, vel, write)
        else:  # one answer each
            picked = accel if some is not None else accel[rows]
            answer(core, [ids[i] for i in rows], ks[rows], picked, now, t, vel[rows], write)
        core.control.account(ids, pos, out, accel, report)
        job = core.control.pending_lookahead()
        if job is not None:
            core.lookahead.append(job)
    send_rejoiners(core)
    if t >= core.config.duration_s:
        core.note(f"mission time {t:.2f} s reached the duration")
        core.finished = True


def send_rejoiners(
    core: SwarmCore,
    leader_m: FloatArray | None = None,
    leader_vel: FloatArray | None = None,
    radius_m: float | None = None,
) -> None:
    """Members that flew and are being readied again (lost and heard again,
    or joining again after a leave) fly to their rejoin point beside the
    leader, which moves on meanwhile: outside the formation on the ray
    through their slot (``ControlLoop.rejoin_m``), at the leader's velocity,
    given as the setpoint's feed-forward and matched before the vehicle is
    READY (``VehicleProtocol.set_goto``), so it rejoins a moving formation;
    a leader at rest gives a point at rest. ``leader_m`` [m], ``leader_vel``
    [m/s], ``radius_m`` [m] (the farthest member from the leader): the
    controller's, when this core does not run the law (a link shard, from
    the controller's beats)."""
    if core.members <= core.flying:  # the usual case, without two new sets a step
        return
    rejoining = (core.members & core.flown) - core.flying
    if not rejoining:
        return
    if leader_m is None:
        leader_vel = core.control.controller.leader_vel_mps
    moving = leader_vel is not None and bool(np.any(leader_vel != 0.0))
    for sysid in rejoining:
        vp = core.vehicles[sysid]
        if vp.phase in READYING and vp.phase is not Phase.READY:
            point = core.control.rejoin_m(core.plans[sysid].start_m, leader_m, radius_m)
            vp.set_goto(point, leader_vel if moving else None)


class Commanding(Protocol):
    """What ``command`` needs of a core: the one-process ``SwarmCore`` and a
    sharded run's ``ControllerCore`` both are."""

    control: ControlLoop
    recorder: FlightRecorder | None

    def abort(self, why: str) -> None: ...

    def note(self, text: str, *, level: int = ...) -> None: ...


def command(
    core: Commanding,
    ids: Sequence[int],
    pos: FloatArray,
    vel: FloatArray,
    t: float,
    sent: Iterable[int],
    rows: npt.NDArray[np.int64] | None = None,
) -> tuple[ControlOutput, FloatArray, SafetyReport | None] | None:
    """The law's command for ``ids`` at their mission-frame states
    (``ControlLoop.command``: the leader, the law, the safety filter, the
    shaper) at mission time ``t`` [s], with the checks that end a mission as
    failed (``core.abort``; then None and nothing goes out); the avoidance
    episodes noted; the step given to the flight recorder, ``sent`` the
    vehicles that get a setpoint, before the setpoints go out (the log's
    LEADER note marks the step). ``rows``: only those of ``ids`` are
    commanded (``ControlLoop.command``), the accelerations are theirs."""
    try:
        # Overflow is judged below, on the leader (and counted, on the setpoints).
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            out, accel, report = core.control.command(ids, pos, vel, rows)
    except (SwarmError, ArithmeticError, ValueError) as err:
        core.abort(f"t={t:.2f} s: the law failed in flight: {err}")
        return None
    lead = (out.leader_pos_m.tolist(), out.leader_vel_mps.tolist())
    b = LEADER_BOUND
    if not all(-b <= x <= b for x in lead[0] + lead[1]):  # NaN fails too
        core.abort(f"t={t:.2f} s: the virtual leader's state is not finite (position "
                   f"{lead[0]} m, velocity {lead[1]} m/s)")  # fmt: skip
        return None
    if out.event is not None:
        what = "starts" if out.event == "start" else "ends: formation resumes"
        core.note(f"t={t:.2f} s: avoidance episode {out.episode} {what}")
    if core.recorder is not None:
        cor = None if report is None else report.correction_mps2
        acc = accel
        if rows is not None:  # the record's rows are every vehicle's: the rows' filled
            acc = np.zeros((len(ids), 3))
            acc[rows] = accel
            if cor is not None:
                full = np.full(len(ids), np.nan)
                full[rows] = cor
                cor = full
        core.recorder.step(t, ids, pos.copy(), out.leader_pos_m, out.behaviour,
                           out.episode, accel_mps2=acc, sent=sent,
                           correction_mps2=cor)  # fmt: skip
    return out, accel, report


def flying_states(
    core: SwarmCore, ids: Sequence[int], now: float, ks: npt.NDArray[np.intp] | None = None
) -> tuple[npt.NDArray[np.intp], FloatArray, FloatArray]:
    """The table rows of ``ids`` and their mission-frame states ``(K, 3)``
    (position [m], velocity [m/s]) as the law reads them at wall ``now`` [s]:
    predicted over the commands in flight when there is a delay compensator.
    ``ks``: the rows of ``ids`` when known (``FlyingOrder``)."""
    table = core.table
    if ks is None:
        ks = table.slots(ids)
    pos, vel = table.mission_states(ks)
    if core.delay is not None:
        for i, s in enumerate(ids):
            k = int(ks[i])
            if table.position(k) is not None:
                t_s = table.boot_ms(k) * 1e-3
                pos[i], vel[i] = core.delay.predict(s, t_s, now, pos[i], vel[i])
    return ks, pos, vel


def answer(
    core: SwarmCore,
    sysids: Sequence[int],
    ks: npt.NDArray[np.intp],
    accel: FloatArray,
    now: float,
    t: float,
    vel: FloatArray,
    write: Write,
) -> None:
    """One acceleration setpoint (mission frame ``accel (K, 3)``) for each
    of ``sysids`` (rows ``ks`` of the telemetry table), each link's at once.
    A velocity-tracked vehicle's goes with its velocity setpoint (Eq. V1,
    from ``vel``, the velocity the law saw, at mission time ``t``)."""
    table = core.table
    ned = table.answer(ks, accel)
    vel_ned: FloatArray | None = None
    tracked = []
    if core.velocity_tracked:
        tracked = [k for k, s in enumerate(sysids) if s in core.velocity_tracked]
    if tracked:
        # What was sent (the NED rows, clipped) back in the mission frame: V1 integrates it.
        sent = np.stack([ned[tracked, 1], ned[tracked, 0], -ned[tracked, 2]], axis=1)
        ref = core.reference.setpoints([sysids[k] for k in tracked], t, vel[tracked], sent)
        vel_ned = np.full((len(sysids), 3), np.nan)
        bias = table.bias_ned[ks[tracked]]
        # The vehicle flies its own (biased) velocity estimate to the setpoint.
        vel_ned[tracked, 0] = ref[:, 1] + bias[:, 0]
        vel_ned[tracked, 1] = ref[:, 0] + bias[:, 1]
        vel_ned[tracked, 2] = -ref[:, 2] + bias[:, 2]
    rows: dict[str, list[int]] = {}
    if len(core.links) == 1:  # one link: every vehicle's (core.link_of)
        rows[core.links[0]] = list(range(len(sysids)))
    else:
        link_of = core.link_of
        for k, sysid in enumerate(sysids):
            rows.setdefault(link_of[sysid], []).append(k)
    vehicles = core.vehicles
    boot_ms = table.boot_ms_of(ks)
    arrival = table.arrival_s[ks].tolist()
    for link in core.links:
        idx = rows.get(link)
        if idx is None:
            write(link, None)
            continue
        whole = len(idx) == len(sysids)
        write(
            link,
            SetpointBatch(
                [sysids[k] for k in idx],
                [vehicles[sysids[k]].compid for k in idx],
                boot_ms if whole else [boot_ms[k] for k in idx],
                ned if whole else ned[idx],
                arrival if whole else [arrival[k] for k in idx],
                vel_ned if vel_ned is None or whole else vel_ned[idx],
            ),
        )
    if core.delay is not None:
        for k, sysid in enumerate(sysids):
            core.delay.sent(sysid, now, accel[k])


def resolve_lookahead(
    control: ControlLoop, job: LookaheadJob, result: LookaheadResult, took_s: float
) -> str:
    """Apply a plane look-ahead's ``result``, computed off the step in
    ``took_s`` [s] (in a worker thread: ``runtime.worker``); the note that
    says what it chose."""
    control.resolve_lookahead(job, result)
    n_vertical = int(result.vertical.sum())
    return (
        f"look-ahead for episode {job.episode}: vertical plane for {n_vertical} of "
        f"{len(result.ids)} vehicles ({1e3 * took_s:.0f} ms in a worker thread)"
    )
