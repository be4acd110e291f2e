"""``gcs-swarm shard --connect ENDPOINT``: one link shard's process
(docs/architecture.md, "Scaled out: shards").

The shard says hello to the controller listening at ``ENDPOINT`` (Zenoh,
``runtime.zbus``), is assigned its networks (the mission's text, the
vehicles' links, the lockstep flag), and then runs an ordinary ``Station``
over its vehicles only: links, codec, the vehicles' protocols, start-up,
membership and its vehicles' join/leave events (reserves readied with the
others), the telemetry table. Only its control step differs: the state
batch goes to the controller (``swarm.shard.ShardSide.take_state``) and the
controller's reply is answered through the links (``ShardSide.apply``).

In a run with a folder the assignment names where this shard logs each of
its networks' frames (``flight-<network>.tlog``); its final report carries
the inbound counts and the vehicles' parameter records for the controller's
summary and ``vehicle_params.json``.

Ending: the controller's ``end`` (its mode), a signal (SIGINT/SIGTERM), or
the controller silent for the stale timeout all end every vehicle of the
shard with ``Station.end`` (zero acceleration, then the end action,
confirmed); the shard then sends its vehicles' report (``done``) and exits.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import secrets
import signal
from collections.abc import Callable
from dataclasses import asdict, astuple, replace
from pathlib import Path
from typing import Any

import numpy as np

from gcs_swarm.errors import LinkError, StartupError
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.coordinates import GeoOrigin
from gcs_swarm.mission import parse_mission
from gcs_swarm.report.record import FlightRecorder
from gcs_swarm.runtime.config import StationConfig
from gcs_swarm.runtime.endpoints import LatencyRing
from gcs_swarm.runtime.plans import shard_config, station_config
from gcs_swarm.runtime.run_report import frame_sink, vehicle_param_records
from gcs_swarm.runtime.station import Station
from gcs_swarm.runtime.tlog import TlogWriter
from gcs_swarm.runtime.zbus import Bus, TlsFiles
from gcs_swarm.swarm.departures import live_columns
from gcs_swarm.swarm.shard import ShardSide
from gcs_swarm.swarm.shard_wire import decode_reply, encode_state, keep_out_json

__all__ = ["BEAT_S", "HELLO_TIMEOUT_S", "WINDOW_S", "FlightEnd", "run_shard", "shard_command"]

_log = logging.getLogger("gcs_swarm.shard")

BEAT_S = 0.1
"""Heartbeat period [s] both ways: ten within the default 1 s stale timeout."""
HELLO_TIMEOUT_S = 30.0
"""How long a shard says hello before it gives up on its controller [s]."""
WINDOW_S = 10.0
"""The end of the formation [s of mission time] the shard's report measures
(``FlightEnd``): its setpoint latencies and missed vehicle-cycles."""


FrameSource = Callable[[Station], Callable[[float], dict[str, Any]]]
"""Given the shard's station, what builds its operator-view frame at wall
time ``now`` (``gcs_swarm.view.sharded.shard_frames``, passed in by the
command line: the runtime does not import the view)."""


async def run_shard(
    endpoint: str,
    *,
    tls: TlsFiles | None = None,
    token: str | None = None,
    frames: FrameSource | None = None,
) -> int:
    """Serve as one link shard of the controller at ``endpoint`` (with
    ``tls`` for ``quic/`` and ``tls/``: ``runtime.zbus``) until the run
    ends; 0 when every vehicle that flew ended, 1 otherwise. With
    ``frames``, a run that has the operator view open gets this shard's
    frames (its vehicles) at the view's rate.
    ``LinkError`` when the controller cannot be reached."""
    token = token or secrets.token_hex(8)
    loop = asyncio.get_running_loop()
    async with Bus(connect=[endpoint], tls=tls) as bus:
        assigned: asyncio.Future[dict[str, Any]] = loop.create_future()

        def on_assign(key: str, data: bytes) -> None:
            if not assigned.done():
                assigned.set_result(json.loads(data))

        bus.subscribe(f"assign/{token}", on_assign)
        try:
            async with asyncio.timeout(HELLO_TIMEOUT_S):
                while not assigned.done():
                    bus.put_json("hello", {"token": token, "pid": os.getpid()})
                    await asyncio.wait([assigned], timeout=0.2)
        except TimeoutError:
            raise LinkError(
                f"shard: no controller answered at {endpoint} in {HELLO_TIMEOUT_S:g} s" + bus.hint()
            ) from None
        return await _serve(bus, assigned.result(), frames)


async def _serve(bus: Bus, a: dict[str, Any], frames: FrameSource | None) -> int:
    index = int(a["index"])
    mission = parse_mission(a["mission"], a["source"])
    links = {int(k): str(v) for k, v in a["links"].items()}
    mine = {int(k) for k in a["keys"]}
    full = station_config(mission, links, lockstep=bool(a["lockstep"]))
    cfg = replace(shard_config(full, mine), end_timeout_s=float(a["end_timeout_s"]))
    up = f"up/{index}"
    start = asyncio.Event()
    ended = asyncio.Event()
    entered = asyncio.Event()
    """The station is open: its clock runs and its core takes work."""
    end_mode: list[int | None] = [None]
    station: Station | None = None
    side: ShardSide | None = None
    window: FlightEnd | None = None

    def step(now: float, write: Any) -> None:
        assert side is not None
        batch = side.take_state(now)
        if batch is not None:
            # Real time: the next step brings a newer batch; lockstep waits for this one.
            bus.put(f"{up}/state", encode_state(batch), droppable=not cfg.lockstep)

    def on_reply(key: str, data: bytes) -> None:
        if station is None or side is None or not entered.is_set():
            return
        reply, shard = decode_reply(data), side
        station.apply(lambda now, write: shard.apply(reply, now, write))
        if window is not None:
            window.reply(reply.t_s)

    relayed: asyncio.Future[GeoOrigin] = asyncio.get_running_loop().create_future()
    """The mission origin as the controller's beats carry it (``_relayed_origin``)."""

    def on_down(key: str, data: bytes) -> None:
        msg = json.loads(data)
        if msg.get("origin") is not None and not relayed.done():
            relayed.set_result(GeoOrigin(*(float(x) for x in msg["origin"])))
        if msg["kind"] == "end":
            end_mode[0] = msg.get("mode")
            ended.set()
        if msg["kind"] == "start":
            start.set()
        if station is None or side is None or not entered.is_set():
            return  # the station's clock and core are not running yet (beats repeat)
        side.heard(station.now())
        if msg.get("leader") is not None:
            leader, shard = np.array(msg["leader"], dtype=np.float64), side
            vel = msg.get("leader_vel")
            vel = None if vel is None else np.array(vel, dtype=np.float64)
            radius = msg.get("radius")
            radius = None if radius is None else float(radius)
            station.apply(lambda now, write: shard.leader_at(leader, vel, radius))

    bus.subscribe("down/all", on_down)
    bus.subscribe(f"down/{index}/ctl", on_down)  # to this shard alone: ended once declared dead
    # Without ``mission.origin`` the mission frame is the first vehicle's EKF
    # origin; a shard that does not own that vehicle is told it (``_relayed_origin``).
    relay = full.mission_origin is None and cfg.vehicles[0].sysid != full.vehicles[0].sysid
    waited = await _relayed_origin(cfg, relayed, ended) if relay else None
    if waited is not None:
        cfg = replace(cfg, mission_origin=waited)

    # A run with a folder: this shard logs its own networks' frames (one
    # .tlog each, where the controller named them) and counts what came in.
    tlog_paths = {int(j): Path(p) for j, p in a.get("tlogs", {}).items()}
    network_of = {links[v.key]: v.net_index for v in mission.vehicles if v.key in mine}
    tlogs: dict[int, TlogWriter] = {}
    recorder = FlightRecorder() if tlog_paths else None

    def log_failed(text: str) -> None:  # logging stopped: say so once, fly on
        if station is not None:
            station.warn(text)

    for j, path in sorted(tlog_paths.items()):
        with contextlib.suppress(OSError):  # a shard on another machine: the same path there
            path.parent.mkdir(parents=True, exist_ok=True)
        tlogs[j] = TlogWriter(path, on_error=log_failed)

    def frames_for(link: str) -> Callable[[bytes, str], None] | None:
        tlog = tlogs.get(network_of.get(link, -1))
        return None if tlog is None else frame_sink(tlog)

    station = Station(cfg, control_step=step, recorder=recorder,
                      on_frame_for=frames_for if tlogs else None)  # fmt: skip
    station.hold_when_ready = cfg.lockstep
    side = ShardSide(station.core, index, cfg.stale_timeout_s)
    window = FlightEnd(station, side, cfg.duration_s, cfg.rate_hz)
    bus.subscribe(f"down/{index}/reply", on_reply)
    if waited is not None:
        station.core.note("mission origin = the mission's first vehicle's EKF origin, "
                          "from the shard that owns it")  # fmt: skip
    outcome_ok = True
    flying_drops = [0]
    """Setpoints dropped (a newer one queued first) before the ending began."""
    stack = contextlib.AsyncExitStack()
    try:
        if relay and waited is None:
            first = mission.label(full.vehicles[0].sysid)
            raise LinkError(f"no mission origin came from the controller in "
                            f"{cfg.ready_timeout_s:g} s (the EKF origin of {first}, "
                            "another shard's vehicle)")  # fmt: skip
        for tlog in tlogs.values():  # closed after the station: its ending is logged
            await stack.enter_async_context(tlog)
        await stack.enter_async_context(station)
    except LinkError as err:  # a link that does not open: the controller is told why
        await stack.aclose()
        bus.put_json(f"{up}/msg", {"kind": "failed", "text": str(err)})
        bus.put_json(f"{up}/msg", {**_done(station, side), "setpoints_dropped_before_end": 0})
        await asyncio.sleep(0.3)  # the report's way out before the session closes
        return 1
    async with stack:
        entered.set()
        side.heard(station.now())

        async def beat() -> None:  # heartbeats out; the controller's silence watched
            assert station is not None and side is not None
            while True:
                core = station.core
                flying = len(core.flying) if core.started else None
                o = core.origin
                origin = None if o is None else [o.lat_deg, o.lon_deg, o.alt_m]
                # The columns of its vehicles it calls lost (Eq. K1), for the law's filter.
                kept = keep_out_json(core.control.keep_out)
                flies = core.started and not (core.ending or core.finished)
                live = keep_out_json(live_columns(core, station.now()) if flies else {})
                bus.put_json(f"{up}/msg", {"kind": "beat", "flying": flying, "origin": origin,
                                           "keep_out": kept, "keep_live": live})  # fmt: skip
                if side.controller_silent(station.now()) and not ended.is_set():
                    station.warn(f"controller silent for {cfg.stale_timeout_s:g} s: "
                                 "ending every vehicle of this shard")  # fmt: skip
                    ended.set()
                await asyncio.sleep(BEAT_S)

        beating = asyncio.ensure_future(beat())
        view_hz = float(a.get("view_hz") or 0.0)
        if frames is not None and view_hz > 0.0:
            frame_at = frames(station)

            async def show() -> None:  # this shard's part of the operator view
                assert station is not None
                while True:
                    await asyncio.sleep(1.0 / view_hz)
                    bus.put_json(f"{up}/view", frame_at(station.now()))

            showing = asyncio.ensure_future(show())
            stack.callback(showing.cancel)
        try:
            try:
                await _until(station.ready(), ended)
            except StartupError as err:
                bus.put_json(f"{up}/msg", {"kind": "failed", "text": str(err)})
                end_mode[0] = b.COPTER_MODES["LAND"]
                outcome_ok = False
            else:
                if not ended.is_set():
                    station.freeze_heap()  # now, not at the start (Station.freeze_heap)
                    env = station.apply_envelope()
                    bus.put_json(f"{up}/msg", {"kind": "ready", "envelope": asdict(env),
                                               "members": len(station.members)})  # fmt: skip
                    await _until(start.wait(), ended)
                    if start.is_set() and not ended.is_set():
                        station.begin()
                        opening = encode_state(side.opening(station.now()))
                        bus.put(f"{up}/state", opening, droppable=False)
                        station.release()
                        side.heard(station.now())
                        await ended.wait()
        finally:
            flying_drops[0] = sum(lk.stats.setpoints_dropped for lk in station.links.values())
            window.close()
            station.release()  # what a lockstep shard held before the start
            # The ending runs to its end (it has its own timeout): a signal that
            # arrives meanwhile (Ctrl-C reaches the controller and its shards
            # alike) must not cut it short, or the report says "ending".
            ending = asyncio.ensure_future(station.end(end_mode[0]))
            while not ending.done():
                with contextlib.suppress(asyncio.CancelledError):
                    await asyncio.shield(ending)
            beating.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await beating
            done = _done(station, side)
            done["setpoints_dropped_before_end"] = flying_drops[0]
            done["flight_end"] = window.report()
            done["logging_error"] = next((t.error for t in tlogs.values() if t.error), None)
            bus.put_json(f"{up}/msg", done)
        outcome_ok = outcome_ok and station.outcome() == "completed"
    await asyncio.sleep(0.3)  # the report's way out before the session closes
    return 0 if outcome_ok else 1


async def _relayed_origin(
    cfg: StationConfig, relayed: asyncio.Future[GeoOrigin], ended: asyncio.Event
) -> GeoOrigin | None:
    """The mission origin of a mission without ``mission.origin`` (its first
    vehicle's EKF origin) when another shard owns that vehicle: it comes
    with the controller's beats (float64 through JSON: the owner's
    numbers). Until it has come this shard does not talk to its vehicles:
    it could not place them, and a lockstep emulator (as SITL) waits for its
    station's first datagram. None after ``ready_timeout_s`` or once the run
    ends (the caller then fails)."""
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(cfg.ready_timeout_s):
            await _until(asyncio.shield(relayed), ended)
    return relayed.result() if relayed.done() else None


async def _until(coro: Any, ended: asyncio.Event) -> None:
    """Await ``coro`` unless ``ended`` is set first (then it is cancelled)."""
    task = asyncio.ensure_future(coro)
    stop = asyncio.ensure_future(ended.wait())
    try:
        await asyncio.wait([task, stop], return_when=asyncio.FIRST_COMPLETED)
    finally:
        stop.cancel()
    if task.done():
        task.result()
    else:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def _done(station: Station, side: ShardSide) -> dict[str, Any]:
    """The shard's final report: each vehicle as ``VehicleAtEnd`` needs it,
    the links' counters, the log."""
    links = station.links.values()
    records = vehicle_param_records(station.vehicles)
    params = dict(zip(map(str, sorted(station.vehicles)), records, strict=True))
    return {
        "kind": "done",
        "vehicles": [
            {
                "sysid": s,
                "phase": vp.phase.value,
                "mode": vp.mode_name,
                "failure": vp.failure,
                "label": vp.label,
                "last_accel_ned_mps2": [float(x) for x in vp.last_accel_ned],
                "rate_requests": vp.rate_requests,
                "telemetry_rate_min_hz": vp.telemetry_rate_min_hz
                if math.isfinite(vp.telemetry_rate_min_hz)
                else None,
                "velocity_bias_ned_mps": list(vp.velocity_bias.bias),
                "velocity_bias_corrected": vp.velocity_bias.settings.correct,
                "velocity_bias_saturated": vp.velocity_bias.saturated,
            }
            for s, vp in sorted(station.vehicles.items())
        ],
        "flown": sorted(station.flown),
        "messages_sent": sum(lk.stats.sent for lk in links),
        "setpoints_dropped": sum(lk.stats.setpoints_dropped for lk in links),
        "messages_dropped": sum(lk.stats.messages_dropped for lk in links),
        "bad_packets": sum(lk.stats.bad_packets for lk in links),
        "unknown_sysid_messages": sum(station.unknown_sysids.values()),
        "spoofed": sum(lk.stats.spoofed for lk in links),
        "signature_rejected": sum(lk.stats.signature_rejected for lk in links),
        "clipped_setpoints": station.clipped_setpoints(),
        "rebinds_refused": {str(k): n for k, n in station.rebinds_refused().items()},
        "states": side.states,
        "replies": side.replies,
        "log": list(station.log),
        "vehicle_params": params,
        "telemetry": {}
        if station.recorder is None
        else {str(k): astuple(c) for k, c in station.recorder.telemetry.counts.items()},
    }


class FlightEnd:
    """The last ``WINDOW_S`` of the formation, measured in the shard's report
    (``report``): from the first reply whose mission time is within
    ``WINDOW_S`` of the duration (a shorter mission: its first) to the
    ending's start (``close``), each link's setpoint latencies (telemetry
    arrival to setpoint write: a fresh ``Link.latency`` ring then, holding
    the window's) and the vehicle-cycles missed (reports taken less
    setpoints written, less the change in the reports the controller had
    not answered yet: bench_station's count)."""

    def __init__(self, station: Station, side: ShardSide, duration_s: float, rate_hz: float):
        self.station, self.side = station, side
        self.opens_at_s = duration_s - WINDOW_S
        self.rate_hz = rate_hz
        self.opened_t_s: float | None = None
        self._start = (0, 0)  # reports taken, in flight
        self._end: tuple[int, int, int] | None = None  # and setpoints written

    def _counts(self) -> tuple[int, int]:
        st = self.station
        return st.reports_in - st.reports_waiting, self.side.in_flight()

    def reply(self, t_s: float) -> None:
        """A reply of mission time ``t_s`` [s] was applied."""
        if self.opened_t_s is not None or t_s < self.opens_at_s or self._end is not None:
            return
        self.opened_t_s = t_s
        core = self.station.core
        for key, lk in self.station.links.items():
            n = sum(1 for link in core.link_of.values() if link == key)
            lk.latency = LatencyRing(max(16384, math.ceil(self.rate_hz * n * (WINDOW_S + 1.0))))
        self._start = self._counts()

    def close(self) -> None:
        """The ending begins: the window's counts end here."""
        if self.opened_t_s is not None and self._end is None:
            written = sum(lk.latency.count for lk in self.station.links.values())
            self._end = (*self._counts(), written)

    def report(self) -> dict[str, float | None]:
        """p50, p99 and max latency [ms], setpoints, missed (NaN, None: never opened)."""
        lat = sorted(self.station.setpoint_latencies_s())
        rings = [lk.latency for lk in self.station.links.values()]

        def pct(q: float) -> float:
            return 1e3 * lat[min(len(lat) - 1, int(q * len(lat)))] if lat else math.nan

        peak = 1e3 * max((r.max_s for r in rings), default=0.0)
        out: dict[str, float | None] = {"from_t_s": self.opened_t_s, "p50_ms": pct(0.50),
                                        "p99_ms": pct(0.99), "max_ms": peak,
                                        "setpoints": None, "missed": None}  # fmt: skip
        if self._end is not None:
            (r0, f0), (r1, f1, written) = self._start, self._end
            out["setpoints"] = float(written)
            out["missed"] = float((r1 - r0) - written - (f1 - f0))
        return out


def shard_command(
    endpoint: str, frames: FrameSource | None = None, tls: TlsFiles | None = None
) -> int:
    """``gcs-swarm shard --connect ENDPOINT [--tls-ca/--tls-cert/--tls-key]``:
    SIGINT/SIGTERM end every vehicle of the shard (the end action), then the
    process exits."""

    async def main() -> int:
        loop = asyncio.get_running_loop()
        task = asyncio.current_task()
        assert task is not None
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, task.cancel)
        try:
            return await run_shard(endpoint, tls=tls, frames=frames)
        except asyncio.CancelledError:
            return 130

    return asyncio.run(main())
