"""A slowly changing bias between the acceleration a vehicle is sent and the
one it flies, estimated from its own velocity reports and taken out of what
it is sent (docs/sitl.md, PX4).

Why: Eq. 1 models each vehicle as a point mass that flies the commanded
acceleration. ArduCopter flies an acceleration setpoint through its own
position controller, which takes out its airframe's errors; PX4 v1.14 in
OFFBOARD flies an acceleration-only setpoint open loop (thrust and tilt from
the acceleration, PositionControl::_accelerationControl), so whatever the
airframe adds (drag, a tilt-estimate error, a hover-thrust error) stays. On
PX4 SITL (SIH) the law's mean command over 20 s windows of a held 17 m
tetrahedron was 0.1-0.3 m/s^2 per axis: a bias the springs hold at
bias / stiffness, 0.1-0.2 m of radius (+1.3 % on one vehicle).

Estimate (READING): over a sliding window W of the vehicle's own telemetry,
in mission time (the vehicles' clocks),

    b = ( (v(t) - v(t - W)) - integral of a_sent dt over the window ) / W

where ``a_sent`` is what the station sent, held from one control step to the
next. It is the mean of (flown - sent) acceleration over the window: exact
for a constant bias whatever the law commands; with a drag ``-k v`` it also
holds ``-k`` times the window's mean velocity. Taking that part out would
cancel the drag with a velocity feedback delayed by ~W / 2, which the law's
damping does not survive: measured on the emulator's PX4 (drag 1/s), the
17 m sitl_px4 tetrahedron grew to 40 m in 10 s while it formed from 12 m. So
the estimate is refreshed only over windows whose mean velocity is below
``still_mps`` (0.05 m/s: at most 0.05 k of drag in it), i.e. while the vehicle
holds its place in the formation; otherwise the last estimate is kept.
The estimate does not depend on itself: it is computed from what was sent,
compensation included, so taking it out closes no loop (but for the
autopilot's delay d, which couples it with weight d / W, 0.03 for 0.3 s in
10 s). Checkpoints every ``window_s / 20``; the estimate is refreshed
at each, once the window spans ``min_span_s``. A gap longer than ``max_gap_s``
or time going backwards restarts the window and zeroes the estimate. An
estimate longer than ``max_mps2`` is held at that length and flagged.

Pure computation, no I/O, O(1) per step.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

__all__ = ["AccelBiasObserver", "AccelBiasSettings"]

Vec3 = tuple[float, float, float]
_ZERO: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class AccelBiasSettings:
    """``correct``: take the estimate out of what is sent; None: for ``px4``
    vehicles only (ArduCopter's position controller does it on the vehicle);
    ``window_s`` [s]; ``max_mps2`` [m/s^2] largest estimate applied; the rest as
    in the module docstring."""

    correct: bool | None = None
    window_s: float = 10.0
    max_mps2: float = 0.5
    min_span_s: float = 2.0
    max_gap_s: float = 0.5
    still_mps: float = 0.05

    def __post_init__(self) -> None:
        if not (self.window_s > 0.0 and self.min_span_s > 0.0 and self.max_gap_s > 0.0):
            raise ValueError("window_s, min_span_s and max_gap_s must be > 0")
        if not (self.max_mps2 >= 0.0 and self.still_mps >= 0.0):
            raise ValueError("max_mps2 and still_mps must be >= 0")

    def applies(self, autopilot: str) -> bool:
        """Whether a vehicle of ``autopilot`` gets the correction."""
        return autopilot == "px4" if self.correct is None else self.correct


class AccelBiasObserver:
    """The acceleration bias of one vehicle, in the mission frame."""

    __slots__ = ("_checkpoints", "_every_s", "_int", "_last", "_sent", "bias", "estimate",
                 "resets", "saturated", "settings")  # fmt: skip

    def __init__(self, settings: AccelBiasSettings | None = None) -> None:
        self.settings = settings if settings is not None else AccelBiasSettings()
        self._every_s = self.settings.window_s / 20.0
        # (t, v, integrals of a_sent dt and of v dt up to t) at each checkpoint, oldest first.
        self._checkpoints: deque[tuple[float, Vec3, tuple[float, ...]]] = deque()
        self._last: tuple[float, Vec3] | None = None
        self._int: list[float] = [0.0] * 6
        self._sent: Vec3 = _ZERO
        self.bias: Vec3 = _ZERO
        """The estimate applied [m/s^2], flown minus sent; zeros until a window is long enough."""
        self.estimate: Vec3 = _ZERO
        """The last estimate made, kept when a window restarts (for the summary)."""
        self.resets = 0
        self.saturated = False

    def _restart(self) -> None:
        self._checkpoints.clear()
        self._int = [0.0] * 6
        self.bias = _ZERO
        self.saturated = False

    def update(self, t_s: float, v: Vec3) -> Vec3:
        """Take the velocity [m/s] at mission time ``t_s`` (the acceleration last
        given to ``sent`` was flown since the previous update); returns the bias."""
        s = self.settings
        last = self._last
        self._last = (t_s, v)
        if last is not None:
            dt = t_s - last[0]
            if dt < 0.0 or dt > s.max_gap_s:
                self.resets += 1
                self._restart()
            else:
                a, i, u = self._sent, self._int, last[1]
                for k in range(3):
                    i[k] += a[k] * dt
                    i[3 + k] += 0.5 * (u[k] + v[k]) * dt  # trapezoid
        cks = self._checkpoints
        if not cks or t_s - cks[-1][0] >= self._every_s:
            cks.append((t_s, v, tuple(self._int)))
            while len(cks) > 1 and t_s - cks[1][0] >= s.window_s:
                cks.popleft()
            t0, v0, i0 = cks[0]
            span = t_s - t0
            i = self._int
            mv = [(i[3 + k] - i0[3 + k]) / span for k in range(3)] if span > 0.0 else [0.0] * 3
            still = math.sqrt(mv[0] * mv[0] + mv[1] * mv[1] + mv[2] * mv[2]) <= s.still_mps
            if span >= s.min_span_s and still:
                b = tuple(((v[k] - v0[k]) - (i[k] - i0[k])) / span for k in range(3))
                n = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
                self.saturated = n > s.max_mps2
                q = s.max_mps2 / n if self.saturated else 1.0
                self.bias = self.estimate = (b[0] * q, b[1] * q, b[2] * q)
        return self.bias

    def sent(self, a: Vec3) -> None:
        """The acceleration [m/s^2] sent this step (flown until the next update)."""
        self._sent = a

    def forget(self) -> None:
        """The vehicle left: the next update starts a new window."""
        self._last = None
        self._restart()
