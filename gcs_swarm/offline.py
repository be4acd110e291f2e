"""The offline mission simulation (``gcs-swarm simulate``, ``gcs_swarm.simulate``):
a mission file flown without MAVLink, through the in-process integrator.

Maps a validated ``Mission`` onto ``gcs_swarm.integrator.integrate``: the
initial vehicles are active from t = 0, reserves wait at their start until
their join event, events keep their mission times (seconds from the start of
the formation phase), and every commanded acceleration passes through the
same limits and safety filter the station applies (``SafetyFilter``), paced
at the mission's control period. With no limits and the filter off (the
paper's missions) the filter is the identity and the paper's law runs
exactly. A vehicle that leaves is held where it left (``integrate``); with
the filter on the others keep the separation from its column (Eq. K1,
docs/vehicle-safety.md), as the station keeps them from a vehicle that
left and flies on.

When the mission states ``limits.envelope`` the reference models the vehicle
(docs/vehicle-envelope.md): the station's command path of
``gcs_swarm.control.loop.ControlLoop`` (filter planning within the
envelope, then ``CommandShaper``) once per control period, flown by the
envelope's jerk-limited, lagged vehicle (``integrator.vehicle_step``), so the
step is the control period whatever ``dt_s`` says. ``envelope_demand`` and
``demand_report`` measure what the gains ask of an ideal point mass and
say when it is more than an envelope (``gcs-swarm check``, the start-up
report).

Pure computation: no I/O apart from what the caller asks of the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from gcs_swarm.analysis import command_demand
from gcs_swarm.control.envelope import CommandShaper, Demand, demand_lines
from gcs_swarm.control.keep_out import lost_column
from gcs_swarm.control.params import Envelope, LawConfig
from gcs_swarm.control.safety import (
    SafetyFilter,
    SafetyHook,
    SafetyStats,
    SafetyTotals,
    filter_acts,
)
from gcs_swarm.integrator import F64, SimResult, integrate
from gcs_swarm.mission import Mission

__all__ = [
    "DEMAND_DT_S",
    "EnvelopeHook",
    "MissionSimResult",
    "demand_report",
    "envelope_demand",
    "simulate_mission",
]

DEMAND_DT_S = 0.1
"""RK4 step [s] of the demand estimate: coarse, so ``gcs-swarm check`` stays
fast (about a second per 10 s of mission on one core, the station's limits
filtered at every stage); RK4 is stable there for the paper's gains (damping
(D + k) / M = 10 1/s). The peaks are within a few per cent of a 0.01 s run
for Example 1; jerk, a difference of samples, is the coarsest of them."""


@dataclass(frozen=True)
class MissionSimResult:
    """The trajectories and, when limits or the safety filter were in force,
    how often and how hard the filter intervened; ``envelope`` the vehicle
    envelope modelled (None: the ideal point mass)."""

    result: SimResult
    safety: SafetyTotals | None
    envelope: Envelope | None = None

    def text(self) -> str:
        """The summary printed by ``gcs-swarm simulate``."""
        lines = [self.result.figures().text()]
        if self.envelope is not None:
            e = self.envelope
            lines.append(
                f"vehicle envelope modelled: |a_xy| <= {e.accel_xy:g}, |a_z| <= {e.accel_z:g}"
                f" m/s^2, jerk {e.jerk_xy:g}/{e.jerk_z:g} m/s^3, lag {e.lag_s:g} s"
            )
        if self.safety is not None:
            lines.append(str(self.safety))
        return "\n".join(lines)


@dataclass
class EnvelopeHook:
    """The station's command path as a simulator hook, called ONCE per control
    step (the vehicle-model path of ``integrate``): the safety filter, planning
    from each vehicle's last command, then the shaper (E1-E2)."""

    shaper: CommandShaper
    safety_filter: SafetyFilter | None = None
    stats: SafetyStats = field(default_factory=SafetyStats)

    def __call__(
        self, t: float, ids: tuple[int, ...], pos_m: F64, vel_mps: F64, accel_mps2: F64
    ) -> F64:
        """The command sent (N, 3) [m/s^2] for the law's ``accel_mps2``."""
        accel = accel_mps2
        self.shaper.retain(ids)  # a vehicle out of the simulation left: it rejoins from rest
        if self.safety_filter is not None:
            prev = self.shaper.previous(ids)
            accel, report = self.safety_filter.filter(
                pos_m, vel_mps, accel, ids=ids, prev_accel_mps2=prev
            )
            self.stats.update(report)
        return self.shaper.shape(ids, accel)


@dataclass
class _HeldColumns:
    """The station's rule for vehicles out of the formation and in the air
    (``swarm.departures.live_columns``), on the integrator's inactive ones:
    each is held at rest (where it left, or a reserve at its start), and the
    members keep the separation from where it may be (Eq. K1, no coast, no
    speed, braking as the envelope allows): a column for one that flew and
    left (climbing for an RTL failsafe), the cube of Eq. K1c for a reserve,
    with the filter on."""

    mission: Mission
    envelope: Envelope
    filter: SafetyFilter | None

    def __post_init__(self) -> None:
        if not self.mission.law.safety.enabled:
            self.filter = None  # the rows (e) exist only with the filter on

    def __call__(self, held: dict[int, F64], flown: set[int]) -> None:
        assert self.filter is not None
        m = self.mission
        brake = min(self.envelope.accel_xy, m.law.limits.a_max)
        fs, by_key = m.settings.failsafe, {v.key: v for v in m.vehicles}
        zero = np.zeros(3)
        rtl = m.settings.end == "rtl"
        self.filter.set_keep_out([
            lost_column(p, zero, zero, coast_s=0.0, brake_mps2=brake, down=key in flown,
                        climbs=rtl and key in flown and fs.gcs_for(by_key[key].autopilot))
            for key, p in sorted(held.items())
        ])  # fmt: skip


def _with_envelope(law: LawConfig, envelope: Envelope) -> LawConfig:
    return replace(law, limits=replace(law.limits, envelope=envelope))


def simulate_mission(
    mission: Mission,
    *,
    dt_s: float = 0.01,
    duration_s: float | None = None,
    ideal: bool = False,
    envelope: Envelope | None = None,
) -> MissionSimResult:
    """Simulate ``mission`` for its duration (or ``duration_s``) with RK4 step
    ``dt_s`` [s]. Deterministic: the same mission gives the same result.

    The vehicle envelope is ``envelope`` if given, else the mission's
    ``limits.envelope``; a bounded one is modelled (module docstring) unless
    ``ideal``, which flies the point mass with the station planning as for
    one."""
    env = mission.law.limits.envelope if envelope is None else envelope
    law = _with_envelope(mission.law, Envelope() if ideal else env)
    period = 1.0 / mission.settings.rate
    hook: SafetyHook | EnvelopeHook | None = None
    model = None
    shaper = CommandShaper(env, period)
    if not ideal and env.bounded and (shaper.active or env.lag_s > 0.0):
        filt = None
        if filter_acts(law.limits, law.safety):
            filt = SafetyFilter(law.limits, law.safety, law.obstacles, dt=period)
        hook = EnvelopeHook(shaper, filt)
        model, dt_s = env, period
    elif filter_acts(law.limits, law.safety):
        hook = SafetyHook(SafetyFilter(law.limits, law.safety, law.obstacles, dt=period))
    vehicles = mission.vehicles
    held = _HeldColumns(mission, env, getattr(hook, "safety_filter", None))
    result = integrate(
        law,
        [v.start for v in vehicles],
        [v.q for v in vehicles],
        duration=mission.settings.duration if duration_s is None else duration_s,
        dt=dt_s,
        active=[not v.reserve for v in vehicles],
        events=[(e.t, e.action, e.key) for e in mission.events],
        ids=[v.key for v in vehicles],
        accel_filter=hook,
        vehicle=model,
        on_out=held if held.filter is not None else None,
    )
    stats = None
    if isinstance(hook, EnvelopeHook):
        stats = hook.stats.totals() if hook.safety_filter is not None else None
    elif hook is not None:
        stats = hook.stats.totals()
    return MissionSimResult(result, stats, model)


def envelope_demand(mission: Mission, *, dt_s: float = DEMAND_DT_S) -> Demand:
    """What the mission's gains ask of an ideal point mass (the station's
    limits a_max, v_max, floor and fence, no envelope, no barrier): the peaks of
    ``analysis.command_demand`` over a ``dt_s`` RK4 run of the whole mission."""
    # The law and the station's hard limits only: the separation and clearance
    # barriers act near a conflict, not on the gains' demand, and cost most.
    law = replace(mission.law, safety=replace(mission.law.safety, enabled=False))
    out = simulate_mission(replace(mission, law=law), dt_s=dt_s, ideal=True)
    r = out.result
    # The law's own steps: a behaviour switch or a change of the active set.
    steps = np.any(r.active[1:] != r.active[:-1], axis=1)
    for t_switch, _ in r.switches:
        steps |= np.isclose(r.times_s[1:], t_switch, rtol=0.0, atol=1e-9 + 1e-6 * dt_s)
    return command_demand(
        r.times_s, r.accel_mps2, r.vel_mps, t_form_s=r.figures().time_to_form_s, steps=steps
    )


def demand_report(
    mission: Mission, envelope: Envelope, *, demand: Demand | None = None
) -> list[str]:
    """Lines saying where the gains demand more than ``envelope`` and the
    smallest ``gains.time_scale`` that fits (``control.envelope.demand_lines``);
    empty when everything fits or the envelope is unbounded. For the start-up
    report with the envelope read from the vehicles, and ``gcs-swarm check``
    with the mission's."""
    if not envelope.bounded:
        return []
    d = envelope_demand(mission) if demand is None else demand
    return demand_lines(d, envelope, current=mission.law.gains.time_scale)
