"""The emulator process: asyncio endpoints hosting many vehicles, the clock, lockstep.

Owns ``Emulator``, a thin asyncio shell (an ``async with`` lifetime owning one
``asyncio.TaskGroup``, every socket and the clock task) around
``core.EmulatorCore``, which holds the vehicles and everything they do without
I/O (delivery, impairments, the physics step, telemetry scheduling). The clock
task steps the core in real time or in lockstep; the lockstep rule is written
in the ``sim_vehicle`` package docstring, its tests on the fleet are
``lockstep``, and the waiting is ``_lockstep_wait`` here with ``_step_now``
(the datagram that brings the last answer takes the step at once, without
waking the clock task).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

import numpy as np

from sim_vehicle import lockstep, signing
from sim_vehicle.config import EmulatorConfig, Impairment, VehicleSpec
from sim_vehicle.core import EmulatorCore
from sim_vehicle.fleet import Fleet
from sim_vehicle.impairments import Impairer
from sim_vehicle.lane import MIN_BYTES, may_be_stream, take_stream
from sim_vehicle.link import Addr, Endpoint, TcpPort, bind_udp
from sim_vehicle.stats import EmulatorStats
from sim_vehicle.vehicles import HostedVehicle, VehicleState

__all__ = ["Emulator", "EmulatorStats", "VehicleState"]


class Emulator:
    """Many emulated ArduCopters in one process. Use as ``async with Emulator(cfg) as emu``."""

    def __init__(self, config: EmulatorConfig) -> None:
        self.config = config
        self.core = EmulatorCore(config)
        self.dt = self.core.dt
        self._lockstep = config.clock == "lockstep"
        self._shared: Endpoint | None = None
        self._added = 0
        self._waiters: list[tuple[Callable[[], bool], asyncio.Future[None]]] = []
        self._wake = asyncio.Event()
        self._tg: asyncio.TaskGroup | None = None
        self._clock_task: asyncio.Task[None] | None = None
        # Lockstep: while the clock waits for answers, the datagram that brings the last
        # one takes the step itself (``_step_now``); ``_last`` is the wall time of the
        # last step, ``_handed_back`` tells the clock a step was taken meanwhile.
        self._stepping = False
        self._handed_back = False
        self._last = 0.0
        self._error: BaseException | None = None

    @property
    def stats(self) -> EmulatorStats:
        """Counters (steps, lockstep timeouts, late steps, link)."""
        return self.core.stats

    @property
    def fleet(self) -> Fleet:
        """The vectorised rows of every vehicle."""
        return self.core.fleet

    @property
    def sim_time_s(self) -> float:
        """Sim time [s]: ``step_count * dt``."""
        return self.core.sim_time_s

    @property
    def step_count(self) -> int:
        """Physics steps taken."""
        return self.core.step_count

    # ------------------------------------------------------------ lifetime
    async def __aenter__(self) -> Emulator:
        self._tg = asyncio.TaskGroup()
        await self._tg.__aenter__()
        try:
            cfg = self.config
            if cfg.shared_port is not None:
                self._shared = await self._open_endpoint(cfg.shared_port, shared=True, key=0)
            for spec in cfg.vehicles:
                await self._add(spec, initial=True)
            self._clock_task = self._tg.create_task(self._clock())
        except BaseException:
            # No task runs yet (the clock starts last): close what was opened
            # and let the error out as it is (an OSError, not an ExceptionGroup).
            self._close_all()
            await self._tg.__aexit__(None, None, None)
            raise
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        assert self._tg is not None
        self._stepping = False
        try:
            if self._clock_task is not None:
                self._clock_task.cancel()
        finally:
            self._close_all()
            # An error of the body propagates as itself, not wrapped in an ExceptionGroup;
            # a cancellation is passed on so the TaskGroup can account for it.
            if exc_type is not None and issubclass(exc_type, asyncio.CancelledError):
                await self._tg.__aexit__(exc_type, exc, tb)
            else:
                await self._tg.__aexit__(None, None, None)

    def _close_all(self) -> None:
        for ep in self.core.ports:
            ep.close()
        self.core.ports.clear()
        for _pred, fut in self._waiters:
            if not fut.done():
                fut.set_exception(RuntimeError("emulator stopped"))
        self._waiters.clear()

    async def _open_endpoint(
        self, port: int, shared: bool, key: int, tcp_port: int | None = None
    ) -> Endpoint:
        cfg = self.config
        ss = np.random.SeedSequence([cfg.seed, key, 7])
        up, down = (np.random.default_rng(s) for s in ss.spawn(2))
        sock = bind_udp(cfg.host, port)
        ep = Endpoint(
            sock=sock,
            shared=shared,
            uplink=Impairer(cfg.uplink, up),
            downlink=Impairer(cfg.downlink, down),
            on_datagram=self._on_datagram,
            stats=self.core.stats.link,
            out=cfg.out,
            signing_key=cfg.signing_key,
            # a network's setpoints together (lane.take_stream); real time only
            on_datagrams=self._on_datagrams if shared and not self._lockstep else None,
        )
        loop = asyncio.get_running_loop()
        await loop.create_datagram_endpoint(lambda: ep, sock=sock)
        self.core.ports.append(ep)
        if tcp_port is not None:
            try:
                tcp = TcpPort(ep, self._on_tcp_messages, self._on_tcp_peer)
                await tcp.start(cfg.host, tcp_port)
            except BaseException:
                self.core.ports.remove(ep)
                ep.close()
                raise
            ep.tcp = tcp
        return ep

    # ------------------------------------------------------------ vehicles
    @property
    def endpoints(self) -> dict[int, Addr]:
        """Vehicle key (its system id unless ``VehicleSpec.vid`` is set) -> (host, port)."""
        return {s: _endpoint(v).address for s, v in self.core.vehicles.items()}

    @property
    def tcp_endpoints(self) -> dict[int, Addr]:
        """Vehicle key -> (host, port) of its TCP server (``EmulatorConfig.tcp_base_port``);
        connect with ``tcp:HOST:PORT``."""
        eps = {s: _endpoint(v) for s, v in self.core.vehicles.items()}
        return {s: ep.tcp.address for s, ep in eps.items() if ep.tcp is not None}

    async def add_vehicle(self, spec: VehicleSpec) -> Addr:
        """Add a vehicle while running; returns the address it is served on."""
        return _endpoint(await self._add(spec, initial=False)).address

    async def _add(self, spec: VehicleSpec, initial: bool) -> HostedVehicle:
        cfg = self.config
        key = spec.key
        if key in self.core.vehicles:
            raise ValueError(f"vehicle {key} is already hosted")
        if self._shared is not None and spec.sysid in self._shared.sysids:
            raise ValueError(f"sysid {spec.sysid} is already served on the shared endpoint")
        index = self._added
        self._added += 1
        if self._shared is not None:
            ep = self._shared
        else:
            port = spec.port
            if port is None:
                step = 1 if spec.autopilot == "px4" else 10
                port = cfg.base_port + step * index if cfg.base_port else 0
            tcp = cfg.tcp_base_port
            tcp_port = None if tcp is None else (tcp + 10 * index if tcp else 0)
            ep = await self._open_endpoint(port, shared=False, key=key, tcp_port=tcp_port)
        enc = signing.mavlink(spec.sysid, spec.compid, cfg.signing_key)
        return self.core.add(spec, ep, initial, enc)

    def set_impairment(self, uplink: Impairment, downlink: Impairment) -> None:
        """Change every link's impairments from now on (each keeps its seeded
        random stream), e.g. to fly lossy links after a clean start-up."""
        for ep in self.core.ports:
            ep.uplink.imp = uplink
            ep.downlink.imp = downlink

    def set_silent(self, sysid: int, silent: bool = True) -> None:
        """Switch vehicle ``sysid``'s radio off (``silent``) or on again: while
        silent it neither sends nor hears anything but keeps flying (its own
        GUID_TIMEOUT brakes it); back on, it sends a HEARTBEAT at once. Only
        for a vehicle on its own endpoint."""
        v = self.core.vehicle(sysid)
        if v.ep.shared:
            raise ValueError("set_silent needs a vehicle on its own endpoint, not a shared one")
        self.core.set_silent(v, silent)
        self._wake.set()

    def remove_vehicle(self, sysid: int) -> None:
        """Stop serving ``sysid`` (its own endpoint is closed)."""
        v = self.core.remove(sysid)
        if not v.ep.shared:
            ep = _endpoint(v)
            ep.close()
            self.core.ports.remove(ep)
        self._wake.set()

    def vehicle_state(self, sysid: int) -> VehicleState:
        """Snapshot of one vehicle."""
        v = self.core.vehicle(sysid)
        ep = _endpoint(v)
        tcp = ep.tcp.address if ep.tcp is not None else None
        return self.core.snapshot(v, ep.address, tcp)

    def set_param(self, sysid: int, name: str, value: float) -> None:
        """Set a parameter directly (as PARAM_SET would, without a reply)."""
        self.core.set_param(self.core.vehicle(sysid), name, value)

    # ------------------------------------------------------------- waiting
    async def wait_until(self, predicate: Callable[[], bool]) -> None:
        """Return once ``predicate()`` is true (checked now and after every step)."""
        if predicate():
            return
        fut: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._waiters.append((predicate, fut))
        await fut

    async def wait_steps(self, n: int) -> None:
        """Return after ``n`` more physics steps."""
        target = self.step_count + n
        await self.wait_until(lambda: self.step_count >= target)

    def _notify(self) -> None:
        keep = []
        for pred, fut in self._waiters:
            if fut.done():
                continue
            if pred():
                fut.set_result(None)
            else:
                keep.append((pred, fut))
        self._waiters = keep

    # ------------------------------------------------------------ inbound
    def _on_datagram(self, ep: Endpoint, data: bytes, addr: Addr) -> None:
        if not self._stepping:
            self._receive(ep, data, addr)
            return
        self._receive(ep, data, addr)
        if not self._blocked():  # lockstep rule 3: the last answer is in, step now
            self._step_now()

    def _on_datagrams(self, ep: Endpoint, batch: list[tuple[bytes, Addr]]) -> None:
        """A shared endpoint's datagrams read together (``Endpoint.on_datagrams``;
        real time: no step comes between them), in order: each peer's run of
        the stream's datagrams, of at least ``lane.MIN_BYTES``, first offered
        to ``lane.take_stream``; the rest (or all, if it declines) one by one."""
        i = 0
        while i < len(batch):
            addr = batch[i][1]
            j = i + 1
            while j < len(batch) and batch[j][1] == addr:
                j += 1
            grams = [data for data, _ in batch[i:j]]
            k = len(grams)  # the stream's datagrams (the read ends at the first that is not)
            while k and not may_be_stream(grams[k - 1]):
                k -= 1
            if sum(map(len, grams[:k])) >= MIN_BYTES and take_stream(
                self.core, ep, grams[:k], addr
            ):
                if not self._stepping:  # as _receive_msgs
                    self._wake.set()
                grams = grams[k:]
            for data in grams:
                self._on_datagram(ep, data, addr)
            i = j

    def _step_now(self) -> None:
        """Take the lockstep step the clock task waits for, here (no task switch); hand
        the clock back to the task when the step leaves nobody blocking."""
        try:
            self._step()
        except BaseException as exc:  # the clock task raises it, as its own step would
            self._error = exc
            self._stepping = False
            self._wake.set()
            return
        self._last = asyncio.get_running_loop().time()
        if not self._blocked():
            self._stepping = False
            self._handed_back = True
            self._wake.set()

    def _on_tcp_peer(self, ep: Endpoint, addr: Addr, up: bool) -> None:
        """A TCP client connected (a new peer: HEARTBEAT at once, lockstep rule 1, as SITL
        starts when something connects) or went away. With signing, a connection is no
        peer yet: its first well-signed frame makes it one, as on UDP (``core.receive``)."""
        if not up:
            ep.peers.pop(addr, None)
            return
        if ep.signing_key is not None:
            return
        ep.peers[addr] = None
        self.core.greet(ep, addr)
        self._wake.set()

    def _on_tcp_messages(self, ep: Endpoint, msgs: list[Any], addr: Addr) -> None:
        if not self._stepping:
            self._receive_msgs(ep, msgs, addr)
            return
        self._receive_msgs(ep, msgs, addr)
        if not self._blocked():  # lockstep rule 3, as for a datagram
            self._step_now()

    def _receive(self, ep: Endpoint, data: bytes, addr: Addr) -> None:
        if ep.silent:
            return
        self._receive_msgs(ep, ep.parse(data, raw=True), addr)

    def _receive_msgs(self, ep: Endpoint, msgs: list[Any], addr: Addr) -> None:
        if ep.silent:
            return
        if not self._stepping:  # the clock is blocked: only a step may change that
            self._wake.set()
        # lockstep: the autopilot handling it is told the wall clock (Autopilot.wall_s)
        self.core.receive(ep, msgs, addr, time.monotonic() if self._lockstep else None)

    # --------------------------------------------------------------- clock
    def _step(self, emit: bool = True) -> None:
        """One physics step of the core, then the waiters whose condition now holds
        (``emit=False``: the physics alone, ``_run_realtime``'s overrun)."""
        self.core.step(time.monotonic if self._lockstep else None, emit=emit)
        self._notify()

    def _blocked(self) -> bool:
        return lockstep.blocked(self.core.fleet)

    async def _clock(self) -> None:
        self.core.emit(0.0, time.monotonic if self._lockstep else None)
        if self.config.clock == "lockstep":
            await self._run_lockstep()
        else:
            await self._run_realtime()

    async def _run_realtime(self) -> None:
        """Steps at ``speedup`` x the wall clock. Behind it (the loop was
        held), the steps whose time has passed are taken at once, each with
        its messages (``overrun`` ``"catch_up"``: as SITL's simulated clock
        catches up, exact in sim time, a burst in wall time). With
        ``"skip"``, each of them that the next step is already due behind
        is the physics alone (an overrun: the world went on, the autopilots'
        loops did not run), and the last runs the autopilots once, at its
        time: each stream goes once, as an autopilot whose loop overran
        sends it (ArduCopter 4.5.6 ``GCS_MAVLINK::update_send``: a message
        more than an interval late is sent once and rescheduled from now,
        "we do not want to try to catch up too much"; ``schedule.due_reports``),
        not once per step missed, reports of one vehicle a few microseconds
        apart. ``late_steps`` counts the steps more than a period late,
        ``overrun_steps`` those taken as physics alone."""
        loop = asyncio.get_running_loop()
        period = self.dt / self.config.speedup
        skip = self.config.overrun == "skip"
        t0, k0 = loop.time(), self.step_count
        if self.config.start_at_s is not None:  # the first step then (loop.time is monotonic)
            t0 = self.config.start_at_s - period
        while True:
            due = t0 + (self.step_count - k0 + 1) * period
            delay = due - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                if delay < -period:
                    self.stats.late_steps += 1
                if delay < -1.0:  # hopelessly behind: drop the backlog, keep pacing
                    t0, k0 = loop.time(), self.step_count
                    due = loop.time()
                await asyncio.sleep(0)
            # "skip": a step the next is due behind already is the physics alone
            self._step(emit=not skip or loop.time() - due <= period)

    async def _run_lockstep(self) -> None:
        loop = asyncio.get_running_loop()
        period = self.dt / self.config.speedup
        vehicles = self.core.vehicles
        while not lockstep.started(v.contacted for v in vehicles.values() if v.initial):
            self._wake.clear()
            await self._wake.wait()
        self._last = loop.time()
        while True:
            if self._blocked():  # _lockstep_wait yields: no extra pass of the event loop
                if not await self._lockstep_wait(blocked=True):
                    continue  # steps were taken meanwhile; the last left nobody blocking
            else:
                await asyncio.sleep(0)  # let inbound datagrams in between two steps
                if self.fleet.holding.any():
                    if not await self._lockstep_wait():
                        continue
                else:  # rule 4: nobody holds, pace at speed-up x wall clock
                    await asyncio.sleep(lockstep.pace_delay(self._last, period, loop.time()))
            self._step()
            self._last = loop.time()

    async def _lockstep_wait(self, blocked: bool = False) -> bool:
        """Rules 2-3: wait until no holding vehicle blocks, or the wall-clock timeout
        (``blocked``: the caller has just found that one does). True: the caller takes
        the step. False: the datagrams that brought the answers took the steps
        (``_step_now``) and the last left nobody blocking; the caller starts over."""
        loop = asyncio.get_running_loop()
        if not blocked and not self._blocked():
            return True
        timeout = self.config.lockstep_timeout_s
        # One timer for many steps: it only wakes the loop below, which arms it again
        # from the latest step when steps were taken meanwhile.
        fired: list[bool] = []

        def expire() -> None:
            fired.append(True)
            self._wake.set()

        armed = self._last
        timer = loop.call_at(armed + timeout, expire)
        self._handed_back = False
        self._stepping = True
        try:
            while True:
                self._wake.clear()
                await self._wake.wait()
                if self._error is not None:
                    raise self._error
                if self._handed_back:
                    return False
                if not self._blocked():
                    return True
                if fired and armed != self._last:  # steps were taken: time from the last
                    fired.clear()
                    armed = self._last
                    timer = loop.call_at(armed + timeout, expire)
                elif fired or self._last + timeout - loop.time() <= 0:
                    # Before calling it a timeout, let the loop turn a few times:
                    # after a stall of the whole process (a loaded machine, a
                    # garbage collection) the answer may still be unread in a
                    # socket, or one task switch away in the station.
                    for _ in range(lockstep.GRACE_TURNS):
                        await asyncio.sleep(0)
                        if self._handed_back or not self._blocked() or self._error:
                            break
                    if self._error is not None:
                        raise self._error
                    if self._handed_back:
                        return False
                    if not self._blocked():
                        return True
                    if armed != self._last:  # steps were taken meanwhile: time from the last
                        fired.clear()
                        armed = self._last
                        timer.cancel()
                        timer = loop.call_at(armed + timeout, expire)
                        continue
                    self.stats.lockstep_timeouts += 1
                    return True
        finally:
            self._stepping = False
            timer.cancel()


def _endpoint(v: HostedVehicle) -> Endpoint:
    """The endpoint (socket) a vehicle is served on: the shell opened every port."""
    ep = v.ep
    assert isinstance(ep, Endpoint)
    return ep
