"""``gcs-swarm run MISSION --shards N``: the controller of a sharded run
(docs/architecture.md, "Scaled out: shards").

``run_sharded`` is ``run_mission``'s twin for a station split in processes:
it starts the bundled emulators (one per network, as ``run_mission``),
listens for shards on a Zenoh endpoint (``runtime.zbus``; by default
``tcp/127.0.0.1:<free port>``), starts N shard processes on this machine
(``gcs-swarm shard --connect ENDPOINT``; with ``spawn=False`` it waits for
shards started elsewhere), gives each whole networks, waits until every
shard has readied its vehicles, starts the formation and runs the law
(``swarm.controller.ControllerCore``: with ``step: network`` a step per
state batch) until the mission's duration; then it sends every shard the
end action and gathers their reports into one ``RunSummary``. It always
ends the shards, also when cancelled (Ctrl-C) or when start-up fails.

With a run folder each shard logs its networks' frames, the controller its
notes (``controller.tlog``) and, at the end, the summary, the picture and
the vehicles' parameters (``runtime.run_report.ControllerLog``).

With the operator view each shard sends its vehicles' half of a frame
(``ShardedRun.views``) and the view merges them with the law's
(``gcs_swarm.view.sharded``).

Join/leave events and reserves are each run by the shard owning the
vehicle (``swarm.shard``); ``check_shards`` refuses the events a shard
cannot run as one station would (a rejoin after a leave, a join while
nobody of its shard flies). Not (yet) sharded: TIMESYNC delay compensation
(each shard predicts its own reports).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import sys
import time
from collections import deque
from collections.abc import Callable, Mapping
from contextlib import AbstractAsyncContextManager
from dataclasses import replace
from pathlib import Path
from typing import Any

from gcs_swarm.control.params import Envelope
from gcs_swarm.errors import LinkError, StartupError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mission import Mission
from gcs_swarm.report.artefacts import RunFolder, create_run_folder
from gcs_swarm.runtime import plans
from gcs_swarm.runtime.ending import EndRequest, unless_ended
from gcs_swarm.runtime.lifetime import reap
from gcs_swarm.runtime.plans import check_shards
from gcs_swarm.runtime.run_report import ControllerLog
from gcs_swarm.runtime.shard import BEAT_S
from gcs_swarm.runtime.summary import RunSummary
from gcs_swarm.runtime.worker import run_lookahead
from gcs_swarm.runtime.zbus import Bus, TlsFiles, check_endpoint, free_endpoint
from gcs_swarm.swarm.controller import ControllerCore
from gcs_swarm.swarm.departures import departure_terms
from gcs_swarm.swarm.shard_wire import decode_state, encode_reply, keep_out_from_json
from sim_vehicle import Emulator

__all__ = [
    "LOCKSTEP_BARRIER_S",
    "SHARD_VIEW_HZ",
    "ShardedRun",
    "ShardedView",
    "check_shards",
    "free_endpoint",
    "run_sharded",
]

_log = logging.getLogger("gcs_swarm.run")

LOCKSTEP_BARRIER_S = 10.0
"""A bundled lockstep emulator's wait for an answer in a sharded run [s]
(0.5 s in one process): a shard holds its READY vehicles' reports until
every shard is ready and the formation starts (``Station.hold_when_ready``),
and the emulator must wait as long, or its clock moves on unanswered and the
flight is no longer the one-process flight (measured: shards ready up to
0.9 s apart on a loaded 2-core machine). Lockstep semantics otherwise:
a dead shard's emulator then steps once per this wait."""

ShardedView = Callable[["ShardedRun", EndRequest], AbstractAsyncContextManager[object]]
"""An operator view's lifetime over a sharded run (``gcs_swarm.view.sharded``):
its frames merge the shards' (``ShardedRun.views``) with the controller's law."""

SHARD_VIEW_HZ = 10.0
"""How often each shard sends its part of the operator view [Hz], when open."""

_HANDSHAKE_S = 30.0
"""Wall time [s] for every shard to say hello (a process start and a Zenoh
session: about a second each on a loaded 2-core machine)."""


class ShardedRun:
    """The controller's shell: Zenoh in and out, one timer, the shards'
    handshake and reports (``run_sharded`` drives it)."""

    def __init__(self, bus: Bus, core: ControllerCore, assignment: list[dict[str, Any]]) -> None:
        self.bus = bus
        self.core = core
        self.assignment = assignment
        self.endpoint = ""
        self.processes: list[asyncio.subprocess.Process] = []
        """The shard processes this run started (their ids: ``pid``)."""
        self.tokens: dict[str, int] = {}
        self.pids: dict[int, int] = {}
        """Each shard's process id, as its hello said (shard index -> pid)."""
        self.emulators: dict[int, Emulator] = {}
        """The bundled emulators, by network index (the vehicles' side of a test)."""
        self.ready: dict[int, dict[str, Any]] = {}
        self.ready_at: dict[int, float] = {}
        """Loop time [s] each shard reported its vehicles READY."""
        self.failed: dict[int, str] = {}
        self.done: dict[int, dict[str, Any]] = {}
        self.droppable = True
        """Replies may be dropped on a congested link (real time: the next step
        brings one); never in lockstep, where nothing follows a lost one."""
        self._step_soon = False  # a real-time step waits for the loop's next turn
        self.bytes_per_step: dict[str, int] = {"state": 0, "batches": 0, "reply": 0, "steps": 0}
        """Bytes of state batches in (and the batches), replies out, and the steps they made."""
        self.flight_s: tuple[float, float] | None = None
        """Loop times [s] of the formation's start and of the mission's end."""
        self.origin: list[float] | None = None
        """The mission origin (latitude, longitude [deg], altitude [m]) as the
        shard owning the mission's first vehicle learned it; every beat tells
        every shard (a mission that names none: its first vehicle's EKF origin)."""
        self.views: dict[int, dict[str, Any]] = {}
        """Each shard's latest operator-view frame (its vehicles), when the view is open."""
        self.view_events: deque[dict[str, Any]] = deque(maxlen=2000)
        """The shards' view events (joins, leaves, their notes) not yet shown."""
        self.changed = asyncio.Event()
        self.finished = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None
        self.jobs: set[asyncio.Task[None]] = set()
        """Plane look-aheads running off the step (real time)."""

    def now(self) -> float:
        return self._loop.time()

    def listen(self) -> None:
        self.bus.subscribe("hello", self._on_hello)
        for i in range(len(self.assignment)):
            self.bus.subscribe(f"up/{i}/state", self._on_state)
            self.bus.subscribe(f"up/{i}/msg", self._on_msg)
            self.bus.subscribe(f"up/{i}/view", self._on_view)

    def _on_hello(self, key: str, data: bytes) -> None:
        hello = json.loads(data)
        token = str(hello["token"])
        index = self.tokens.get(token)
        if index is None:
            if len(self.tokens) >= len(self.assignment):
                return  # one shard too many: not answered
            index = self.tokens[token] = len(self.tokens)
            self.pids[index] = int(hello.get("pid", 0))
            _log.info("shard %d joined (token %s)", index, token)
        self.bus.put_json(f"assign/{token}", {"index": index, **self.assignment[index]})
        self.changed.set()

    def _on_view(self, key: str, data: bytes) -> None:
        frame = json.loads(data)
        self.views[int(key.split("/")[1])] = frame
        self.view_events.extend(frame.get("events", ()))

    def _on_state(self, key: str, data: bytes) -> None:
        batch = decode_state(data)
        self.bytes_per_step["state"] += len(data)
        self.bytes_per_step["batches"] += 1
        if self._declared_dead(batch.shard):
            return
        self.core.receive_state(batch, self.now())
        if not self.droppable:  # lockstep: each batch is stepped as it comes
            self._after()
        elif not self._step_soon:  # real time: batches queued behind it join its step
            self._step_soon = True  # (docs/architecture.md, "Scaled out: shards")
            asyncio.get_running_loop().call_soon(self._step_queued)

    def _step_queued(self) -> None:
        self._step_soon = False
        self._after()

    def _declared_dead(self, index: int) -> bool:
        """A shard declared dead that speaks again (a Zenoh link back after
        the stale timeout) is told to end its vehicles: it never rejoins."""
        view = self.core.shards.get(index)
        if view is None or view.alive:
            return False
        self.bus.put_json(f"down/{index}/ctl", {"kind": "end", "mode": None})
        return True

    def _on_msg(self, key: str, data: bytes) -> None:
        index = int(key.split("/")[1])
        msg = json.loads(data)
        kind = msg["kind"]
        if kind == "done":
            self.done[index] = msg
            self.changed.set()
            return
        if self.core.started and self._declared_dead(index):
            return
        now = self.now()
        if kind == "beat":
            kept, live = (keep_out_from_json(msg.get(k)) for k in ("keep_out", "keep_live"))
            self.core.heard(index, now, msg.get("flying"), kept, live)
            if self.origin is None and msg.get("origin") is not None:
                self.origin = [float(x) for x in msg["origin"]]
        elif kind == "ready":
            self.ready[index] = msg
            self.ready_at[index] = now
            self.core.heard(index, now)
        elif kind == "failed":
            self.failed[index] = str(msg["text"])
        self.changed.set()
        self._after()

    def _after(self) -> None:
        core = self.core
        if core.step_wanted:
            for reply in core.control_step(self.now()):
                data = encode_reply(reply)
                self.bytes_per_step["reply"] += len(data)
                self.bus.put(f"down/{reply.shard}/reply", data, droppable=self.droppable)
            self.bytes_per_step["steps"] += 1
        for job in core.lookahead:
            task = asyncio.ensure_future(run_lookahead(core, job, self.now))
            self.jobs.add(task)
            task.add_done_callback(self.jobs.discard)
        core.lookahead.clear()
        if core.timer_moved:
            core.timer_moved = False
            self._arm()
        if core.finished:
            self.finished.set()
        self.changed.set()  # wait_for looks again (a step, a dead shard)

    def _arm(self) -> None:
        due = self.core.get_timer()
        if self._timer is not None:
            if due is not None and self._timer_at is not None and self._timer_at <= due:
                return
            self._timer.cancel()
            self._timer = None
        if due is not None:
            self._timer_at = due
            self._timer = self._loop.call_at(due, self._on_timer, due)

    def _on_timer(self, due: float) -> None:
        self._timer = self._timer_at = None
        self.core.handle_timer(max(self.now(), due))
        self.core.timer_moved = True
        self._after()

    async def watch(self, proc: asyncio.subprocess.Process) -> None:
        """Wake ``wait_for`` when a shard process this run started exits."""
        await proc.wait()
        self.changed.set()

    def exited(self) -> str:
        """The shard processes of this run that have exited, with their codes
        ("" while none has): a start-up then fails at once, not after its
        timeout."""
        gone = [f"pid {p.pid} exit code {p.returncode}" for p in self.processes
                if p.returncode is not None]  # fmt: skip
        return ", ".join(gone)

    def status_line(self) -> str:
        """One line of the run's state (the command line's status)."""
        core = self.core
        alive = sum(v.alive for v in core.shards.values())
        return (f"t={core.control.t_s:6.2f} s  {len(core.flying)} flying on {alive}/"
                f"{len(core.shards)} shards  {core.control.steps} steps  "
                f"{core.fallbacks} fallback")  # fmt: skip

    async def status(self, on_status: Callable[[str], None], every_s: float = 1.0) -> None:
        while True:
            await asyncio.sleep(every_s)
            if self.core.started:
                on_status(self.status_line())

    async def beat(self) -> None:
        while True:
            core = self.core
            ctl = core.control.controller
            leader = ctl.leader_pos_m.tolist() if core.started else None
            vel = ctl.leader_vel_mps.tolist() if core.started else None
            radius = core.control.formation_radius_m() if core.started else None
            self.bus.put_json("down/all", {"kind": "beat", "origin": self.origin,
                                           "leader": leader, "leader_vel": vel,
                                           "radius": radius})  # fmt: skip
            await asyncio.sleep(BEAT_S)

    async def start(self, shards: int, hello_s: float, ready_timeout_s: float) -> None:
        """The start-up: every shard says hello within ``hello_s`` [s] and
        readies its vehicles within ``ready_timeout_s`` + 10 s, then the
        formation starts within the tightest of their envelopes.
        ``StartupError`` when a shard fails, exits or is late."""
        core, endpoint = self.core, self.endpoint
        if not await self.wait_for(lambda: len(self.tokens) == shards or bool(self.exited()),
                                   hello_s):  # fmt: skip
            raise StartupError(f"{len(self.tokens)} of {shards} shards said hello at "
                               f"{endpoint} in {hello_s:g} s{self.bus.hint()}")  # fmt: skip
        ready_s = ready_timeout_s + 10.0
        if not await self.wait_for(
            lambda: len(self.ready) + len(self.failed) == shards or bool(self.exited()), ready_s
        ):
            raise StartupError(f"{len(self.ready)} of {shards} shards ready in {ready_s:g} s")
        if self.exited() and not self.failed:
            raise StartupError(f"shard process exited during start-up: {self.exited()}")
        if self.failed:
            raise StartupError("; ".join(f"shard {i}: {t}" for i, t in sorted(self.failed.items())))
        env = Envelope()
        for msg in self.ready.values():
            env = env.tighter(Envelope(**msg["envelope"]))
        core.set_envelope(env)
        core.start(self.now(), {i: int(m["members"]) for i, m in self.ready.items()})
        self.bus.put_json("down/all", {"kind": "start"})
        self._after()

    async def flown(self) -> None:
        """Until the mission is over (its duration, a failure, every shard dead)."""
        await self.finished.wait()

    async def wait_for(self, what: Callable[[], bool], timeout_s: float) -> bool:
        """Until ``what()`` holds (True), or ``timeout_s`` has passed (False)."""
        try:
            async with asyncio.timeout(timeout_s):
                while not what():
                    self.changed.clear()
                    await self.changed.wait()
        except TimeoutError:
            return False
        return True


async def run_sharded(
    mission: Mission,
    shards: int,
    *,
    links: Mapping[int, str] | None = None,
    lockstep: bool | None = None,
    endpoint: str | None = None,
    tls: TlsFiles | None = None,
    spawn: bool = True,
    end_timeout_s: float = 15.0,
    log_dir: str | Path | None = None,
    picture: bool = True,
    on_folder: Callable[[RunFolder], None] | None = None,
    view: ShardedView | None = None,
    on_run: Callable[[ShardedRun], None] | None = None,
    on_status: Callable[[str], None] | None = None,
    on_summary: Callable[[RunSummary], None] | None = None,
    shm: bool = True,
) -> RunSummary:
    """Fly ``mission`` with ``shards`` link shards (module docstring) and
    return its summary. ``links`` and ``lockstep`` as ``run_mission``'s;
    ``endpoint`` where the controller listens (default: a free TCP port on
    127.0.0.1), with ``tls`` for a ``quic/`` or ``tls/`` one (``runtime.zbus``:
    mutual TLS); ``shm`` False sends every batch as bytes even to shards on
    this host (default: large ones in shared memory, ``zbus``); ``on_run``
    gets the live run (its core, its processes) once the shards are started;
    ``on_status`` a status line every second in flight; ``on_summary`` the
    summary, also when the run is cancelled or its start-up fails (the
    exception then propagates). With ``log_dir``
    the run gets a folder there as ``run_mission``'s (``on_folder`` gets it
    at once): each shard writes its networks' ``flight-<network>.tlog``,
    the controller its annotations (``controller.tlog``), the summary,
    the picture (unless ``picture`` is False) and the vehicles' parameters
    from the shards' reports; ``gcs-swarm report`` reads it as any.
    ``view`` is entered once the controller listens: its ``EndRequest``
    (the page's Hold, Land, Return) ends the run with that end action, as
    the mission's duration does (``gcs_swarm.view.sharded``). Raises
    ``UsageError`` when the mission cannot be sharded so, ``StartupError``
    when a shard cannot ready its vehicles (every shard then lands its
    airborne ones)."""
    check_shards(mission, shards)
    endpoint = check_endpoint(endpoint) if endpoint else None
    wall0 = time.monotonic()
    given = dict(links or {})
    sims = [v for v in mission.vehicles if v.is_sim and v.key not in given]
    if lockstep is None:
        lockstep = bool(sims) and mission.emulator.mode == "lockstep"
    s = mission.settings
    folder = None if log_dir is None else create_run_folder(mission, base_dir=log_dir)
    if folder is not None and on_folder is not None:
        on_folder(folder)
    log = ControllerLog(mission, folder)
    vs, terms = mission.vehicles, departure_terms
    departures = {v.key: terms(v.autopilot, plans.param_settings(mission, v),
                               s.startup.guid_timeout) for v in vs}  # fmt: skip
    core = ControllerCore(mission.law, {v.key: v.q for v in vs}, s.rate, shards=shards,
                          duration_s=s.duration, stale_timeout_s=s.stale_timeout,
                          lockstep=lockstep, recorder=log.recorder, departures=departures,
                          labels={v.key: mission.label(v.key) for v in vs},
                          step_per_network=plans.steps_per_network(mission, lockstep))  # fmt: skip
    outcome = "cancelled"
    emulators: dict[int, Emulator] = {}
    summary: RunSummary | None = None
    async with log, contextlib.AsyncExitStack() as stack:
        for j in sorted({v.net_index for v in sims}):
            cfg = plans.emulator_config(mission, network=j)
            if cfg.clock == "lockstep":
                cfg = replace(cfg, lockstep_timeout_s=LOCKSTEP_BARRIER_S)
            try:
                emu = await stack.enter_async_context(Emulator(cfg))
            except OSError as err:
                raise LinkError(f"bundled emulator on {cfg.host}: {err.strerror or err}") from None
            emulators[j] = emu
            for v in sims:
                if v.net_index == j:
                    host, port = emu.endpoints[v.sysid]
                    given[v.key] = f"udpout:{host}:{port}"
        for v in mission.vehicles:
            given.setdefault(v.key, v.link)
        nets = sorted({v.net_index for v in mission.vehicles})
        common = {"mission": mission.text, "source": mission.source, "lockstep": lockstep,
                  "links": {str(k): v for k, v in given.items()},
                  "end_timeout_s": end_timeout_s,
                  "view_hz": SHARD_VIEW_HZ if view is not None else 0.0}  # fmt: skip
        assignment = [
            {**common, "keys": [v.key for v in mission.vehicles if v.net_index in nets[i::shards]],
             "tlogs": log.tlogs(nets[i::shards])}
            for i in range(shards)
        ]  # fmt: skip
        bus = await stack.enter_async_context(
            Bus(listen=[endpoint], tls=tls, shm=shm)
            if endpoint
            else Bus.on_free_port(tls=tls, shm=shm)  # a port taken meanwhile: another one
        )
        endpoint = bus.listen[0]
        run = ShardedRun(bus, core, assignment)
        run.droppable = not lockstep
        run.endpoint = endpoint
        run.emulators = emulators
        run.listen()
        stack.callback(lambda: [job.cancel() for job in run.jobs])
        beating = asyncio.ensure_future(run.beat())
        stack.callback(beating.cancel)
        if on_status is not None:
            showing = asyncio.ensure_future(run.status(on_status))
            stack.callback(showing.cancel)
        if spawn:
            stack.push_async_callback(reap, run.processes, end_timeout_s + 5.0)
            for _ in range(shards):
                proc = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "gcs_swarm", "shard", "--connect", endpoint,
                    stdin=asyncio.subprocess.DEVNULL)  # fmt: skip
                run.processes.append(proc)
                watching = asyncio.ensure_future(run.watch(proc))
                stack.callback(watching.cancel)
        if on_run is not None:
            on_run(run)
        request = None if view is None else EndRequest()
        if view is not None and request is not None:
            await stack.enter_async_context(view(run, request))
        end_mode: int | None = None
        try:
            # Shards started elsewhere (by hand) get as long as a start-up does.
            hello_s = _HANDSHAKE_S if spawn else max(_HANDSHAKE_S, s.startup.ready_timeout)
            if not await unless_ended(request, run.start(shards, hello_s, s.startup.ready_timeout)):
                t_start = run.now()
                await unless_ended(request, run.flown())
                run.flight_s = (t_start, run.now())
                outcome = "flown"
            if core.failure is not None:
                end_mode = plans.END_MODES["hold"]
            elif request is not None and request.action is not None:
                end_mode = plans.END_MODES[request.action]  # the operator's button
                core.note(f"ending on the operator's request: {request.action}")
        except StartupError:
            outcome, end_mode = "startup failed", b.COPTER_MODES["LAND"]
            raise
        finally:
            core.end()
            bus.put_json("down/all", {"kind": "end", "mode": end_mode})
            # Every shard that joined and is neither dead nor exited reports once ended.
            expect = {i for i, v in core.shards.items() if v.alive and i in run.pids}

            def reported() -> bool:
                gone = {p.pid for p in run.processes if p.returncode is not None}
                return all(i in run.done or run.pids[i] in gone for i in expect)

            await run.wait_for(reported, end_timeout_s + 5.0)
            summary = RunSummary.from_controller(
                core, run.done, mission, outcome=outcome, wall_time_s=time.monotonic() - wall0
            )
            summary = replace(summary, logging_error=log.error(run.done.values()))
            await log.close(summary, run.done.values(), picture=picture, commanded=bool(run.pids))
            if on_summary is not None:  # also when cancelled or the start-up failed
                on_summary(summary)
    assert summary is not None  # the ending above ran
    return summary
