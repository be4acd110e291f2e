"""A constant bias in a vehicle's reported velocity, estimated from its own
reported positions (docs/velocity-bias.md).

Why: Eq. 1 damps the measured velocity with ``D + k`` (10 with the paper's
Example 1 gains, ``lambda (D + k)`` at time scale lambda), so a velocity
report that is off by a constant ``b`` is an acceleration ``-(D + k) b / M``
that the springs must hold. ArduCopter 4.5.6 SITL reports, while hovering
still, a velocity of about (-0.015, +0.013, 0.000) m/s NED on every vehicle
(its position does not move: 0.000 m/s over 30 s windows, measured in
docs/sitl.md). Through the damping that held the Example 1 octahedron's
radii 1.2 % off the law's equilibrium, the whole formation displaced about
0.11 m against the bias; the same law with that bias added in simulation
gives the same radii to 0.01 m.

Estimate (READING): over a sliding window of the vehicle's own telemetry,
in its own time (``time_boot_ms``),

    b = ( integral of v dt  -  (p(t) - p(t - W)) ) / W

with the integral by the trapezoid rule over consecutive reports. It is
exact for a constant bias whatever the vehicle does, and zero for telemetry
whose velocity is the derivative of its position. The window slides in
checkpoints of ``window_s / 20``; the estimate is refreshed at each
checkpoint, once the window spans ``min_span_s``. A report gap longer than
``max_gap_s``, time going backwards (a reboot) or a position step that the
velocity does not explain by more than ``jump_m`` (an EKF reset) restarts the
window and keeps the last estimate until the new window is long enough. An
estimate longer than ``max_mps`` is held at that length and flagged
(``saturated``): a velocity that wrong is a vehicle problem, not a bias to
correct silently.

Pure computation, no I/O, O(1) per report.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

__all__ = ["BiasSettings", "VelocityBiasObserver"]


@dataclass(frozen=True)
class BiasSettings:
    """``correct``: subtract the estimate from the velocity the law uses;
    ``window_s`` [s] of telemetry per estimate; ``max_mps`` [m/s] largest
    estimate applied. The rest as in the module docstring."""

    correct: bool = True
    window_s: float = 10.0
    max_mps: float = 0.3
    min_span_s: float = 2.0
    max_gap_s: float = 0.5
    jump_m: float = 1.0

    def __post_init__(self) -> None:
        if not (self.window_s > 0.0 and self.min_span_s > 0.0 and self.max_gap_s > 0.0):
            raise ValueError("window_s, min_span_s and max_gap_s must be > 0")
        if not (self.max_mps >= 0.0 and self.jump_m > 0.0):
            raise ValueError("max_mps must be >= 0 and jump_m > 0")


class VelocityBiasObserver:
    """The velocity bias of one vehicle, in the frame of its reports (NED)."""

    __slots__ = (
        "_checkpoints",
        "_every_s",
        "_last",
        "_sum",
        "bias",
        "resets",
        "samples",
        "saturated",
        "settings",
    )

    def __init__(self, settings: BiasSettings | None = None) -> None:
        self.settings = settings if settings is not None else BiasSettings()
        self._every_s = self.settings.window_s / 20.0
        # (t, p, integral of v dt up to t) at each checkpoint, oldest first.
        self._checkpoints: deque[tuple[float, tuple[float, float, float], list[float]]] = deque()
        self._last: tuple[float, float, float, float, float, float, float] | None = None
        self._sum = [0.0, 0.0, 0.0]
        self.bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
        """The estimate [m/s] (NED); zeros until a window is long enough."""
        self.resets = 0
        """Windows restarted by a gap, a reboot or a position jump."""
        self.samples = 0
        self.saturated = False
        """True when the last estimate was longer than ``max_mps`` (held at it)."""

    def update(
        self, t_s: float, x: float, y: float, z: float, vx: float, vy: float, vz: float
    ) -> None:
        """Take one report: time [s] on the vehicle's clock, position [m], velocity [m/s]."""
        last = self._last
        self._last = (t_s, x, y, z, vx, vy, vz)
        self.samples += 1
        if last is None:
            self._restart(t_s, (x, y, z))
            return
        dt = t_s - last[0]
        if dt <= 0.0 or dt > self.settings.max_gap_s:
            if dt != 0.0:  # a duplicate changes nothing; a gap or a reboot restarts
                self.resets += 1
                self._restart(t_s, (x, y, z))
            return
        s = self._sum
        ix = 0.5 * (vx + last[4]) * dt
        iy = 0.5 * (vy + last[5]) * dt
        iz = 0.5 * (vz + last[6]) * dt
        jump = math.hypot(x - last[1] - ix, y - last[2] - iy, z - last[3] - iz)
        if jump > self.settings.jump_m:
            self.resets += 1
            self._restart(t_s, (x, y, z))
            return
        s[0] += ix
        s[1] += iy
        s[2] += iz
        cps = self._checkpoints
        if t_s - cps[-1][0] >= self._every_s:
            cps.append((t_s, (x, y, z), s[:]))
            while len(cps) > 2 and t_s - cps[1][0] >= self.settings.window_s:
                cps.popleft()
            self._estimate()

    def _restart(self, t_s: float, p: tuple[float, float, float]) -> None:
        self._sum = [0.0, 0.0, 0.0]
        self._checkpoints.clear()
        self._checkpoints.append((t_s, p, [0.0, 0.0, 0.0]))

    def _estimate(self) -> None:
        (t0, p0, i0), (t1, p1, i1) = self._checkpoints[0], self._checkpoints[-1]
        span = t1 - t0
        if span < self.settings.min_span_s:
            return
        b = [((i1[k] - i0[k]) - (p1[k] - p0[k])) / span for k in range(3)]
        size = math.hypot(*b)
        cap = self.settings.max_mps
        self.saturated = size > cap
        if self.saturated:
            scale = cap / size
            b = [c * scale for c in b]
        self.bias = (b[0], b[1], b[2])

    @property
    def correction(self) -> tuple[float, float, float]:
        """What to subtract from the reported velocity: the estimate when
        ``settings.correct``, else zeros."""
        return self.bias if self.settings.correct else (0.0, 0.0, 0.0)
