"""The swarm's rules without I/O: membership, events, origin, steps, ending.

``SwarmCore`` is the ground station with its sockets and tasks taken out,
driven as aioquic drives a connection (STYLE.md habit 1): messages go in with
the link they came on and the time (``receive``; a flying vehicle's
LOCAL_POSITION_NED is written into ``table`` by the link state, then
``telemetry_written``), ``handle_timer(now)`` when ``get_timer()`` is due,
``control_step(now, write)`` when ``step_wanted``; what the protocols queued waits in
``outbound`` as ``(link, spec, sysid)``; ``changed`` and ``finished`` tell the shell
(``runtime.station.Station``) a phase moved or the mission is over (links: connection strings).

- each received message goes to its vehicle's ``VehicleProtocol`` (traffic from system ids
  the mission does not name on that link is counted and ignored); every protocol's
  deadline is kept, and the earliest is the core's timer;
- a step is wanted when every flying vehicle has sent a fresh LOCAL_POSITION_NED (with
  ``mission.step: network``, also every vehicle of one network: its rows), or a fallback
  delay after the first one (half a period; 0.2 s in lockstep), and answers each fresh
  report with exactly one setpoint: the emulator's lockstep rule, and a steady rate on
  real vehicles;
- membership: initial vehicles fly from the start; a reserve is readied with them (it takes
  off and holds at its start, its reserve point) and joins on its event, so that the join
  happens at the mission's time; a vehicle leaves on its event, or when its protocol
  reports it LOST or FAILED; the law simply gets the current set (formation-law.md s9).
  A lost vehicle that comes back is readied again and rejoins at its slot;
- the mission origin: the mission's, else the first vehicle's EKF origin as soon as it is
  heard, handed to every vehicle;
- ending (issue 15): the mission time reached, or nobody left flying (after
  ``stale_timeout_s``, or ``ready_timeout_s`` while a vehicle is being
  readied to rejoin), or a failure of the law in flight (an expression that
  fails, a non-finite leader state): then ``failure`` says why, no setpoint
  of that step goes out, and the caller brakes everyone. ``outcome()``
  judges the run honestly once it is ended.
"""

from __future__ import annotations

import heapq
import logging
from collections import Counter, deque
from typing import TYPE_CHECKING, Any

from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult
from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.params import Envelope
from gcs_swarm.control.tracking import VelocityReference
from gcs_swarm.mavlink.codec import MessageSpec
from gcs_swarm.mavlink.coordinates import GeoOrigin
from gcs_swarm.mavlink.inbound import Inbound, LocalPositionNed, from_pymavlink, with_key
from gcs_swarm.mavlink.personality import personality_for
from gcs_swarm.mavlink.states import Phase, ProtocolEvent
from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.mavlink.vehicle import VehicleProtocol
from gcs_swarm.swarm.departures import keep_out_lost
from gcs_swarm.swarm.handshakes import HandshakeGate
from gcs_swarm.swarm.step import READYING, FlyingOrder, Write, resolve_lookahead, run_step

if TYPE_CHECKING:  # plain data of the layer above, for the types only
    from gcs_swarm.report.record import FlightRecorder
    from gcs_swarm.runtime.config import StationConfig
    from gcs_swarm.runtime.delay import DelayCompensator

__all__ = ["SwarmCore"]

_log = logging.getLogger("gcs_swarm.station")


class SwarmCore:
    """One mission's rules (module docstring). Time is an argument [s]."""

    def __init__(
        self,
        config: StationConfig,
        *,
        recorder: FlightRecorder | None = None,
        delay: DelayCompensator | None = None,
    ) -> None:
        """``recorder`` receives every control step, membership change and
        received message; ``delay`` (TIMESYNC estimates) predicts each
        report to the step's time."""
        self.config = config
        self.recorder = recorder
        self.delay = delay
        pcfg = config.protocol_config()
        self.plans = {p.sysid: p for p in config.vehicles}
        phases = config.status_phases()
        self.vehicles = {
            p.sysid: VehicleProtocol(
                p.sysid,
                pcfg,
                goto_m=p.start_m,
                params=p.params,
                personality=personality_for(p.autopilot),
                label=p.label or None,
                status_phase=phases[p.sysid],
                enabled=config.handshakes_per_network is None,  # else ``gate`` (swarm.handshakes)
            )
            for p in config.vehicles
        }
        self.labels = {p.sysid: p.label or str(p.sysid) for p in config.vehicles}
        """How each vehicle is named in the log (``blue:7`` on a named network)."""
        self.table = TelemetryTable([p.sysid for p in config.vehicles], config.step_groups())
        """The flying vehicles' telemetry (the links write it, the step reads it)."""
        if recorder is not None:
            self.table.on_inbound = recorder.inbound
        # The plane look-ahead: in real time off the step (``lookahead``, run by
        # the shell in a worker thread); in lockstep inline at its step, where
        # the emulator waits for it, so that a run with obstacles is repeatable.
        self.control = ControlLoop(config.law, {p.sysid: p.q for p in config.vehicles},
                                   config.rate_hz, defer=not config.lockstep)  # fmt: skip
        self.links = list(dict.fromkeys(p.link for p in config.vehicles))
        """The mission's links (connection strings), in the order first named."""
        self.link_of = {p.sysid: p.link for p in config.vehicles}
        self.base_of = {p.link: p.base for p in config.vehicles}
        """What each link's keys add to the system ids it carries (its network's)."""
        window, nets = config.handshakes_per_network, {p.sysid: p.base for p in config.vehicles}
        self.gate = None if window is None else HandshakeGate(window, nets)
        self.members = {p.sysid for p in config.vehicles if not p.reserve}
        self.velocity_tracked = {
            p.sysid for p in config.vehicles if p.setpoint == "velocity+acceleration"
        }
        """Vehicles sent a velocity setpoint with the acceleration (Eq. V1)."""
        self.reference = VelocityReference()
        self.flying: set[int] = set()
        self.order = FlyingOrder()  # ``flying`` in key order, for each step
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
        self.failure: str | None = None
        """Why the law could not go on in flight (the mission then ends as failed)."""
        # What the shell reads after each call:
        self.outbound: list[tuple[str, MessageSpec, int]] = []
        """Protocol messages to send: (link, spec, sysid); the shell empties it."""
        self.step_wanted = False
        """A control step is due (``control_step``)."""
        self.timer_moved = False
        """``get_timer()`` may be earlier than when last read; the shell clears it."""
        self.changed = False
        """A vehicle's phase moved (``ready``/``end`` look again); the shell clears it."""
        self.finished = False
        """The mission is over (duration, nobody left, or ``failure``): no
        step runs after it, whenever the shell gets round to ending."""
        self.lookahead: list[LookaheadJob] = []
        """Plane look-aheads to run off the step (``resolve_lookahead``); the shell empties it."""
        self._events = sorted(config.events)
        self._origin = config.mission_origin
        self._deadlines: dict[int, float] = {}
        self._heap: list[tuple[float, int]] = []
        self._fallback_at: float | None = None
        self._fallback_due = False  # the wanted step is the fallback's: every fresh report
        self._idle_since: float | None = None
        self._idle_at: float | None = None

    @property
    def reports_waiting(self) -> int:
        """Reports accepted since the last control step (answered at the next)."""
        return self.table.fresh_count

    # ------------------------------------------------------------ inbound
    def receive(self, msg: Any, link: str, now: float, rx_s: float) -> None:
        """A pymavlink message from ``link``, which arrived at ``rx_s`` [s]
        (the clock of the setpoints' latency), handled at ``now``."""
        base = self.base_of.get(link, 0)
        sysid = int(msg.get_srcSystem()) + base  # the vehicle's key
        if self.recorder is not None:
            self.recorder.inbound(sysid, int(msg.get_srcComponent()), int(msg.get_seq()),
                                  int(msg.get_msgId()))  # fmt: skip
        vp = self._vehicle(sysid, link)
        if vp is None:
            return
        if msg.get_type() == "TIMESYNC":
            if self.delay is not None and msg.tc1 != 0:
                self.delay.timesync(sysid, msg.tc1, msg.ts1, now)
            return
        inbound = from_pymavlink(msg)
        if inbound is not None:
            if base:
                inbound = with_key(inbound, sysid)
            self._handle(vp, inbound, now, rx_s)

    def telemetry_written(self, now: float) -> None:
        """The links wrote flying vehicles' reports into ``table`` (``LinkState.receive``):
        count them, let a protocol whose rate window asked for the interval
        again send it, and see whether a step is due."""
        table = self.table
        taken = table.taken
        if table.attention:
            waiting, table.attention = table.attention, []
            for sysid in waiting:
                self._service(self.vehicles[sysid], now)
        if taken:
            table.taken = 0
            self.reports_in += taken
            self._maybe_step(now)

    def _vehicle(self, sysid: int, link: str) -> VehicleProtocol | None:
        """The mission's vehicle ``sysid`` if it belongs on ``link``; traffic
        from anyone else is counted (and noted once) and ignored."""
        vp = self.vehicles.get(sysid)
        if vp is None or self.link_of.get(sysid) != link:
            if sysid not in self.unknown_sysids:
                wire = sysid - self.base_of.get(link, 0)
                self.note(f"ignoring traffic from system {wire} on {link}",
                          level=logging.WARNING)  # fmt: skip
            self.unknown_sysids[sysid] += 1
            return None
        return vp

    def _handle(self, vp: VehicleProtocol, inbound: Inbound, now: float, rx_s: float) -> None:
        if type(inbound) is LocalPositionNed and vp.sysid in self.flying:
            # A flying vehicle's report that came as a message (after another
            # message of it in one datagram, or signed): its table row takes it.
            table = self.table
            if table.write(table.slot[vp.sysid], inbound.compid, -1, inbound[2:], now, rx_s):
                self.telemetry_written(now)
                return
        vp.handle_message(inbound, now)
        self._service(vp, now)

    def service(self, sysid: int, now: float) -> None:
        """Take what vehicle ``sysid``'s protocol queued, react to its events,
        keep its deadline (after a call on the protocol from outside)."""
        self._service(self.vehicles[sysid], now)

    def _service(self, vp: VehicleProtocol, now: float) -> None:
        link = self.link_of[vp.sysid]
        for spec in vp.take_outbound():
            self.outbound.append((link, spec, vp.sysid))
        events = vp.take_events()
        for event in events:
            self._on_event(vp, event, now)
        if self._origin is None and vp.origin is not None:
            if vp.sysid == self.config.vehicles[0].sysid:
                self._origin = vp.origin
                self.note(f"mission origin = vehicle {vp.label}'s EKF origin")
                for other in self.vehicles.values():
                    other.set_reference(vp.origin)
        self._arm(vp)
        if events:
            self.changed = True
        if self.gate is not None:
            for sysid in self.gate.update(vp):  # places freed in its network
                self.vehicles[sysid].enable(now)
                self._service(self.vehicles[sysid], now)

    @property
    def origin(self) -> GeoOrigin | None:
        """The mission origin, once known (the mission's, or learned)."""
        return self._origin

    def _on_event(self, vp: VehicleProtocol, event: ProtocolEvent, now: float) -> None:
        level = {"refused": logging.WARNING, "failed": logging.ERROR, "lost": logging.WARNING,
                 "warning": logging.WARNING}.get(event.kind, logging.INFO)  # fmt: skip
        self.note(event.text, level=level)
        if event.kind not in ("phase", "lost", "failed"):
            return
        sysid = vp.sysid
        if vp.phase is not Phase.LOST and self.control.release(sysid):
            self.note(f"vehicle {vp.label} heard again: the others no longer keep out of "
                      "its column")  # fmt: skip
        if sysid in self.flying and vp.phase is not Phase.FLYING:
            self.flying.discard(sysid)  # its table row was detached with the phase
            self.control.forget(sysid)
            self.reference.forget(sysid)
            if self.recorder is not None:
                self.recorder.member(self.control.t_s, sysid, False)
            self.note(f"vehicle {vp.label} out of the formation ({vp.phase.value}); "
                      f"{len(self.flying)} re-form")  # fmt: skip
            if vp.phase is Phase.LOST:  # still in the air, unheard (Eq. K1)
                said = keep_out_lost(
                    vp, self.plans[sysid], self.control, self.config.guid_timeout_s
                )
                if said is not None:
                    self.note(said[0], level=said[1])
            self._maybe_step(now)
            if not self.flying:
                self.check_alive(now)
        elif vp.phase is Phase.READY and self.started and not self.ending:
            if sysid in self.members:
                self._join(vp, now)

    # ------------------------------------------------------------- timers
    def _arm(self, vp: VehicleProtocol) -> None:
        """Keep ``vp``'s next deadline. An earlier one already kept stands:
        firing early is harmless (the protocol acts only on what is due, and
        is kept again then); telemetry pushes the stale deadline on at every
        message, and this avoids a heap churn."""
        due = vp.next_deadline()
        sysid = vp.sysid
        old = self._deadlines.get(sysid)
        if old is not None:
            if due is not None and old <= due:
                return
            del self._deadlines[sysid]  # its heap entry is skipped when it comes up
        if due is not None:
            self._deadlines[sysid] = due
            heap = self._heap
            if not heap or due < heap[0][0]:
                self.timer_moved = True
            heapq.heappush(heap, (due, sysid))

    def get_timer(self) -> float | None:
        """The earliest time [s] ``handle_timer`` has something to do, or None."""
        heap, armed = self._heap, self._deadlines
        while heap and armed.get(heap[0][1]) != heap[0][0]:
            heapq.heappop(heap)
        times = [t for t in (self._fallback_at, self._idle_at) if t is not None]
        if heap:
            times.append(heap[0][0])
        return min(times) if times else None

    def handle_timer(self, now: float) -> None:
        """What is due at ``now``: each vehicle's protocol deadline, the step's
        fallback, the check that somebody is still flying."""
        heap, armed = self._heap, self._deadlines
        while heap and heap[0][0] <= now:
            due, sysid = heapq.heappop(heap)
            if armed.get(sysid) != due:
                continue  # superseded by an earlier deadline, already handled
            del armed[sysid]
            vp = self.vehicles[sysid]
            vp.handle_timer(now)
            self._service(vp, now)
        if self._fallback_at is not None and self._fallback_at <= now:
            self._fallback_at = None
            self._fallback_due = True
            self.step_wanted = True
        if self._idle_at is not None and self._idle_at <= now:
            self.check_alive(now)

    # ---------------------------------------------------------- membership
    def start(self, now: float) -> None:
        """Start the formation: the initial members fly."""
        self.started = True
        for sysid in sorted(self.members):
            self._join(self.vehicles[sysid], now)
        who = ", ".join(self.labels[s] for s in sorted(self.flying))
        self.note(f"formation started with vehicles [{who}]")

    def finish_all(self, now: float, mode: int | None = None) -> None:
        """Zero acceleration and the end mode (``mode``, else the mission's)
        for every vehicle; the mission is ending."""
        self.ending = True
        for vp in self.vehicles.values():
            vp.finish(now, mode=mode)
            self._service(vp, now)

    def _join(self, vp: VehicleProtocol, now: float) -> None:
        if vp.phase is Phase.READY:
            vp.begin_flying(now, self.table)
            self.flying.add(vp.sysid)
            self.flown.add(vp.sysid)
            if self.recorder is not None:
                self.recorder.member(self.control.t_s, vp.sysid, True)
            if self.started:
                self.note(f"t={self.control.t_s:.2f} s: vehicle {vp.label} joins the formation "
                          f"({len(self.flying)} flying)")  # fmt: skip

    def _run_events(self, t: float, now: float) -> None:
        while self._events and self._events[0][0] <= t:
            at, action, sysid = self._events.pop(0)
            vp = self.vehicles[sysid]
            self.note(f"t={at:g} s: vehicle {vp.label} {action}s")
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

    def check_alive(self, now: float) -> None:
        """End a started mission once nobody has flown for ``stale_timeout_s``
        (``ready_timeout_s`` while a member is being readied to rejoin)."""
        self._idle_at = None
        if not self.started or self.ending or self.flying:
            self._idle_since = None
            return
        if self._idle_since is None:
            self._idle_since = now
        coming = any(self.vehicles[s].phase in READYING for s in self.members)
        wait = self.config.ready_timeout_s if coming else self.config.stale_timeout_s
        if now - self._idle_since >= wait:
            self.note("no vehicle left in the formation; ending", level=logging.WARNING)
            self.finished = True
        else:
            self._idle_at = self._idle_since + wait
            self.timer_moved = True

    # --------------------------------------------------------- control step
    def _maybe_step(self, now: float) -> None:
        fresh = self.table.fresh_count
        if not self.started or self.ending or self.finished or not fresh:
            return
        # Only flying vehicles' rows take reports (a vehicle leaving is detached),
        # so the fresh count is enough.
        if fresh >= len(self.flying):
            self.step_wanted = True
        elif self.config.step_per_network and self.table.complete_groups():
            self.step_wanted = True  # one network's reports are all in: its rows
        elif self._fallback_at is None:
            # Lockstep: a generous wait keeps runs repeatable; real time: half a period.
            wait = 0.2 if self.config.lockstep else 0.5 / self.config.rate_hz
            self._fallback_at = now + wait
            self.timer_moved = True

    def control_step(self, now: float, write: Write) -> None:
        """One step of the law at ``now`` over the fresh reports: events,
        the law, each link's setpoints handed to ``write`` (one answer per
        fresh report), then the bookkeeping (``swarm.step``). Nothing once
        the mission is finished or ending."""
        fresh = self.take_step()
        if fresh is None:
            return
        t = self.advance_clock_and_events(fresh, now)
        run_step(self, fresh, t, now, write)

    def advance_clock_and_events(self, fresh: dict[int, int], now: float) -> float:
        """The step's mission time [s] from its ``fresh`` reports
        (``ControlLoop.advance_clock``), with the events due by then run:
        a vehicle leaving or joining at that time is out of, or in, this
        step's flying set. ``control_step`` calls it before the law; a link
        shard before it takes its state batch (``swarm.shard``)."""
        t = self.control.advance_clock(fresh)
        self._run_events(t, now)
        return t

    def take_step(self) -> dict[int, int] | None:
        """The wanted step begins: the fresh reports (key -> ``time_boot_ms``)
        taken from the table, or None once finished or ending (steps past the
        mission's end are not part of it), for ``control_step`` or a link
        shard's controller; with ``step_per_network``, complete networks'."""
        self.step_wanted = False
        fallback, self._fallback_at = self._fallback_at, None
        due, self._fallback_due = self._fallback_due, False
        if self.ending or self.finished:
            return None
        table = self.table
        if self.config.step_per_network and not due and table.fresh_count < len(self.flying):
            fresh = table.take_complete()
            if fresh:
                if table.fresh_count and fallback is not None:  # the others' wait goes on
                    self._fallback_at, self.timer_moved = fallback, True
                return fresh
        return table.take_fresh()

    def resolve_lookahead(self, job: LookaheadJob, result: LookaheadResult, took_s: float) -> None:
        """A look-ahead's ``result``, computed off the step in ``took_s`` [s]."""
        self.note(resolve_lookahead(self.control, job, result, took_s))

    # --------------------------------------------------------------- ending
    def abort(self, why: str) -> None:
        """End the mission now, as failed: no setpoint of this step goes out;
        the caller ends every vehicle (``finish_all``, braking)."""
        if self.failure is None:
            self.failure = why
            self.note(f"{why}; ending the mission (failed)", level=logging.ERROR)
        self.finished = True

    def outcome(self) -> str:
        """The run's outcome once ended: ``failed`` when the law failed in
        flight or every vehicle that flew was lost (or failed, or never
        confirmed its end action); ``degraded`` when some were; ``completed``
        when every vehicle that flew ended."""
        gone = [s for s in self.flown if self.vehicles[s].phase is not Phase.ENDED]
        if self.failure is not None or (self.flown and len(gone) == len(self.flown)):
            return "failed"
        return "degraded" if gone else "completed"

    def apply_envelope(self) -> Envelope:
        """Plan and shape every command within the tightest envelope of the
        readied vehicles (docs/vehicle-envelope.md); returns it."""
        env = Envelope()
        for vp in self.vehicles.values():
            if vp.phase is Phase.READY:
                env = env.tighter(vp.envelope)
        inforce = self.control.set_envelope(env)
        if inforce.bounded:
            self.note(f"envelope in force: {inforce.describe()}")
        return inforce

    def note(self, text: str, *, level: int = logging.INFO) -> None:
        """A line for the log (and the run's summary at INFO and above)."""
        _log.log(level, "%s", text)
        if level >= logging.INFO:
            self.log.append(text)
