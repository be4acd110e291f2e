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

Pure computation, no I/O, O(1) per report. ``BiasBank`` runs many vehicles'
observers with one report each as arrays (the station's telemetry table, at
each control step): the same floats as each observer's ``update``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["BiasBank", "BiasSettings", "VelocityBiasObserver"]


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
        # (t, x, y, z, and the integral of v dt up to t) at each checkpoint, oldest
        # first: flat tuples of floats, which the cyclic garbage collector stops
        # tracking at its first pass (1,500 vehicles keep 30,000 of them).
        self._checkpoints: deque[tuple[float, float, float, float, float, float, float]] = deque()
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
        if t_s - self._checkpoints[-1][0] >= self._every_s:
            self._checkpoint(t_s, x, y, z, s[0], s[1], s[2])

    def _checkpoint(
        self, t_s: float, x: float, y: float, z: float, sx: float, sy: float, sz: float
    ) -> None:
        """A checkpoint at ``t_s`` (position ``x, y, z``, integral ``sx, sy, sz``):
        the window slides and the estimate is refreshed."""
        cps = self._checkpoints
        cps.append((t_s, x, y, z, sx, sy, sz))
        while len(cps) > 2 and t_s - cps[1][0] >= self.settings.window_s:
            cps.popleft()
        self._estimate()

    def _restart(self, t_s: float, p: tuple[float, float, float]) -> None:
        self._sum = [0.0, 0.0, 0.0]
        self._checkpoints.clear()
        self._checkpoints.append((t_s, p[0], p[1], p[2], 0.0, 0.0, 0.0))

    def _estimate(self) -> None:
        c0, c1 = self._checkpoints[0], self._checkpoints[-1]
        span = c1[0] - c0[0]
        if span < self.settings.min_span_s:
            return
        # (integral - displacement) / span per axis: positions at 1-3, integrals at 4-6
        b = [((c1[k + 4] - c0[k + 4]) - (c1[k + 1] - c0[k + 1])) / span for k in range(3)]
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


_JUMP_BAND = 1.0 - 1e-9
"""``BiasBank`` takes a report's unexplained step as surely within ``jump_m``
when its squared norm (x, y, z summed in order: ``kernels.bias_common_reports``)
is below ``jump_m^2`` times this; one nearer the threshold goes to the
observer's ``math.hypot`` (the sum's rounding is a few units in 1e-16)."""


class BiasBank:
    """The ``VelocityBiasObserver`` of many vehicles, one row each, fed one
    report per row at a time as arrays (``update``).

    The common report (the last one less than ``max_gap_s`` before, a step
    surely within ``jump_m``, no checkpoint due) is the observer's
    arithmetic element by element: the same IEEE operations in the same
    order, so the same floats. Every other report (a row's first, a gap, a
    reboot, a possible jump) goes to the observer's own ``update``; a due
    checkpoint to its ``_checkpoint``; so the window, the estimate and the
    counters stay the observer's. A row's running state (last report,
    integral, reports counted) lives in the arrays while the row is
    *banked*, else in its observer; ``sync`` writes it back.
    """

    def __init__(self, n: int) -> None:
        # The compiled common report (numba, about 0.4 s to load in a process)
        # comes with the bank, made with the station's table before any report.
        from gcs_swarm.control import kernels

        self._kernels = kernels
        self.observers: list[VelocityBiasObserver | None] = [None] * n
        self._banked = np.zeros(n, dtype=bool)
        self._last = np.zeros((n, 7))
        """The last report: t [s], x, y, z [m], vx, vy, vz [m/s] (banked rows)."""
        self._sum = np.zeros((n, 3))
        """The integral of v dt since the window restarted (banked rows)."""
        self._count = np.zeros(n, dtype=np.int64)
        """Reports taken here since the row was banked (``samples`` less the observer's)."""
        self._cp_t = np.zeros(n)
        """The newest checkpoint's time [s] (banked rows)."""
        self._lim = np.zeros((n, 3))
        """Per row: checkpoint interval [s], ``max_gap_s``, ``jump_m^2 * _JUMP_BAND``."""

    def attach(self, k: int, obs: VelocityBiasObserver) -> None:
        """Row ``k`` is ``obs`` from now on (banked once it has a report)."""
        self.observers[k] = obs
        st = obs.settings
        self._lim[k] = (obs._every_s, st.max_gap_s, st.jump_m * st.jump_m * _JUMP_BAND)
        self._banked[k] = False
        self._bank(k)

    def detach(self, k: int) -> VelocityBiasObserver | None:
        """Row ``k`` lets its observer go, its running state written back."""
        self._unbank(k)
        obs, self.observers[k] = self.observers[k], None
        return obs

    def sync(self, k: int) -> VelocityBiasObserver | None:
        """Row ``k``'s observer with its running state written back (the
        row stays banked)."""
        obs = self.observers[k]
        if obs is not None and self._banked[k]:
            last = self._last[k].tolist()
            obs._last = (last[0], last[1], last[2], last[3], last[4], last[5], last[6])
            obs._sum = self._sum[k].tolist()
            obs.samples += int(self._count[k])
            self._count[k] = 0
        return obs

    def _bank(self, k: int) -> None:
        obs = self.observers[k]
        if obs is None or obs._last is None or self._banked[k]:
            return
        self._last[k] = obs._last
        self._sum[k] = obs._sum
        self._cp_t[k] = obs._checkpoints[-1][0]
        self._count[k] = 0
        self._banked[k] = True

    def _unbank(self, k: int) -> None:
        self.sync(k)
        self._banked[k] = False

    def update(self, ks: Sequence[int], reports: npt.NDArray[np.float64]) -> list[int]:
        """One report each of rows ``ks`` (distinct, each with an observer):
        ``reports (K, 7)``, t [s] on the vehicle's clock, x, y, z [m], vx, vy,
        vz [m/s]. Returns the rows whose estimate may have changed."""
        kk = np.asarray(ks, dtype=np.intp)
        reports = np.asarray(reports, dtype=np.float64)
        # The common report, element by element in the arrays (compiled:
        # kernels.bias_common_reports); the others go to their observers.
        odd, due = self._kernels.bias_common_reports(
            kk, reports, self._last, self._sum, self._count, self._cp_t, self._lim, self._banked
        )
        changed: list[int] = []
        for j in odd:
            k = int(kk[j])
            obs = self.observers[k]
            assert obs is not None
            self._unbank(k)
            obs.update(*reports[j].tolist())
            self._bank(k)
            changed.append(k)
        for j in due:
            k = int(kk[j])
            obs = self.observers[k]
            assert obs is not None
            tj, x, y, z = reports[j, :4].tolist()
            obs._checkpoint(tj, x, y, z, *self._sum[k].tolist())
            self._cp_t[k] = tj
            changed.append(k)
        return changed
