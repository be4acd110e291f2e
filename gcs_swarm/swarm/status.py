"""The status line of a flying swarm, from its core's figures (no I/O)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gcs_swarm.swarm.core import SwarmCore

__all__ = ["StatusLine"]


class StatusLine:
    """One line at a time with the run's figures as they evolve (``line``)."""

    def __init__(self) -> None:
        self._mark: tuple[float, float, int] | None = None
        """(wall time, mission time, steps) at the last line."""

    def line(
        self, core: SwarmCore, now: float, drops: int = 0, refused: dict[int, int] | None = None
    ) -> str:
        """Mission time, control rate over the last interval and the pace
        against ``now`` [s], behaviour, radius range, separation now and its
        minimum so far, minimum obstacle clearance so far, peak commanded
        acceleration, each vehicle's phase and mode, then the links'
        ``drops`` (setpoints overwritten), low telemetry rates, clipped
        setpoints and the frames ``refused`` per vehicle."""
        control = core.control
        last = control.last
        parts = [f"t={control.t_s:7.2f}s"]
        t = control.t_s
        if self._mark is not None and t > self._mark[1]:
            # Control steps per second of vehicle time (the mission rate when
            # keeping up, in real time or lockstep alike), and the pace.
            wall0, t0, steps0 = self._mark
            parts.append(f"{(control.steps - steps0) / (t - t0):5.1f} Hz")
            if now > wall0:
                parts.append(f"x{(t - t0) / (now - wall0):.1f}")
        self._mark = (now, t, control.steps)
        if last is not None and last.ids:
            r = last.radii_m
            parts.append(f"{last.law.behaviour:9s} r={r.min():.3f}..{r.max():.3f} m")
            sep = last.min_separation_m
            if math.isfinite(sep):
                parts.append(f"sep {sep:.3f} (min {control.min_separation_m:.3f}) m")
            clr = control.min_clearance_m
            if math.isfinite(clr):
                parts.append(f"min clearance {clr:.3f} m")
            parts.append(f"peak |a| {control.peak_accel_mps2:.2f} m/s^2")
        vehicles = core.vehicles
        parts.append(" ".join(f"{vp.label}:{vp.phase.value}/{vp.mode_name}"
                              for _, vp in sorted(vehicles.items())))  # fmt: skip
        if drops:
            parts.append(f"drops {drops}")
        low = [f"{vp.label}:{vp.telemetry_rate_hz:.1f}Hz" for _, vp in sorted(vehicles.items())
               if vp.rate_low and vp.telemetry_rate_hz is not None]  # fmt: skip
        if low:
            parts.append("low telemetry " + " ".join(low))
        clipped = sum(vp.clipped_setpoints for vp in vehicles.values())
        if clipped:
            parts.append(f"clipped setpoints {clipped}")
        if refused:
            parts.append("rebind refused " + " ".join(f"{s}:{n}" for s, n in refused.items()))
        return " | ".join(parts)
