"""A mission file flown through the in-process simulator (``gcs-swarm simulate``).

Maps a validated ``Mission`` onto ``gcs_swarm.simulation.simulate``: the
initial vehicles are active from t = 0, reserves wait at their start until
their join event, events keep their mission times (seconds from the start of
the formation phase), and every commanded acceleration passes through the
same limits and safety filter the station applies (``SafetyFilter``), paced
at the mission's control period. With no limits and the filter off (the
paper's missions) the filter is the identity and the paper's law runs
exactly.

Pure computation: no I/O apart from what the caller asks of the result.
"""

from __future__ import annotations

from dataclasses import dataclass

from gcs_swarm.control.safety import SafetyFilter, SafetyHook, SafetySummary, filter_acts
from gcs_swarm.mission import Mission
from gcs_swarm.simulation import SimResult, simulate

__all__ = ["MissionSimResult", "simulate_mission"]


@dataclass(frozen=True)
class MissionSimResult:
    """The trajectories and, when limits or the safety filter were in force,
    how often and how hard the filter intervened."""

    result: SimResult
    safety: SafetySummary | None

    def text(self) -> str:
        """The summary printed by ``gcs-swarm simulate``."""
        lines = [self.result.summary().text()]
        if self.safety is not None:
            lines.append(f"safety filter: {self.safety}")
        return "\n".join(lines)


def simulate_mission(
    mission: Mission, *, dt_s: float = 0.01, duration_s: float | None = None
) -> MissionSimResult:
    """Simulate ``mission`` for its duration (or ``duration_s``) with RK4 step
    ``dt_s`` [s]. Deterministic: the same mission gives the same result."""
    law = mission.law
    vehicles = mission.vehicles
    hook: SafetyHook | None = None
    if filter_acts(law.limits, law.safety):
        period = 1.0 / mission.settings.rate
        hook = SafetyHook(SafetyFilter(law.limits, law.safety, law.obstacles, dt=period))
    result = simulate(
        law,
        [v.start for v in vehicles],
        [v.q for v in vehicles],
        duration=mission.settings.duration if duration_s is None else duration_s,
        dt=dt_s,
        active=[not v.reserve for v in vehicles],
        events=[(e.t, e.action, e.sysid) for e in mission.events],
        ids=[v.sysid for v in vehicles],
        accel_filter=hook,
    )
    return MissionSimResult(result, hook.stats.summary() if hook is not None else None)
