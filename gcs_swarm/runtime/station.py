"""The ground station's asyncio shell: sockets, one timer, the TaskGroup.

``Station`` is one ``async with`` lifetime owning one ``asyncio.TaskGroup``
(heartbeat, control loop, status line, TIMESYNC, look-ahead workers) and its
links (STYLE.md habit 7). The swarm's rules are ``gcs_swarm.swarm.SwarmCore``
(membership, join/leave, events, the mission origin, when a step runs,
ending, outcome); this shell feeds it what the links decode with the loop's
time, sends what it queued, arms one ``loop.call_at`` timer at its
``get_timer()`` (habit 1), runs its control step when it wants one, and
waits on its phases in ``ready()`` and ``end()``.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
from collections import Counter, deque
from collections.abc import Callable
from types import TracebackType
from typing import Any

from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.params import Envelope
from gcs_swarm.errors import StartupError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import MessageSpec
from gcs_swarm.mavlink.states import FINAL_PHASES, Phase, describe_states, state_words
from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.mavlink.vehicle import VehicleProtocol
from gcs_swarm.report.record import FlightRecorder
from gcs_swarm.runtime.config import StationConfig, VehiclePlan
from gcs_swarm.runtime.delay import DelayCompensator
from gcs_swarm.runtime.lifetime import close_task_group
from gcs_swarm.runtime.links import Link
from gcs_swarm.runtime.worker import run_lookahead
from gcs_swarm.swarm.core import SwarmCore
from gcs_swarm.swarm.handshakes import held
from gcs_swarm.swarm.link_state import OnFrame
from gcs_swarm.swarm.status import StatusLine
from gcs_swarm.swarm.step import SetpointBatch, Write

__all__ = ["Station", "StationConfig", "VehiclePlan"]

_log = logging.getLogger("gcs_swarm.station")

_LATE_S = 0.05
"""A timer this late [s] means the process was stalled."""
_GRACE_TURNS = 4
"""Event-loop turns a late timer waits, so that datagrams that arrived during
the stall are read first (microseconds: nothing is delayed noticeably)."""


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
        on_frame_for: Callable[[str], OnFrame | None] | None = None,
        control_step: Callable[[float, Write], None] | None = None,
    ) -> None:
        """``recorder`` receives every control step, membership change and
        received message (the run's flight record); ``on_frame`` every raw
        frame in and out on every link (the ``.tlog``), or ``on_frame_for``
        gives each link's own (by connection string: one ``.tlog`` per
        network). ``control_step(now, write)`` replaces the core's when a
        step is wanted (a link shard sends its states to its controller
        instead: ``runtime.shard``)."""
        self._on_frame_for = on_frame_for
        self.config = config
        self.on_status = on_status
        self.recorder = recorder
        self._on_frame = on_frame
        self.status_interval_s = status_interval_s
        self.delay: DelayCompensator | None = None
        if config.delay_compensation and not config.lockstep:
            self.delay = DelayCompensator(config.predict_accel_max_mps2)
        self.core = SwarmCore(config, recorder=recorder, delay=self.delay)
        self._control_step = control_step or self.core.control_step
        self.on_step: Callable[[], None] | None = None
        """Called after each control step, once its setpoints are written (the
        operator view builds its next frame then, while the loop waits for the
        next round of telemetry: docs/operator-view.md)."""
        self._status = StatusLine()
        self._links: dict[str, Link] = {}
        self._timer: tuple[float, asyncio.Handle] | None = None
        self._tg = asyncio.TaskGroup()
        self._stack = contextlib.AsyncExitStack()
        self._tasks: list[asyncio.Task[None]] = []
        self._changed = asyncio.Event()
        self._step = asyncio.Event()
        self._finished = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._froze = False
        self.hold_when_ready = False
        """Hold the inbound messages once every vehicle is READY, until
        ``release`` (a lockstep link shard waiting for its controller's
        start: the emulator's clock then waits too, so the formation starts
        at the vehicle time an unsharded station starts it). The core's
        timers wait as well: the vehicles are silent because they are held."""
        self._held: list[tuple[Any, Link, float]] | None = None

    # The core's figures, as the station's (run summary, tests, benchmarks).
    @property
    def vehicles(self) -> dict[int, VehicleProtocol]:
        return self.core.vehicles

    @property
    def control(self) -> ControlLoop:
        return self.core.control

    @property
    def table(self) -> TelemetryTable:
        return self.core.table

    @property
    def plans(self) -> dict[int, VehiclePlan]:
        return self.core.plans

    @property
    def members(self) -> set[int]:
        return self.core.members

    @property
    def flying(self) -> set[int]:
        return self.core.flying

    @property
    def flown(self) -> set[int]:
        return self.core.flown

    @property
    def left(self) -> set[int]:
        return self.core.left

    @property
    def unknown_sysids(self) -> Counter[int]:
        return self.core.unknown_sysids

    @property
    def reports_in(self) -> int:
        return self.core.reports_in

    @property
    def reports_waiting(self) -> int:
        """Reports accepted since the last control step (answered at the next)."""
        return self.core.reports_waiting

    @property
    def log(self) -> deque[str]:
        return self.core.log

    @property
    def started(self) -> bool:
        return self.core.started

    @property
    def ending(self) -> bool:
        return self.core.ending

    @property
    def failure(self) -> str | None:
        """Why the law could not go on in flight (the mission then ends as failed)."""
        return self.core.failure

    @property
    def links(self) -> dict[str, Link]:
        return dict(self._links)

    def now(self) -> float:
        assert self._loop is not None
        return self._loop.time()

    # ------------------------------------------------------------ lifetime
    async def __aenter__(self) -> Station:
        self._loop = asyncio.get_running_loop()
        try:
            for key in self.core.links:
                served = [p.sysid for p in self.config.vehicles if p.link == key]
                on_frame = self._on_frame
                if self._on_frame_for is not None:
                    on_frame = self._on_frame_for(key)
                link = Link(key, self._on_message, on_frame=on_frame,
                            base=self.core.base_of[key],
                            telemetry=self.core.table,
                            on_telemetry=self._on_telemetry,
                            signing_key=self.config.signing_key, sysids=served,
                            allow_rebind=self.config.allow_rebind,
                            on_notice=self.warn)  # fmt: skip
                self._links[key] = await self._stack.enter_async_context(link)
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
        if self._timer is not None:
            self._timer[1].cancel()
            self._timer = None
        try:
            await close_task_group(self._tg, self._tasks, et, ev, tb)
        finally:
            await self._stack.aclose()

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
                            _not_ready("could not be readied", failed), _reasons(failed)
                        )
                    if all(vp.phase is Phase.READY for vp in everyone):
                        return
                    await self._wait_change()
        except TimeoutError:
            late = [vp for vp in everyone if vp.phase is not Phase.READY]
            what = f"not ready after {self.config.ready_timeout_s:g} s"
            raise StartupError(_not_ready(what, late), _reasons(late)) from None

    def apply_envelope(self) -> Envelope:
        """Plan and shape every command within the tightest envelope of the
        readied vehicles (each read from its parameters, or the mission's
        where it was not read: docs/vehicle-envelope.md); call between
        ``ready()`` and ``fly()``. Returns the envelope in force."""
        return self.core.apply_envelope()

    def warn(self, text: str) -> None:
        """A line for the log and the summary, at warning level."""
        self.core.note(text, level=logging.WARNING)

    async def fly(self) -> None:
        """Start the formation and return when the mission time is over (or
        nobody is left to fly)."""
        # The cyclic garbage collector's full passes over the start-up heap
        # (mission, numpy, pymavlink's dialect) took up to 29 ms and 6 ms for
        # generation 1 (measured at 250 vehicles): a stalled setpoint stream.
        # Collect once now, while the vehicles hold at their start points, and
        # freeze what is left so that later passes scan only the flight's own
        # objects; ``__aexit__`` unfreezes.
        self.begin()
        await self._finished.wait()

    def begin(self) -> None:
        """Start the formation now (``fly`` without waiting for its end)."""
        self.freeze_heap()
        self.core.start(self.now())
        self._after()

    def freeze_heap(self) -> None:
        """The start-up heap collected once and frozen (``fly``'s comment), if
        not yet: a link shard does it before it says READY, so that its start
        (``begin``) is not later than the other shards' by the collection."""
        if not self._froze:
            gc.collect()
            gc.freeze()
            self._froze = True

    def apply(self, work: Callable[[float, Write], None]) -> None:
        """``work(now, write)`` on the core from outside (a controller's
        setpoints arriving at a shard), then what the core asks for."""
        work(self.now(), self._write)
        self._after()

    async def end(self, mode: int | None = None) -> None:
        """Zero acceleration and the end mode for everyone, confirmed by heartbeat.
        A started formation's last figures go out as one more status line first
        (a run shorter than the status interval would otherwise show none)."""
        core = self.core
        if core.started and not core.ending and self.on_status is not None:
            self.on_status(self.status_line())
        core.finish_all(self.now(), mode)
        self._after()
        settled = {Phase.ENDED, Phase.FAILED, Phase.LOST, Phase.CONNECTING}

        def busy(vp: VehicleProtocol) -> bool:  # still ending, or restoring its parameters
            return vp.phase not in settled or vp.restoring

        try:
            async with asyncio.timeout(self.config.end_timeout_s):
                while any(busy(vp) for vp in self.vehicles.values()):
                    await self._wait_change()
        except TimeoutError:
            late = [vp for vp in self.vehicles.values() if busy(vp)]
            core.note(_not_ready("end mode not confirmed", late), level=logging.ERROR)

    # ----------------------------------------------------------- messages
    def _on_message(self, msg: Any, link: Link) -> None:
        if self._held is not None:
            self._held.append((msg, link, link.rx_time_s))
            return
        self.core.receive(msg, link.connection, self.now(), link.rx_time_s)
        self._after()

    def release(self) -> None:
        """Hand the core what ``hold_when_ready`` held, in arrival order, then
        the timers it deferred (after the messages: a vehicle held longer than
        its stale timeout is not LOST for the station's own wait)."""
        held, self._held = self._held, None
        self.hold_when_ready = False
        for msg, link, rx_s in held or ():
            self.core.receive(msg, link.connection, self.now(), rx_s)
            self._after()
        if held is not None:
            self.core.timer_moved = True
            self._after()

    def _on_telemetry(self, link: Link) -> None:
        core = self.core
        core.telemetry_written(self.now())
        if core.outbound or core.step_wanted or core.timer_moved or core.changed:
            self._after()

    def _after(self) -> None:
        """Carry out what the core asks for after a call: its messages to
        their links, a step, the timer, a wake-up of ``ready``/``end``."""
        core = self.core
        if core.outbound:
            out, core.outbound = core.outbound, []
            links = self._links
            for key, spec, sysid in out:
                links[key].send(spec, sysid)
        if core.step_wanted:
            self._step.set()
        if core.timer_moved:
            core.timer_moved = False
            self._arm_timer()
        if core.changed:
            core.changed = False
            self._changed.set()
            if self.hold_when_ready and self._held is None:
                if all(vp.phase is Phase.READY for vp in self.vehicles.values()):
                    self._held = []
        if core.finished:
            self._finished.set()

    # --------------------------------------------------------------- timer
    def _arm_timer(self) -> None:
        """One ``call_at`` at the core's ``get_timer()``; an earlier one armed
        stands (firing early is harmless: the core acts on what is due)."""
        due = self.core.get_timer()
        old = self._timer
        if old is not None:
            if due is not None and old[0] <= due:
                return
            old[1].cancel()
            self._timer = None
        if due is not None and self._loop is not None:
            self._timer = (due, self._loop.call_at(due, self._on_timer, due))

    def _on_timer(self, due: float, turns: int = 0) -> None:
        assert self._loop is not None
        if turns < _GRACE_TURNS and self.now() - due > _LATE_S:
            # Fired late: the process was stalled (a loaded machine, the garbage
            # collection in ``fly``). What the vehicles sent meanwhile is read
            # first, a few loop turns on, or a vehicle would look stale because
            # the station itself stopped (issue 15 item 12).
            self._timer = (due, self._loop.call_soon(self._on_timer, due, turns + 1))
            return
        self._timer = None
        if self._held is not None:
            # Holding (``hold_when_ready``): the vehicles' clock waits with their
            # reports, so their protocols' watchdogs wait too; ``release`` re-arms.
            return
        # call_at may fire up to one clock resolution early: never hand the
        # core a time before the deadline it asked for.
        self.core.handle_timer(max(self.now(), due))
        self.core.timer_moved = True  # the next deadline, whatever it is
        self._after()

    # --------------------------------------------------------- control loop
    async def _control_task(self) -> None:
        while True:
            await self._step.wait()
            self._step.clear()
            self._control_step(self.now(), self._write)
            if self.on_step is not None:
                self.on_step()
            for job in self.core.lookahead:
                self._tasks.append(self._tg.create_task(run_lookahead(self.core, job, self.now)))
            self.core.lookahead.clear()
            self._after()

    def _write(self, key: str, batch: SetpointBatch | None) -> None:
        link = self._links[key]
        if batch is None:
            link.flush()
        else:
            link.send_accel_setpoints(*batch)

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
            self.core.check_alive(self.now())
            self._after()

    def status_line(self) -> str:
        """One line with the run's figures as they evolve (``swarm.status``)."""
        drops = sum(link.stats.setpoints_dropped for link in self._links.values())
        return self._status.line(self.core, self.now(), drops, self.rebinds_refused())

    def clipped_setpoints(self) -> int:
        """Setpoints scaled down to the ceiling or zeroed (non-finite), all vehicles."""
        return sum(vp.clipped_setpoints for vp in self.vehicles.values())

    def rebinds_refused(self) -> dict[int, int]:
        """Frames refused per vehicle because they came from another address
        than the one it is bound to (``Link.rebinds_refused``), by vehicle key
        (network index * 256 + system id, ``mission.vehicle_key``)."""
        total: Counter[int] = Counter()
        for link in self._links.values():
            base = link.state.base
            total.update({s + base: n for s, n in link.rebinds_refused.items()})
        return dict(sorted(total.items()))

    # ---------------------------------------------------------------- misc
    async def _wait_change(self) -> None:
        self._changed.clear()
        await self._changed.wait()

    def outcome(self) -> str:
        """The run's outcome once ``end()`` has returned (``SwarmCore.outcome``)."""
        return self.core.outcome()

    def setpoint_latencies_s(self) -> list[float]:
        """Recent telemetry-arrival-to-setpoint-write times [s] of every link
        (each link keeps its last ``LatencyRing`` size samples)."""
        return [x for link in self._links.values() for x in link.latency.samples()]

    def phases(self) -> dict[int, Phase]:
        return {s: vp.phase for s, vp in self.vehicles.items()}

    def final(self) -> bool:
        return all(vp.phase in FINAL_PHASES for vp in self.vehicles.values())


def _not_ready(what: str, vps: list[VehicleProtocol]) -> str:
    return describe_states(what, [(vp.label, _words(vp)) for vp in vps])


def _reasons(vps: list[VehicleProtocol]) -> dict[int, str]:
    """``StartupError.reasons``: each vehicle's phase, and its failure in its own words."""
    return {vp.sysid: _words(vp) for vp in vps}


def _words(vp: VehicleProtocol) -> str:
    if held(vp):  # by mission.startup.handshakes_per_network
        return state_words(vp.phase, "heard, waiting for a handshake place on its network")
    return state_words(vp.phase, vp.failure)
