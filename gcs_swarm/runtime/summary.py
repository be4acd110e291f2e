"""The end-of-run summary: what flew, where it ended, what the links counted.

``RunSummary.from_station`` reads a ``Station`` once its vehicles have been
ended (``from_controller`` a sharded run's controller and its shards'
final reports); positions are mission frame [m] at the last control step (the state
the law last saw), so a test can compare them with the in-process law.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.control.params import Vec3
from gcs_swarm.mission import Mission
from gcs_swarm.runtime.station import Station
from gcs_swarm.swarm.controller import ControllerCore

__all__ = ["RunSummary", "VehicleAtEnd"]


@dataclass(frozen=True)
class VehicleAtEnd:
    """One vehicle at the end: its phase and Copter mode, position [m] and
    radius to the leader [m] at the last control step (None if it was not
    flying then), the last acceleration the station commanded [m/s^2, NED]
    (zero after a clean ending), and why it failed or was lost, if it did;
    the bias estimated in its reported velocity [m/s, NED] (docs/velocity-bias.md),
    whether it was corrected, and whether the estimate hit ``velocity_bias.max``."""

    sysid: int
    phase: str
    mode: str
    position_m: Vec3 | None
    radius_m: float | None
    last_accel_ned_mps2: Vec3
    failure: str | None
    velocity_bias_ned_mps: Vec3 = (0.0, 0.0, 0.0)
    velocity_bias_corrected: bool = False
    velocity_bias_saturated: bool = False
    telemetry_rate_min_hz: float | None = None
    """Lowest LOCAL_POSITION_NED rate over a 2 s window in flight (vehicle time)."""
    rate_requests: int = 0
    """Times the station asked for the mission rate again because it was low."""
    label: str = ""
    """How it is named: ``network:sysid`` on a named network (``sysid`` is
    then its key, ``mission.vehicle_key``); its system id otherwise."""


@dataclass(frozen=True)
class RunSummary:
    """The run in numbers. ``outcome`` (``Station.outcome``): completed (every
    vehicle that flew ended), degraded (some were lost, failed or never
    confirmed their end action), failed (all of them, or the law failed in
    flight: ``failure``), cancelled, startup failed.
    Separation and clearance [m] are minima over the control steps (``inf``
    when not applicable); ``episodes`` counts avoidance episodes."""

    outcome: str
    mission_time_s: float
    wall_time_s: float
    steps: int
    behaviour: str
    leader_pos_m: Vec3
    vehicles: tuple[VehicleAtEnd, ...]
    min_separation_m: float
    min_clearance_m: float
    episodes: int
    messages_sent: int
    setpoints_dropped: int
    messages_dropped: int
    bad_packets: int
    unknown_sysid_messages: int
    spoofed: int
    signature_rejected: int
    safety: str
    log: tuple[str, ...]
    start_tolerance_m: float = 0.3
    start_speed_tolerance_mps: float = 0.3
    """What "at its start" meant at start-up (``mission.startup``)."""
    clipped_setpoints: int = 0
    """Setpoints scaled down to the ceiling, or zeroed (non-finite)."""
    rebinds_refused: dict[int, int] | None = None
    """Frames refused per vehicle (by key, as ``VehicleAtEnd.sysid``): from
    another address than its bound one."""
    failure: str | None = None
    """Why the mission ended as failed in flight (the law failed), if it did."""
    logging_error: str | None = None
    """Why the run's log stopped (a write error), if it did."""
    keep_out_columns: int = 0
    """Vehicles out of the formation but in the air whose columns the members
    kept out of (lost, or left while heard: Eq. K1, docs/vehicle-safety.md)."""
    min_keep_out_m: float = math.inf
    """The closest any member came to such a column [m] (negative: inside it,
    as when one appears around a member; a column is where the vehicle may
    be, so this is at most the distance to the vehicle)."""

    @classmethod
    def from_station(
        cls,
        station: Station,
        *,
        outcome: str,
        wall_time_s: float,
        logging_error: str | None = None,
    ) -> RunSummary:
        at = _at_last_step(station.control)
        vehicles = tuple(
            VehicleAtEnd(
                sysid=s,
                phase=vp.phase.value,
                mode=vp.mode_name,
                position_m=at[s][0] if s in at else None,
                radius_m=at[s][1] if s in at else None,
                last_accel_ned_mps2=(
                    float(vp.last_accel_ned[0]),
                    float(vp.last_accel_ned[1]),
                    float(vp.last_accel_ned[2]),
                ),
                failure=vp.failure,
                velocity_bias_ned_mps=vp.velocity_bias.bias,
                velocity_bias_corrected=vp.velocity_bias.settings.correct,
                velocity_bias_saturated=vp.velocity_bias.saturated,
                telemetry_rate_min_hz=(
                    vp.telemetry_rate_min_hz if math.isfinite(vp.telemetry_rate_min_hz) else None
                ),
                rate_requests=vp.rate_requests,
                label=vp.label,
            )
            for s, vp in sorted(station.vehicles.items())
        )
        leader = station.control.controller.leader_pos_m
        links = station.links.values()
        return cls(
            outcome=outcome,
            mission_time_s=station.control.t_s,
            wall_time_s=wall_time_s,
            steps=station.control.steps,
            behaviour=station.control.controller.behaviour,
            leader_pos_m=(float(leader[0]), float(leader[1]), float(leader[2])),
            vehicles=vehicles,
            min_separation_m=station.control.min_separation_m,
            min_clearance_m=station.control.min_clearance_m,
            keep_out_columns=station.control.keep_outs_taken,
            min_keep_out_m=station.control.min_keep_out_m,
            episodes=station.control.controller.episode,
            messages_sent=sum(lk.stats.sent for lk in links),
            setpoints_dropped=sum(lk.stats.setpoints_dropped for lk in links),
            messages_dropped=sum(lk.stats.messages_dropped for lk in links),
            bad_packets=sum(lk.stats.bad_packets for lk in links),
            unknown_sysid_messages=sum(station.unknown_sysids.values()),
            spoofed=sum(lk.stats.spoofed for lk in links),
            signature_rejected=sum(lk.stats.signature_rejected for lk in links),
            safety=(
                str(station.control.safety_stats.totals())
                if station.control.filtering
                else "safety filter: off (limits.safety.enabled false or all-sim default, "
                "no finite limit)"
            ),
            log=tuple(station.log),
            start_tolerance_m=station.config.start_tolerance_m,
            start_speed_tolerance_mps=station.config.start_speed_tolerance_mps,
            clipped_setpoints=station.clipped_setpoints(),
            rebinds_refused=station.rebinds_refused(),
            failure=station.failure,
            logging_error=logging_error,
        )

    @classmethod
    def from_controller(
        cls,
        core: ControllerCore,
        reports: Mapping[int, Mapping[str, Any]],
        mission: Mission,
        *,
        outcome: str,
        wall_time_s: float,
        logging_error: str | None = None,
    ) -> RunSummary:
        """A sharded run's summary (``runtime.sharded``): the law's figures
        from its controller, each vehicle and the links' counters from its
        shard's final report (``runtime.shard``, by shard index); the
        vehicles of a shard that sent none are ``lost``. ``outcome``
        "flown" becomes completed, degraded or failed as ``Station.outcome``
        decides it."""
        at = _at_last_step(core.control)
        reported = {v["sysid"]: v for d in reports.values() for v in d["vehicles"]}
        vehicles = []
        for v in sorted(mission.vehicles, key=lambda v: v.key):
            r = reported.get(v.key)
            vehicles.append(VehicleAtEnd(
                sysid=v.key,
                phase=r["phase"] if r else "lost",
                mode=r["mode"] if r else "?",
                position_m=at[v.key][0] if v.key in at else None,
                radius_m=at[v.key][1] if v.key in at else None,
                last_accel_ned_mps2=tuple(r["last_accel_ned_mps2"]) if r else (0.0, 0.0, 0.0),
                failure=r["failure"] if r else "its shard stopped answering",
                rate_requests=r["rate_requests"] if r else 0,
                telemetry_rate_min_hz=r["telemetry_rate_min_hz"] if r else None,
                velocity_bias_ned_mps=tuple(r["velocity_bias_ned_mps"]) if r else (0.0, 0.0, 0.0),
                velocity_bias_corrected=bool(r["velocity_bias_corrected"]) if r else False,
                velocity_bias_saturated=bool(r["velocity_bias_saturated"]) if r else False,
                label=r["label"] if r else mission.label(v.key),
            ))  # fmt: skip
        if outcome == "flown":
            flown = {k for d in reports.values() for k in d["flown"]}
            flown |= {k for k in core.control.charges if k not in reported}  # a dead shard's
            gone = [k for k in flown if reported.get(k, {}).get("phase") != "ended"]
            outcome = "completed" if not gone else "degraded"
            if core.failure is not None or (flown and len(gone) == len(flown)):
                outcome = "failed"

        def total(name: str) -> int:
            return sum(int(d[name]) for d in reports.values())

        rebinds: dict[int, int] = {}
        for d in reports.values():
            rebinds.update({int(k): int(n) for k, n in d.get("rebinds_refused", {}).items()})
        leader = core.control.controller.leader_pos_m
        log = list(core.log) + [line for d in reports.values() for line in d["log"]]
        return cls(
            outcome=outcome,
            mission_time_s=core.control.t_s,
            wall_time_s=wall_time_s,
            steps=core.control.steps,
            behaviour=core.control.controller.behaviour,
            leader_pos_m=(float(leader[0]), float(leader[1]), float(leader[2])),
            vehicles=tuple(vehicles),
            min_separation_m=core.control.min_separation_m,
            min_clearance_m=core.control.min_clearance_m,
            keep_out_columns=core.control.keep_outs_taken,
            min_keep_out_m=core.control.min_keep_out_m,
            episodes=core.control.controller.episode,
            messages_sent=total("messages_sent"),
            setpoints_dropped=total("setpoints_dropped"),
            messages_dropped=total("messages_dropped"),
            bad_packets=total("bad_packets"),
            unknown_sysid_messages=total("unknown_sysid_messages"),
            spoofed=total("spoofed"),
            signature_rejected=total("signature_rejected"),
            safety=str(core.control.safety_stats.totals())
            if core.control.filtering
            else "safety filter: off",
            log=tuple(log),
            start_tolerance_m=mission.settings.startup.start_tolerance,
            start_speed_tolerance_mps=mission.settings.startup.start_speed_tolerance,
            clipped_setpoints=total("clipped_setpoints"),
            rebinds_refused=rebinds,
            failure=core.failure,
            logging_error=logging_error,
        )

    def positions(self) -> dict[int, npt.NDArray[np.float64]]:
        """Mission-frame positions [m] at the last step, by vehicle key
        (``VehicleAtEnd.sysid``: the system id on a one-network mission)."""
        return {v.sysid: np.array(v.position_m) for v in self.vehicles if v.position_m is not None}

    def format(self) -> str:
        """A human-readable multi-line summary."""
        sep = f"{self.min_separation_m:.3f} m" if math.isfinite(self.min_separation_m) else "-"
        why = f" ({self.failure})" if self.failure else ""
        lines = [
            f"outcome: {self.outcome}{why}; mission time {self.mission_time_s:.2f} s in "
            f"{self.wall_time_s:.1f} s wall, {self.steps} control steps",
            f"leader at ({', '.join(f'{c:.3f}' for c in self.leader_pos_m)}) m, "
            f"behaviour {self.behaviour}, minimum separation {sep}",
            f"start-up: at its start within {self.start_tolerance_m:g} m and below "
            f"{self.start_speed_tolerance_mps:g} m/s (mission.startup.start_tolerance, "
            "start_speed_tolerance)",
        ]
        if math.isfinite(self.min_clearance_m):
            lines.append(
                f"avoidance episodes {self.episodes}, minimum box clearance "
                f"{self.min_clearance_m:.3f} m (negative: inside a box)"
            )
        if self.keep_out_columns:
            near = f"{self.min_keep_out_m:.3f} m" if math.isfinite(self.min_keep_out_m) else "-"
            lines.append(f"columns of vehicles out of the formation kept out of: "
                         f"{self.keep_out_columns}, closest member {near} (Eq. K1)")  # fmt: skip
        for v in self.vehicles:
            where = "-"
            if v.position_m is not None and v.radius_m is not None:
                xyz = ", ".join(f"{c:.3f}" for c in v.position_m)
                where = f"at ({xyz}) m, radius {v.radius_m:.4f} m"
            why = f" [{v.failure}]" if v.failure else ""
            b = v.velocity_bias_ned_mps
            bias = ""
            if any(b):
                how = "corrected" if v.velocity_bias_corrected else "not corrected"
                cap = ", at its cap" if v.velocity_bias_saturated else ""
                bias = f", velocity bias ({b[0]:+.4f}, {b[1]:+.4f}, {b[2]:+.4f}) m/s {how}{cap}"
            if v.rate_requests:
                why += (f" [telemetry as low as {v.telemetry_rate_min_hz:.1f} Hz; "
                        f"rate asked again {v.rate_requests} times]")  # fmt: skip
            who = v.label or str(v.sysid)
            lines.append(f"  vehicle {who:>3}: {v.phase:<8} {v.mode:<9} {where}{bias}{why}")
        lines.append(
            f"links: {self.messages_sent} messages sent, {self.setpoints_dropped} setpoints "
            f"and {self.messages_dropped} messages dropped, {self.bad_packets} bad packets, "
            f"{self.unknown_sysid_messages} from unknown systems, {self.spoofed} spoofed, "
            f"{self.signature_rejected} with bad signatures"
        )
        if self.rebinds_refused:
            names = {v.sysid: v.label or str(v.sysid) for v in self.vehicles}
            who = ", ".join(
                f"vehicle {names.get(s, s)}: {n}" for s, n in self.rebinds_refused.items()
            )
            lines.append(f"frames refused from another address than the vehicle's: {who}")
        if self.clipped_setpoints:
            lines.append(
                f"setpoints clipped to the ceiling or zeroed (non-finite): {self.clipped_setpoints}"
            )
        if self.logging_error:
            lines.append(f"logging: {self.logging_error}")
        lines.append(self.safety)
        return "\n".join(lines)


def _at_last_step(control: ControlLoop) -> dict[int, tuple[Vec3, float]]:
    """Each vehicle's mission-frame position [m] and radius [m] at the law's
    last step, by key."""
    last = control.last
    at: dict[int, tuple[Vec3, float]] = {}
    if last is not None:
        for i, key in enumerate(last.ids):
            p = last.pos_m[i]
            at[key] = ((float(p[0]), float(p[1]), float(p[2])), float(last.radii_m[i]))
    return at
