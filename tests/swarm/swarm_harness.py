"""The station's core against the emulator's core, in one process, on one
hand-advanced clock (aioquic's client/server ``transfer`` in its tests).

Station side: ``gcs_swarm.swarm.SwarmCore`` behind one listening
``LinkState`` per network (every vehicle of a network on one ``udpin``
link, each from its own address, as MAVProxy or a radio bridge would).
Vehicle side: the emulator's own I/O-free ``sim_vehicle.core.EmulatorCore``,
one per network (the autopilots, ArduCopter or PX4 as the mission's
``autopilot`` says, the fleet, delivery, the telemetry schedule and the
seeded link impairments of ``sim_vehicle.impairments``: loss, duplicates,
delay, jitter), each vehicle on a ``Radio``, a ``core.Port`` without a
socket. Between them, datagrams as bytes, which a test may also forge or
silence; ``station_off`` stops the station's side altogether (its timers,
HEARTBEAT and setpoints), so the vehicles' own failsafes act. No sockets,
no event loop, no sleeps: a second of flight is 50 physics steps and
whatever the core asks for.

The station side follows ``runtime/station.py`` (``_after``, ``_on_timer``,
``_control_task``); the vehicle side is what ``sim_vehicle/server.py`` does
around the same core, without its sockets and clock task.
"""

from __future__ import annotations

import dataclasses
import re
from collections import Counter
from collections.abc import Callable, Collection, Iterable
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.runtime import emulator_config, station_config
from gcs_swarm.runtime.plans import shard_config
from gcs_swarm.swarm import LinkState, SetpointBatch, SwarmCore
from sim_vehicle import Impairment, signing
from sim_vehicle.autopilot import Autopilot
from sim_vehicle.core import EmulatorCore
from sim_vehicle.impairments import Impairer
from sim_vehicle.link import _split_setpoints
from sim_vehicle.stats import LinkStats
from sim_vehicle.vehicles import HostedVehicle

MISSIONS = Path(__file__).resolve().parents[2] / "config" / "missions"
LINK = "udpin:0.0.0.0:14550"
"""The station's link (of network 0; network j's: ``link_of(j)``)."""
GCS: tuple[str, int] = ("10.0.0.1", 14550)
"""The station's address as the vehicles see it (network 0's: ``gcs_of(j)``)."""
_SETPOINT = mav.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED

Datagram = tuple[tuple[str, int], bytes]
"""(sender address, bytes)."""


def mission_from(name: str, *, duration: float) -> Mission:
    """A shipped mission given a ``duration`` [s] of formation flight."""
    m = load_mission(MISSIONS / name)
    return dataclasses.replace(m, settings=dataclasses.replace(m.settings, duration=duration))


def in_waves(window: int | None, *, duration: float) -> Mission:
    """Example 1 on two networks (blue 1-3, red 1-3) with ``window`` vehicles
    of each network in their start-up handshake at once
    (``mission.startup.handshakes_per_network``; None: no bound)."""
    m = mission_from("example1_networks.yaml", duration=duration)
    startup = dataclasses.replace(m.settings.startup, handshakes_per_network=window)
    return dataclasses.replace(m, settings=dataclasses.replace(m.settings, startup=startup))


PHASE_LINE = re.compile(r"^vehicle (\S+): ([a-z_]+)$")
"""A phase change in a core's log: (label, ``Phase`` value)."""


def handshakes_at_once(log: Iterable[str]) -> tuple[dict[str, int], list[str]]:
    """From a core's log, in order: the most vehicles of each network
    (label before ``:``) in CONFIGURING at once, however briefly (a vehicle
    is in it from its ``configuring`` line to its next phase line), and the
    labels in the order they began it."""
    inside: dict[str, set[str]] = {}
    most: dict[str, int] = {}
    began: list[str] = []
    for line in log:
        if (m := PHASE_LINE.match(line)) is None:
            continue
        label, net = m[1], m[1].split(":")[0]
        now = inside.setdefault(net, set())
        if m[2] == Phase.CONFIGURING.value:
            now.add(label)
            began.append(label)
        else:
            now.discard(label)
        most[net] = max(most.get(net, 0), len(now))
    return most, began


def address(sysid: int) -> tuple[str, int]:
    """Vehicle ``sysid``'s own address (its key on a later network)."""
    return ("10.0.1.1", 5760 + 10 * sysid)


def link_of(network: int) -> str:
    """The station's link to network index ``network``: a link per network."""
    return f"udpin:0.0.0.0:{14550 + network}"


def gcs_of(network: int) -> tuple[str, int]:
    """The station's address as network ``network``'s vehicles see it."""
    return (GCS[0], GCS[1] + network)


class Radio:
    """One vehicle's radio: a ``sim_vehicle.core.Port`` whose ``sendto`` hands the
    datagram to the sky (towards the station) instead of a socket. Its fixed
    peer is the station (``out``), as an emulator serving a ``udpin`` station."""

    shared = False
    signing_key: bytes | None = None

    def __init__(
        self, sky: Sky, addr: tuple[str, int], up: Impairer, down: Impairer, network: int = 0
    ) -> None:
        self.sky, self.address = sky, addr
        self.uplink, self.downlink = up, down
        self.link, self.gcs = link_of(network), gcs_of(network)
        """The station's link and address this radio talks to (its network's)."""
        self.emu: EmulatorCore | None = None
        """Its network's emulator core."""
        self.out: tuple[str, int] | None = self.gcs
        self.sysids: dict[int, int] = {}
        self.peers: dict[tuple[str, int], None] = {self.gcs: None}
        self.outbox: list[tuple[bytes, int]] = []
        self.silent = False
        self.parser = mav.MAVLink(None)
        self.parser.robust_parsing = True
        self.setpoints_in = 0
        """SET_POSITION_TARGET_LOCAL_NED that reached the radio (the uplink's impairment
        then acts inside the emulator's core: ``Sky.stats.rx_lost``)."""

    def sendto(self, data: bytes, addr: tuple[str, int]) -> None:
        assert self.emu is not None
        self.emu.stats.link.tx_datagrams += 1  # as link.Endpoint counts what it sends
        self.sky.to_station(self.address, data, self.link)

    def close(self) -> None:
        pass


@dataclasses.dataclass(eq=False)
class SimVehicle:
    """One emulated vehicle: what the core hosts, and its radio."""

    hosted: HostedVehicle
    radio: Radio

    @property
    def ap(self) -> Autopilot:
        return self.hosted.ap


class Sky:
    """Station core and emulator core wired together (module docstring).

    ``downlink``/``uplink``: the impairment of every datagram to the station
    (telemetry) / to a vehicle (setpoints, commands), seeded per vehicle and
    direction from ``seed`` as the emulator seeds its endpoints.

    A mission of several networks gets a link and an emulator core per
    network (as ``run_mission``); ``link``, ``emu`` and ``stats`` are network
    0's. ``keys``: only these vehicles, on both sides (a link shard's part of
    the mission: ``runtime.plans.shard_config``, its own vehicles' events
    only); the vehicles are seeded as in the whole sky."""

    def __init__(
        self,
        mission: Mission,
        *,
        downlink: Impairment | None = None,
        uplink: Impairment | None = None,
        seed: int = 0,
        keys: Collection[int] | None = None,
        stagger: bool = False,
        raw_setpoints: bool = False,
    ) -> None:
        mine = [v for v in mission.vehicles if keys is None or v.key in keys]
        self.stagger = stagger
        self.raw_setpoints = raw_setpoints
        """The vehicles' radios hand unsigned setpoints to the emulator's core as
        ``codec.RawSetpoint``, as its UDP endpoint does (``Endpoint.parse(raw=True)``)."""
        """Each network's emulator steps, then its datagrams reach the station,
        before the next network's (unsynchronised networks, within one tick)."""
        nets = sorted({v.net_index for v in mine})
        cfg = station_config(mission, {v.key: link_of(v.net_index) for v in mission.vehicles})
        if keys is not None:
            cfg = shard_config(cfg, keys)
        self.core = SwarmCore(cfg)
        self.notices: list[str] = []
        self.now = 0.0
        self.links = {
            link_of(j): LinkState(
                link_of(j),
                unix_clock=lambda: 1.7e9 + self.now,
                sysids=[v.key for v in mine if v.net_index == j],
                telemetry=self.core.table,
                on_notice=self.notices.append,
                base=self.core.base_of[link_of(j)],
            )
            for j in nets
        }
        """The station's link to each network, by name."""
        self.link = self.links[link_of(nets[0])]
        self.emus: list[EmulatorCore] = []
        self.vehicles: dict[int, SimVehicle] = {}
        self._radios: dict[tuple[str, int], Radio] = {}
        for j in nets:
            # Each network's emulator as the mission starts it, airborne, with a quick
            # start-up: the EKF ready, boot ended and PX4's pre-arm checks passed at
            # once; no shaping.
            emu = emulator_config(mission, airborne=True, network=j)
            wire = {v.sysid for v in mine if v.net_index == j}
            emu = dataclasses.replace(
                emu, ekf_ready_s=0.0, boot_s=0.0, accel_shaping=False,
                params={**emu.params, "SIM_PREARM_S": 0.0}, seed=seed,
                uplink=uplink or Impairment(), downlink=downlink or Impairment(),
                vehicles=tuple(spec for spec in emu.vehicles if spec.sysid in wire),
            )  # fmt: skip
            core = EmulatorCore(emu)
            self.emus.append(core)
            base = self.core.base_of[link_of(j)]
            for spec in emu.vehicles:
                # seeded as the emulator seeds each endpoint's two directions
                # (server._open_endpoint)
                ss = np.random.SeedSequence([seed, spec.key, 7])
                up, down = (np.random.default_rng(q) for q in ss.spawn(2))
                radio = Radio(self, address(base + spec.sysid), Impairer(emu.uplink, up),
                              Impairer(emu.downlink, down), network=j)  # fmt: skip
                radio.emu = core
                core.ports.append(radio)
                enc = signing.mavlink(spec.sysid, spec.compid, None)
                hosted = core.add(spec, radio, initial=True, enc=enc)
                self.vehicles[base + spec.sysid] = SimVehicle(hosted, radio)
                self._radios[radio.address] = radio
        self.emu = self.emus[0]
        self.dt = self.emu.dt
        self.station_running = True
        self.control_step: Callable[[float, Any], None] = self.core.control_step
        """What runs when the core wants a step (a link shard's differs)."""
        self.steps = 0
        self.answered: Counter[int] = Counter()
        """Setpoints of the control steps per vehicle (the station's answers)."""
        self._next_hb = 0.0
        self._next_status = 1.0
        self._to_station: list[tuple[tuple[str, int], bytes, str]] = []
        """(sender address, bytes, the station's link it reaches)."""

    @property
    def stats(self) -> LinkStats:
        """The emulator's link counters: ``tx_lost``/``rx_lost`` the datagrams the
        downlink/uplink lost, ``duplicated`` those either delivered twice."""
        return self.emu.stats.link

    # ----------------------------------------------------------- vehicles
    def to_station(self, sender: tuple[str, int], data: bytes, link: str = LINK) -> None:
        """A datagram towards the station's ``link`` (from a vehicle's radio, or ``inject``)."""
        self._to_station.append((sender, data, link))

    def _to_vehicle(self, radio: Radio, data: bytes) -> None:
        """A datagram from the station arrives at a vehicle's radio (server ``_receive``)."""
        if radio.silent:
            return
        if self.raw_setpoints:
            msgs: list[Any] = []
            for piece in _split_setpoints(data):
                if isinstance(piece, bytes):
                    msgs.extend(radio.parser.parse_buffer(piece) or [])
                else:
                    msgs.append(piece)
        else:
            msgs = radio.parser.parse_buffer(data) or []
        radio.setpoints_in += sum(m.get_msgId() == _SETPOINT for m in msgs)
        assert radio.emu is not None
        radio.emu.receive(radio, msgs, radio.gcs, None)

    def set_silent(self, sysid: int, silent: bool = True) -> None:
        """Vehicle ``sysid``'s radio off (it keeps flying) or on again."""
        v = self.vehicles[sysid]
        assert v.radio.emu is not None
        v.radio.emu.set_silent(v.hosted, silent)

    def inject(self, sender: tuple[str, int], data: bytes) -> None:
        """A datagram to the station from ``sender`` (a forger, a stray port)."""
        self.to_station(sender, data)

    # ------------------------------------------------------------ station
    def _write(self, link: str, batch: SetpointBatch | None) -> None:
        if batch is not None:
            self.answered.update(batch.sysids)
        lk = self.links[link]
        writes = lk.datagrams_to_send() if batch is None else lk.accel_setpoints(*batch)
        self._deliver(writes)

    def _deliver(self, writes: list[tuple[Any, bytes, list[float | None]]]) -> None:
        for peer, data, _since in writes:
            radio = self._radios.get(peer)
            if radio is not None:  # else to the forger: nobody listens there
                self._to_vehicle(radio, data)

    def _station_sends(self) -> None:
        core = self.core
        if core.outbound:
            out, core.outbound = core.outbound, []
            for link, spec, sysid in out:
                self.links[link].send(spec, sysid)
        for lk in self.links.values():
            self._deliver(lk.datagrams_to_send())

    def station_off(self) -> None:
        """The station's side stops for good (killed): no timer, no HEARTBEAT, no
        setpoint, nothing heard; the vehicles fly on and their failsafes act."""
        self.station_running = False

    def transfer(self) -> None:
        """Pass datagrams both ways until nobody has anything to say (at ``now``)."""
        core = self.core
        for _ in range(100):
            if not self.station_running:
                self._to_station.clear()  # nobody listens any more
                return
            self._station_sends()
            if core.step_wanted:
                self.control_step(self.now, self._write)
                self.steps += 1
                core.lookahead.clear()  # the look-ahead is not exercised here
                continue
            if not self._to_station:
                return
            batch, self._to_station = self._to_station, []
            for sender, data, name in batch:
                link = self.links[name]
                for msg in link.receive(data, sender, self.now, datagram=True):
                    core.receive(msg, name, self.now, self.now)
                if link.positions_written:
                    core.telemetry_written(self.now)
        raise AssertionError("the two sides kept talking at one instant")

    # -------------------------------------------------------------- clock
    def advance(self, seconds: float) -> None:
        """Fly ``seconds`` [s]: the emulator's physics steps of ``dt`` (each with its
        polls, telemetry and delayed datagrams), the core's timers at their own times."""
        end = self.now + seconds - 1e-9
        if self.emu.step_count == 0 and self.now == 0.0:
            for emu in self.emus:
                emu.emit(0.0)  # what is due at once (the emulator's clock task)
            self.transfer()
        while self.now < end:
            tick = self.now + self.dt
            while (
                self.station_running and (due := self.core.get_timer()) is not None and due <= tick
            ):
                self.now = max(self.now, due)
                self.core.handle_timer(self.now)
                self.transfer()
            if self.station_running and self._next_hb <= tick:  # its shell's 1 Hz HEARTBEAT
                self._next_hb += 1.0
                for lk in self.links.values():
                    lk.send(b.heartbeat())
            for emu in self.emus:
                emu.step()
                if self.stagger:
                    self.transfer()
            self.now = tick
            self.transfer()
            if self.station_running and self._next_status <= self.now:  # its status task
                self._next_status += 1.0
                self.core.check_alive(self.now)
                self.transfer()

    def run_until(self, done: Callable[[], bool], limit_s: float) -> None:
        """Advance a step at a time until ``done()``; fail after ``limit_s`` [s]."""
        end = self.now + limit_s
        while not done():
            assert self.now < end, f"not done after {limit_s} s: {self.phases()}"
            self.advance(self.dt)

    # ------------------------------------------------------------ phases
    def phases(self) -> dict[int, Phase]:
        return {s: vp.phase for s, vp in self.core.vehicles.items()}

    def ready(self, limit_s: float = 30.0) -> None:
        """Until every vehicle is READY (``Station.ready``), then the envelope."""
        self.run_until(lambda: all(p is Phase.READY for p in self.phases().values()), limit_s)
        self.core.apply_envelope()

    def start(self) -> None:
        """The formation starts (``Station.fly``)."""
        self.core.start(self.now)
        self.transfer()

    def end(self, limit_s: float = 10.0) -> None:
        """Zero acceleration and the end mode for everyone, until each vehicle
        has settled (``Station.end``)."""
        self.core.finish_all(self.now)
        self.transfer()
        settled = {Phase.ENDED, Phase.FAILED, Phase.LOST, Phase.CONNECTING}
        vps = list(self.core.vehicles.values())
        self.run_until(lambda: all(v.phase in settled and not v.restoring for v in vps), limit_s)
