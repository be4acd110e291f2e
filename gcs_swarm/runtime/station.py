"""The ground station: links, vehicles, the control loop, join/leave, ending.

``Station`` is one ``async with`` lifetime owning one ``asyncio.TaskGroup``
(heartbeat, control loop, status line, look-ahead workers) and its links
(STYLE.md habit 7). It glues the I/O-free pieces together:

- each received message goes to its vehicle's ``VehicleProtocol`` (traffic
  from system ids the mission does not name is counted and ignored); the
  protocol's outbound specs go to that vehicle's link; ``next_deadline()``
  arms one ``loop.call_at`` timer per vehicle (habit 1);
- the control loop runs when every flying vehicle has sent a fresh
  LOCAL_POSITION_NED (or a fallback delay after the first one), and answers
  each fresh telemetry with exactly one setpoint: the emulator's lockstep
  rule, and a steady rate on real vehicles;
- membership: initial vehicles fly from the start; a reserve is readied with
  them (it takes off and holds at its start, its reserve point) and joins on
  its event, so that the join happens at the mission's time; a vehicle leaves
  on its event, or when its protocol reports it LOST or FAILED; the law simply
  gets the current set (formation-law.md s9). A lost vehicle that comes back
  is readied again and rejoins at its slot;
- ending (issue 15): the mission time reached, or nobody left flying (after
  ``stale_timeout_s``, or ``ready_timeout_s`` while a vehicle is being
  readied to rejoin), or a failure of the law in flight (an expression that
  fails, a non-finite leader state): then ``failure`` says why, no setpoint
  of that step goes out, and the caller brakes everyone. ``outcome()``
  judges the run honestly once it is ended.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import math
from collections import Counter, deque
from collections.abc import Callable
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.lookahead import LookaheadJob
from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.params import Envelope
from gcs_swarm.control.tracking import VelocityReference
from gcs_swarm.errors import StartupError, SwarmError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.batch import accel_ned, mission_states
from gcs_swarm.mavlink.codec import MessageSpec, RawPosition
from gcs_swarm.mavlink.inbound import Inbound, LocalPositionNed, from_pymavlink
from gcs_swarm.mavlink.personality import personality_for
from gcs_swarm.mavlink.states import FINAL_PHASES, Phase, ProtocolEvent
from gcs_swarm.mavlink.vehicle import VehicleProtocol
from gcs_swarm.report.record import FlightRecorder
from gcs_swarm.runtime.config import StationConfig, VehiclePlan
from gcs_swarm.runtime.delay import DelayCompensator
from gcs_swarm.runtime.lifetime import close_task_group
from gcs_swarm.runtime.links import Link, OnFrame

__all__ = ["Station", "StationConfig", "VehiclePlan"]

_log = logging.getLogger("gcs_swarm.station")

FloatArray = npt.NDArray[np.float64]
_FLYING = Phase.FLYING
_READYING = frozenset(
    {Phase.CONFIGURING, Phase.SETTING_GUIDED, Phase.WAITING_ARMABLE, Phase.ARMING,
     Phase.TAKING_OFF, Phase.GOING_TO_START, Phase.READY}
)  # fmt: skip


_LATE_S = 0.05
"""A protocol timer this late [s] means the process was stalled."""
_GRACE_TURNS = 4
"""Event-loop turns a late timer waits, so that datagrams that arrived during
the stall are read first (microseconds: nothing is delayed noticeably)."""

LEADER_BOUND = 1.0e7
"""Largest leader coordinate [m] or velocity component [m/s] taken as finite:
beyond the Earth's size the mission's flat local frame means nothing, and
the law's squares of such numbers overflow."""


class Station:
    """Fly one mission: ``ready()``, ``fly()``, then always ``end()``."""

    def __init__(
        self,
        config: StationConfig,
        *,
        on_status: Callable[[str], None] | None = None,
        status_interval_s: float = 1.0,
        recorder: FlightRecorder | None = None,
        on_frame: OnFrame | None = None,
    ) -> None:
        """``recorder`` receives every control step, membership change and
        received message (the run's flight record); ``on_frame`` every raw
        frame in and out on every link (the ``.tlog``)."""
        self.config = config
        self.on_status = on_status
        self.recorder = recorder
        self._on_frame = on_frame
        self.status_interval_s = status_interval_s
        pcfg = config.protocol_config()
        self.plans = {p.sysid: p for p in config.vehicles}
        self.vehicles = {
            p.sysid: VehicleProtocol(
                p.sysid,
                pcfg,
                goto_m=p.start_m,
                params=p.params,
                personality=personality_for(p.autopilot),
            )
            for p in config.vehicles
        }
        self.control = ControlLoop(config.law, {p.sysid: p.q for p in config.vehicles},
                                   config.rate_hz)  # fmt: skip
        self.members = {p.sysid for p in config.vehicles if not p.reserve}
        self.velocity_tracked = {
            p.sysid for p in config.vehicles if p.setpoint == "velocity+acceleration"
        }
        """Vehicles sent a velocity setpoint with the acceleration (Eq. V1)."""
        self.reference = VelocityReference()
        self.flying: set[int] = set()
        self.flown: set[int] = set()
        """Vehicles that have flown in the formation: if one comes back after
        being lost it goes to its slot beside the leader, not to its start."""
        self.left: set[int] = set()
        self.unknown_sysids: Counter[int] = Counter()
        self.reports_in = 0
        """LOCAL_POSITION_NED accepted from flying vehicles; each is answered by
        one setpoint unless a newer report of the same vehicle replaces it
        before the step (benchmarks: reports in - setpoints out = missed)."""
        self.log: deque[str] = deque(maxlen=2000)
        self.started = False
        self.ending = False
        self._events = sorted(config.events)
        self._reference = config.mission_origin
        self._links: dict[str, Link] = {}
        self._link_of: dict[int, Link] = {}
        self._fresh: dict[int, int] = {}
        self._arrival: dict[int, float] = {}
        self._timers: dict[int, tuple[float, asyncio.Handle]] = {}
        self._fallback: asyncio.TimerHandle | None = None
        self._tg = asyncio.TaskGroup()
        self._stack = contextlib.AsyncExitStack()
        self._tasks: list[asyncio.Task[None]] = []
        self._changed = asyncio.Event()
        self._step = asyncio.Event()
        self._finished = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._idle_since: float | None = None
        self._idle_check: asyncio.TimerHandle | None = None
        self.failure: str | None = None
        """Why the law could not go on in flight (the mission then ends as failed)."""
        self._froze = False
        self.delay: DelayCompensator | None = None
        if config.delay_compensation and not config.lockstep:
            self.delay = DelayCompensator(config.predict_accel_max_mps2)
        self._status_mark: tuple[float, float, int] | None = None
        """(wall time, mission time, steps) at the last status line."""

    # ------------------------------------------------------------ lifetime
    async def __aenter__(self) -> Station:
        self._loop = asyncio.get_running_loop()
        try:
            for plan in self.config.vehicles:
                link = self._links.get(plan.link)
                if link is None:
                    served = [p.sysid for p in self.config.vehicles if p.link == plan.link]
                    link = Link(plan.link, self._on_message, on_frame=self._on_frame,
                                on_position=self._on_positions,
                                signing_key=self.config.signing_key, sysids=served,
                                allow_rebind=self.config.allow_rebind,
                                on_notice=self.warn)  # fmt: skip
                    self._links[plan.link] = await self._stack.enter_async_context(link)
                    link = self._links[plan.link]
                self._link_of[plan.sysid] = link
            await self._tg.__aenter__()
        except BaseException:
            await self._stack.aclose()
            raise
        coros = [self._heartbeat(), self._control_task(), self._status_task()]
        if self.delay is not None:
            coros.append(self._timesync_task())
        for coro in coros:
            self._tasks.append(self._tg.create_task(coro))
        return self

    async def __aexit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._froze:
            gc.unfreeze()
            self._froze = False
        for _, handle in self._timers.values():
            handle.cancel()
        if self._fallback is not None:
            self._fallback.cancel()
        if self._idle_check is not None:
            self._idle_check.cancel()
        try:
            await close_task_group(self._tg, self._tasks, et, ev, tb)
        finally:
            await self._stack.aclose()

    @property
    def reports_waiting(self) -> int:
        """Reports accepted since the last control step (answered at the next)."""
        return len(self._fresh)

    @property
    def links(self) -> dict[str, Link]:
        return dict(self._links)

    def now(self) -> float:
        assert self._loop is not None
        return self._loop.time()

    # ------------------------------------------------------------- phases
    async def ready(self) -> None:
        """Until every vehicle, reserves included, is READY at its start point
        (a reserve then holds there until its join event); raises
        ``StartupError`` (naming each vehicle, with its own words) on a
        failure or after ``ready_timeout_s``. The caller then ends every
        vehicle (``end``): grounded ones are disarmed, pending retries dropped."""
        everyone = [self.vehicles[s] for s in sorted(self.vehicles)]
        try:
            async with asyncio.timeout(self.config.ready_timeout_s):
                while True:
                    failed = [vp for vp in everyone if vp.phase is Phase.FAILED]
                    if failed:
                        raise StartupError(
                            self._not_ready("could not be readied", failed), _reasons(failed)
                        )
                    if all(vp.phase is Phase.READY for vp in everyone):
                        return
                    await self._wait_change()
        except TimeoutError:
            late = [vp for vp in everyone if vp.phase is not Phase.READY]
            what = f"not ready after {self.config.ready_timeout_s:g} s"
            raise StartupError(self._not_ready(what, late), _reasons(late)) from None

    def apply_envelope(self) -> Envelope:
        """Plan and shape every command within the tightest envelope of the
        readied vehicles (each read from its parameters, or the mission's
        where it was not read: docs/vehicle-envelope.md); call between
        ``ready()`` and ``fly()``. Returns the envelope in force."""
        env = Envelope()
        for vp in self.vehicles.values():
            if vp.phase is Phase.READY:
                env = env.tighter(vp.envelope)
        inforce = self.control.set_envelope(env)
        if inforce.bounded:
            self._note(f"envelope in force: {inforce.describe()}")
        return inforce

    def warn(self, text: str) -> None:
        """A line for the log and the summary, at warning level."""
        self._note(text, level=logging.WARNING)

    async def fly(self) -> None:
        """Start the formation and return when the mission time is over (or
        nobody is left to fly)."""
        # The cyclic garbage collector's full passes over the start-up heap
        # (mission, numpy, pymavlink's dialect) took up to 29 ms and 6 ms for
        # generation 1 (measured at 250 vehicles): a stalled setpoint stream.
        # Collect once now, while the vehicles hold at their start points, and
        # freeze what is left so that later passes scan only the flight's own
        # objects; ``__aexit__`` unfreezes.
        gc.collect()
        gc.freeze()
        self._froze = True
        now = self.now()
        self.started = True
        for sysid in sorted(self.members):
            self._join(self.vehicles[sysid], now)
        self._note(f"formation started with vehicles {sorted(self.flying)}")
        await self._finished.wait()

    async def end(self, mode: int | None = None) -> None:
        """Zero acceleration and the end mode for everyone, confirmed by heartbeat.
        A started formation's last figures go out as one more status line first
        (a run shorter than the status interval would otherwise show none)."""
        if self.started and not self.ending and self.on_status is not None:
            self.on_status(self.status_line())
        self.ending = True
        now = self.now()
        for vp in self.vehicles.values():
            vp.finish(now, mode=mode)
            self._service(vp, now)
        settled = {Phase.ENDED, Phase.FAILED, Phase.LOST, Phase.CONNECTING}

        def busy(vp: VehicleProtocol) -> bool:  # still ending, or restoring its parameters
            return vp.phase not in settled or vp.restoring

        try:
            async with asyncio.timeout(self.config.end_timeout_s):
                while any(busy(vp) for vp in self.vehicles.values()):
                    await self._wait_change()
        except TimeoutError:
            late = [vp for vp in self.vehicles.values() if busy(vp)]
            self._note(self._not_ready("end mode not confirmed", late), level=logging.ERROR)

    # ----------------------------------------------------------- messages
    def _on_message(self, msg: Any, link: Link) -> None:
        sysid = int(msg.get_srcSystem())
        if self.recorder is not None:
            self.recorder.inbound(sysid, int(msg.get_srcComponent()), int(msg.get_seq()),
                                  int(msg.get_msgId()))  # fmt: skip
        vp = self._vehicle(sysid, link)
        if vp is None:
            return
        if msg.get_type() == "TIMESYNC":
            if self.delay is not None and msg.tc1 != 0:
                self.delay.timesync(sysid, msg.tc1, msg.ts1, self.now())
            return
        inbound = from_pymavlink(msg)
        if inbound is not None:
            self._handle(vp, inbound, link)

    def _on_positions(self, raws: list[RawPosition], link: Link) -> None:
        """Unsigned LOCAL_POSITION_NED reports, decoded without pymavlink's
        objects (a datagram's run of them): the handling ``_on_message`` gives
        each, written as one loop because it runs for every vehicle 50 times
        a second."""
        recorder = self.recorder
        timers, fresh, arrival = self._timers, self._fresh, self._arrival
        now = self.now()
        rx_s = link.rx_time_s
        accepted = 0
        for raw in raws:
            sysid = raw.sysid
            if recorder is not None:
                recorder.inbound(sysid, raw.compid, raw.seq, b.MSG_ID_LOCAL_POSITION_NED)
            vp = self._vehicle(sysid, link)
            if vp is None:
                continue
            pos = LocalPositionNed(sysid, raw.compid, *raw.values)
            if vp.phase is not _FLYING or sysid not in timers:
                self._handle(vp, pos, link)
                now = self.now()
            # FLYING with its timer armed: what _handle does, without the calls
            # that change nothing here (see the end of _handle).
            elif vp.flying_position(pos, now):
                fresh[sysid] = pos.time_boot_ms
                arrival[sysid] = rx_s
                accepted += 1
                if vp.outbound_waiting:  # the rate watch asked for the interval again
                    self._service(vp, now)
        if accepted:
            self.reports_in += accepted
            self._maybe_step(now)

    def _vehicle(self, sysid: int, link: Link) -> VehicleProtocol | None:
        """The mission's vehicle ``sysid`` if it belongs on ``link``; traffic
        from anyone else is counted (and noted once) and ignored."""
        vp = self.vehicles.get(sysid)
        if vp is None or self._link_of.get(sysid) is not link:
            if sysid not in self.unknown_sysids:
                self._note(f"ignoring traffic from system {sysid} on {link.endpoint}",
                           level=logging.WARNING)  # fmt: skip
            self.unknown_sysids[sysid] += 1
            return None
        return vp

    def _handle(self, vp: VehicleProtocol, inbound: Inbound, link: Link) -> None:
        now = self.now()
        vp.handle_message(inbound, now)
        if (
            isinstance(inbound, LocalPositionNed)
            and vp.phase is Phase.FLYING
            and vp.position is inbound  # not refused as implausible, duplicated or old
        ):
            sysid = vp.sysid
            self._fresh[sysid] = inbound.time_boot_ms
            self.reports_in += 1
            self._arrival[sysid] = link.rx_time_s
            self._maybe_step(now)
            if sysid in self._timers and not vp.outbound_waiting:
                # Accepted telemetry in FLYING queues nothing (but the rate
                # watch's request), raises no event and only moves the
                # protocol's deadlines later, so the armed (earlier) timer
                # stands: ``_service`` would change nothing.
                return
        self._service(vp, now)

    def _service(self, vp: VehicleProtocol, now: float) -> None:
        """Send what the protocol queued, react to its events, re-arm its timer."""
        link = self._link_of[vp.sysid]
        for spec in vp.take_outbound():
            link.send(spec, vp.sysid)
        events = vp.take_events()
        for event in events:
            self._on_event(vp, event, now)
        if self._reference is None and vp.origin is not None:
            if vp.sysid == self.config.vehicles[0].sysid:
                self._reference = vp.origin
                self._note(f"mission origin = vehicle {vp.sysid}'s EKF origin")
                for other in self.vehicles.values():
                    other.set_reference(vp.origin)
        self._arm_timer(vp)
        if events:
            self._changed.set()

    def _on_event(self, vp: VehicleProtocol, event: ProtocolEvent, now: float) -> None:
        level = {"refused": logging.WARNING, "failed": logging.ERROR, "lost": logging.WARNING,
                 "warning": logging.WARNING}.get(event.kind, logging.INFO)  # fmt: skip
        self._note(event.text, level=level)
        if event.kind not in ("phase", "lost", "failed"):
            return
        sysid = vp.sysid
        if sysid in self.flying and vp.phase is not Phase.FLYING:
            self.flying.discard(sysid)
            self._fresh.pop(sysid, None)
            self.control.forget(sysid)
            self.reference.forget(sysid)
            if self.recorder is not None:
                self.recorder.member(self.control.t_s, sysid, False)
            self._note(f"vehicle {sysid} out of the formation ({vp.phase.value}); "
                       f"{len(self.flying)} re-form")  # fmt: skip
            self._maybe_step(now)
            if not self.flying:
                self._check_alive()
        elif vp.phase is Phase.READY and self.started and not self.ending:
            if sysid in self.members:
                self._join(vp, now)

    def _join(self, vp: VehicleProtocol, now: float) -> None:
        if vp.phase is Phase.READY:
            vp.begin_flying(now)
            self.flying.add(vp.sysid)
            self.flown.add(vp.sysid)
            if self.recorder is not None:
                self.recorder.member(self.control.t_s, vp.sysid, True)
            if self.started:
                self._note(f"t={self.control.t_s:.2f} s: vehicle {vp.sysid} joins the formation "
                           f"({len(self.flying)} flying)")  # fmt: skip

    # --------------------------------------------------------------- timers
    def _arm_timer(self, vp: VehicleProtocol) -> None:
        due = vp.next_deadline()
        old = self._timers.get(vp.sysid)
        if old is not None:
            if due is not None and old[0] <= due:
                # Keep the earlier timer: firing early is harmless (the protocol
                # acts only on what is due) and re-arms then. Telemetry pushes the
                # stale deadline on at every message; this avoids a heap churn.
                return
            old[1].cancel()
            del self._timers[vp.sysid]
        if due is not None and self._loop is not None:
            handle = self._loop.call_at(due, self._on_timer, vp.sysid, due)
            self._timers[vp.sysid] = (due, handle)

    def _on_timer(self, sysid: int, due: float, turns: int = 0) -> None:
        if turns < _GRACE_TURNS and self.now() - due > _LATE_S and self._loop is not None:
            # Fired late: the process was stalled (a loaded machine, the garbage
            # collection in ``fly``). What the vehicles sent meanwhile is read
            # first, a few loop turns on, or a vehicle would look stale because
            # the station itself stopped (issue 15 item 12).
            handle = self._loop.call_soon(self._on_timer, sysid, due, turns + 1)
            self._timers[sysid] = (due, handle)
            return
        self._timers.pop(sysid, None)
        # call_at may fire up to one clock resolution early: never hand the
        # protocol a time before the deadline it asked for.
        now = max(self.now(), due)
        vp = self.vehicles[sysid]
        vp.handle_timer(now)
        self._service(vp, now)

    # --------------------------------------------------------- control loop
    def _maybe_step(self, now: float) -> None:
        if not self.started or self.ending or not self._fresh or self.failure is not None:
            return
        # _fresh holds flying vehicles only (a vehicle leaving is popped), so the
        # subset test runs once per step, not once per report.
        if len(self._fresh) >= len(self.flying) and self.flying <= self._fresh.keys():
            self._step.set()
        elif self._fallback is None and self._loop is not None:
            # Lockstep: a generous wait keeps runs repeatable; real time: half a period.
            wait = 0.2 if self.config.lockstep else 0.5 / self.config.rate_hz
            self._fallback = self._loop.call_at(now + wait, self._step.set)

    async def _control_task(self) -> None:
        while True:
            await self._step.wait()
            self._step.clear()
            if self._fallback is not None:
                self._fallback.cancel()
                self._fallback = None
            if not self.ending:
                self._control_step()

    def _control_step(self) -> None:
        now = self.now()
        fresh, self._fresh = self._fresh, {}
        t = self.control.advance_clock(fresh)
        self._run_events(t, now)
        ids = sorted(self.flying)
        if ids:
            pos, vel = mission_states([self.vehicles[s] for s in ids])
            if self.delay is not None:
                for i, s in enumerate(ids):
                    last = self.vehicles[s].position
                    if last is not None:
                        t_s = last.time_boot_ms * 1e-3
                        pos[i], vel[i] = self.delay.predict(s, t_s, now, pos[i], vel[i])
            try:
                # Overflow is judged below, on the leader (and counted, on the setpoints).
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    out, accel, report = self.control.command(ids, pos, vel)
            except (SwarmError, ArithmeticError, ValueError) as err:
                self._abort(f"t={t:.2f} s: the law failed in flight: {err}")
                return
            lead = (out.leader_pos_m, out.leader_vel_mps)
            if not all((np.abs(x) <= LEADER_BOUND).all() for x in lead):  # NaN fails too
                self._abort(f"t={t:.2f} s: the virtual leader's state is not finite (position "
                            f"{lead[0].tolist()} m, velocity {lead[1].tolist()} m/s)")  # fmt: skip
                return
            if out.event is not None:
                what = "starts" if out.event == "start" else "ends: formation resumes"
                self._note(f"t={t:.2f} s: avoidance episode {out.episode} {what}")
            if self.recorder is not None:
                # Before the setpoints go out: the log's LEADER note marks the step.
                cor = None if report is None else report.correction_mps2
                self.recorder.step(t, ids, pos.copy(), out.leader_pos_m, out.behaviour,
                                   out.episode, accel_mps2=accel, sent=fresh.keys(),
                                   correction_mps2=cor)  # fmt: skip
            rows = [i for i, sysid in enumerate(ids) if sysid in fresh]  # one answer each
            self._answer([ids[i] for i in rows], accel[rows], now, t, vel[rows])
            self.control.account(ids, pos, out, accel, report)
            job = self.control.pending_lookahead()
            if job is not None:
                self._tasks.append(self._tg.create_task(self._lookahead(job)))
        for sysid in (self.members & self.flown) - self.flying:
            vp = self.vehicles[sysid]
            if vp.phase in _READYING and vp.phase is not Phase.READY:
                vp.set_goto(self.control.slot_m(self.plans[sysid].start_m))
        if t >= self.config.duration_s:
            self._note(f"mission time {t:.2f} s reached the duration")
            self._finished.set()

    def _abort(self, why: str) -> None:
        """End the mission now, as failed: no setpoint of this step goes out;
        the caller ends every vehicle (``end``, braking)."""
        if self.failure is None:
            self.failure = why
            self._note(f"{why}; ending the mission (failed)", level=logging.ERROR)
        self._finished.set()

    def outcome(self) -> str:
        """The run's outcome once ``end()`` has returned: ``failed`` when the
        law failed in flight or every vehicle that flew was lost (or failed,
        or never confirmed its end action); ``degraded`` when some were;
        ``completed`` when every vehicle that flew ended."""
        gone = [s for s in self.flown if self.vehicles[s].phase is not Phase.ENDED]
        if self.failure is not None or (self.flown and len(gone) == len(self.flown)):
            return "failed"
        return "degraded" if gone else "completed"

    def _answer(
        self, sysids: list[int], accel: FloatArray, now: float, t: float, vel: FloatArray
    ) -> None:
        """Write one acceleration setpoint (mission frame ``accel (K, 3)``) to
        each of ``sysids`` now, each link all of its vehicles' at once, before
        the step's bookkeeping. A velocity-tracked vehicle's goes with its
        velocity setpoint (Eq. V1, from ``vel``, the velocity the law saw, at
        mission time ``t``)."""
        vps = [self.vehicles[s] for s in sysids]
        ned = accel_ned(vps, accel)
        vel_ned: FloatArray | None = None
        tracked = [k for k, s in enumerate(sysids) if s in self.velocity_tracked]
        if tracked:
            # What was sent (the NED rows, clipped) back in the mission frame: V1 integrates it.
            sent = np.stack([ned[tracked, 1], ned[tracked, 0], -ned[tracked, 2]], axis=1)
            ref = self.reference.setpoints([sysids[k] for k in tracked], t, vel[tracked], sent)
            vel_ned = np.full((len(sysids), 3), np.nan)
            bias = np.array([vps[k].vel_correction_ned for k in tracked], dtype=np.float64)
            # The vehicle flies its own (biased) velocity estimate to the setpoint.
            vel_ned[tracked, 0] = ref[:, 1] + bias[:, 0]
            vel_ned[tracked, 1] = ref[:, 0] + bias[:, 1]
            vel_ned[tracked, 2] = -ref[:, 2] + bias[:, 2]
        rows: dict[Link, list[int]] = {}
        for k, sysid in enumerate(sysids):
            rows.setdefault(self._link_of[sysid], []).append(k)
        for link in self._links.values():
            idx = rows.get(link)
            if idx is None:
                link.flush()
                continue
            link.send_accel_setpoints(
                [sysids[k] for k in idx],
                [vps[k].compid for k in idx],
                [vps[k].boot_ms() for k in idx],
                ned if len(idx) == len(sysids) else ned[idx],
                [self._arrival.get(sysids[k]) for k in idx],
                vel_ned=vel_ned if vel_ned is None or len(idx) == len(sysids) else vel_ned[idx],
            )
        if self.delay is not None:
            for k, sysid in enumerate(sysids):
                self.delay.sent(sysid, now, accel[k])

    async def _lookahead(self, job: LookaheadJob) -> None:
        """The plane look-ahead in a worker thread: setpoints keep flowing."""
        t0 = self.now()
        result = await asyncio.to_thread(job)
        self.control.resolve_lookahead(job, result)
        n_vertical = int(result.vertical.sum())
        self._note(
            f"look-ahead for episode {job.episode}: vertical plane for {n_vertical} of "
            f"{len(result.ids)} vehicles ({1e3 * (self.now() - t0):.0f} ms in a worker thread)"
        )

    def _run_events(self, t: float, now: float) -> None:
        while self._events and self._events[0][0] <= t:
            at, action, sysid = self._events.pop(0)
            vp = self.vehicles[sysid]
            self._note(f"t={at:g} s: vehicle {sysid} {action}s")
            if action == "join":
                self.members.add(sysid)
                self.left.discard(sysid)
                if vp.phase is Phase.READY:
                    self._join(vp, now)  # holding at its reserve point: in at once
                else:
                    vp.enable(now)  # readied (again) to its start point, then in
            else:
                self.members.discard(sysid)
                self.left.add(sysid)
                vp.finish(now)
            self._service(vp, now)

    # ------------------------------------------------------ periodic tasks
    async def _timesync_task(self) -> None:
        """TIMESYNC requests at 5 Hz on every link (delay compensation)."""
        while True:
            stamp = int(self.now() * 1e9)
            for link in self._links.values():
                link.send(MessageSpec("TIMESYNC", {"tc1": 0, "ts1": stamp}))
            await asyncio.sleep(0.2)

    async def _heartbeat(self) -> None:
        """HEARTBEAT at 1 Hz on every link (also wakes udpout peers at once)."""
        while True:
            for link in self._links.values():
                link.send(b.heartbeat())
            await asyncio.sleep(1.0)

    async def _status_task(self) -> None:
        while True:
            await asyncio.sleep(self.status_interval_s)
            if self.on_status is not None:
                self.on_status(self.status_line())
            self._check_alive()

    def _check_alive(self) -> None:
        """End a started mission once nobody has flown for ``stale_timeout_s``
        (``ready_timeout_s`` while a member is being readied to rejoin)."""
        if self._idle_check is not None:
            self._idle_check.cancel()
            self._idle_check = None
        if not self.started or self.ending or self.flying:
            self._idle_since = None
            return
        now = self.now()
        if self._idle_since is None:
            self._idle_since = now
        coming = any(self.vehicles[s].phase in _READYING for s in self.members)
        wait = self.config.ready_timeout_s if coming else self.config.stale_timeout_s
        if now - self._idle_since >= wait:
            self._note("no vehicle left in the formation; ending", level=logging.WARNING)
            self._finished.set()
        elif self._loop is not None:
            self._idle_check = self._loop.call_at(self._idle_since + wait, self._check_alive)

    def status_line(self) -> str:
        """One line with the run's figures as they evolve: mission time, control
        rate over the last interval, behaviour, radius range, separation now and
        its minimum so far, minimum obstacle clearance so far, peak commanded
        acceleration, then each vehicle's phase and mode."""
        last = self.control.last
        parts = [f"t={self.control.t_s:7.2f}s"]
        now = self.now()
        t = self.control.t_s
        if self._status_mark is not None and t > self._status_mark[1]:
            # Control steps per second of vehicle time (the mission rate when
            # keeping up, in real time or lockstep alike), and the pace.
            wall0, t0, steps0 = self._status_mark
            parts.append(f"{(self.control.steps - steps0) / (t - t0):5.1f} Hz")
            if now > wall0:
                parts.append(f"x{(t - t0) / (now - wall0):.1f}")
        self._status_mark = (now, t, self.control.steps)
        if last is not None and last.ids:
            r = last.radii_m
            parts.append(f"{last.law.behaviour:9s} r={r.min():.3f}..{r.max():.3f} m")
            sep = last.min_separation_m
            if math.isfinite(sep):
                parts.append(f"sep {sep:.3f} (min {self.control.min_separation_m:.3f}) m")
            clr = self.control.min_clearance_m
            if math.isfinite(clr):
                parts.append(f"min clearance {clr:.3f} m")
            parts.append(f"peak |a| {self.control.peak_accel_mps2:.2f} m/s^2")
        parts.append(" ".join(f"{s}:{vp.phase.value}/{vp.mode_name}"
                              for s, vp in sorted(self.vehicles.items())))  # fmt: skip
        drops = sum(link.stats.setpoints_dropped for link in self._links.values())
        if drops:
            parts.append(f"drops {drops}")
        low = [f"{s}:{vp.telemetry_rate_hz:.1f}Hz" for s, vp in sorted(self.vehicles.items())
               if vp.rate_low and vp.telemetry_rate_hz is not None]  # fmt: skip
        if low:
            parts.append("low telemetry " + " ".join(low))
        clipped = self.clipped_setpoints()
        if clipped:
            parts.append(f"clipped setpoints {clipped}")
        refused = self.rebinds_refused()
        if refused:
            parts.append("rebind refused " + " ".join(f"{s}:{n}" for s, n in refused.items()))
        return " | ".join(parts)

    def clipped_setpoints(self) -> int:
        """Setpoints scaled down to the ceiling or zeroed (non-finite), all vehicles."""
        return sum(vp.clipped_setpoints for vp in self.vehicles.values())

    def rebinds_refused(self) -> dict[int, int]:
        """Frames refused per vehicle because they came from another address
        than the one it is bound to (``Link.rebinds_refused``), by system id."""
        total: Counter[int] = Counter()
        for link in self._links.values():
            total.update(link.rebinds_refused)
        return dict(sorted(total.items()))

    # ---------------------------------------------------------------- misc
    async def _wait_change(self) -> None:
        self._changed.clear()
        await self._changed.wait()

    def _not_ready(self, what: str, vps: list[VehicleProtocol]) -> str:
        who = "; ".join(
            f"vehicle {vp.sysid} {vp.phase.value}" + (f" ({vp.failure})" if vp.failure else "")
            for vp in vps
        )
        return f"{what}: {who}" if who else what

    def _note(self, text: str, *, level: int = logging.INFO) -> None:
        _log.log(level, "%s", text)
        if level >= logging.INFO:
            self.log.append(text)

    def setpoint_latencies_s(self) -> list[float]:
        """Recent telemetry-arrival-to-setpoint-write times [s] of every link
        (each link keeps its last ``LatencyRing`` size samples)."""
        return [x for link in self._links.values() for x in link.latency.samples()]

    def phases(self) -> dict[int, Phase]:
        return {s: vp.phase for s, vp in self.vehicles.items()}

    def final(self) -> bool:
        return all(vp.phase in FINAL_PHASES for vp in self.vehicles.values())


def _reasons(vps: list[VehicleProtocol]) -> dict[int, str]:
    """``StartupError.reasons``: each vehicle's phase, and its failure in its own words."""
    return {vp.sysid: vp.phase.value + (f" ({vp.failure})" if vp.failure else "") for vp in vps}
