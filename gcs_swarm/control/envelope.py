"""The vehicle envelope on the station's side: what is sent is what the vehicle
will do (docs/vehicle-envelope.md).

Pure numpy, no I/O. ArduCopter feeds a GUIDED acceleration target through its
position controller, which moves its own acceleration towards the target at
most PSC_JERK_XY (a horizontal vector rate) and PSC_JERK_Z per second and
flies it with a lag of about 0.2 s (/work/ardupilot-facts.md). This module
owns:

- ``ARDUCOPTER``: ArduCopter 4.5's default envelope (WPNAV_ACCEL 2.5,
  WPNAV_ACCEL_Z 1.0 m/s^2, PSC_JERK_XY/Z 5 m/s^3, WPNAV_SPEED 10,
  WPNAV_SPEED_UP 2.5, WPNAV_SPEED_DN 1.5 m/s, lag 0.2 s);
- ``cap_accel`` (E1) and ``jerk_limit`` (E2), and ``CommandShaper``, which
  applies both every control step per vehicle id, so the command sent is
  inside the envelope's accelerations and changes by at most its jerk per
  step;
- the demand check (E3): ``Demand`` (peak |a_xy|, |a_z|, jerk, speeds of a
  run) and ``suggest_time_scale``, the smallest ``gains.time_scale`` lambda
  that fits, from the time scale's exponents (accelerations scale 1/lambda^2,
  jerk 1/lambda^3, speed 1/lambda), and ``demand_lines`` (the words).

With the default (unbounded) envelope every function here is the identity,
bit for bit: the paper's figures are unchanged.

    (E1)  a_xy <- a_xy min(1, A_xy / |a_xy|),  a_z <- clip(a_z, -A_z, A_z)
    (E2)  a_xy <- a'_xy + (a_xy - a'_xy) min(1, J_xy dt / |a_xy - a'_xy|),
          a_z  <- a'_z + clip(a_z - a'_z, -J_z dt, J_z dt)
    (E3)  lambda = max(sqrt(a_peak / a_lim), cbrt(j_peak / j_lim), v_peak / v_lim)

a' is the previous command sent to the same vehicle (zero for a vehicle not
seen before: it hovers).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.params import Envelope

__all__ = [
    "ARDUCOPTER",
    "CommandShaper",
    "Demand",
    "cap_accel",
    "demand_lines",
    "jerk_limit",
    "suggest_time_scale",
]

FloatArray = NDArray[np.float64]

ARDUCOPTER = Envelope(
    accel_xy=2.5,
    accel_z=1.0,
    jerk_xy=5.0,
    jerk_z=5.0,
    speed_xy=10.0,
    speed_up=2.5,
    speed_down=1.5,
    lag_s=0.2,
)
"""ArduCopter 4.5's default envelope: WPNAV_ACCEL 250 cm/s^2, WPNAV_ACCEL_Z
100 cm/s^2, PSC_JERK_XY/Z 5 m/s^3, WPNAV_SPEED 1000, WPNAV_SPEED_UP 250,
WPNAV_SPEED_DN 150 cm/s, and the measured 0.2 s lag (ardupilot-facts.md)."""


def _scale_rows(vec: FloatArray, limit: float) -> FloatArray:
    """Rows of ``vec (N, k)`` scaled down to norm <= ``limit`` (in place)."""
    norm = np.sqrt(np.einsum("ij,ij->i", vec, vec))
    over = norm > limit
    if np.any(over):
        vec[over] *= (limit / norm[over])[:, None]
    return vec


def cap_accel(accel_mps2: FloatArray, envelope: Envelope) -> FloatArray:
    """(E1): each row of ``accel_mps2 (N, 3)`` [m/s^2, mission frame] with its
    horizontal norm <= ``accel_xy`` (direction kept) and |a_z| <= ``accel_z``.
    A copy; infinite bounds leave the rows bit-exact."""
    out = np.array(accel_mps2, dtype=np.float64, copy=True).reshape(-1, 3)
    if math.isfinite(envelope.accel_xy):
        out[:, :2] = _scale_rows(out[:, :2], envelope.accel_xy)
    if math.isfinite(envelope.accel_z):
        np.clip(out[:, 2], -envelope.accel_z, envelope.accel_z, out=out[:, 2])
    return out


def jerk_limit(
    prev_mps2: FloatArray, accel_mps2: FloatArray, envelope: Envelope, dt_s: float
) -> FloatArray:
    """(E2): move ``prev_mps2`` towards ``accel_mps2`` (both (N, 3) [m/s^2]) by
    at most ``jerk_xy * dt_s`` horizontally (vector norm) and ``jerk_z *
    dt_s`` vertically, as ArduCopter's shape_accel does per cycle. A copy of
    ``accel_mps2`` where the jerk is infinite."""
    out = np.array(accel_mps2, dtype=np.float64, copy=True).reshape(-1, 3)
    prev = np.asarray(prev_mps2, dtype=np.float64).reshape(-1, 3)
    if math.isfinite(envelope.jerk_xy):
        step = _scale_rows(out[:, :2] - prev[:, :2], envelope.jerk_xy * dt_s)
        out[:, :2] = prev[:, :2] + step
    if math.isfinite(envelope.jerk_z):
        dz = np.clip(out[:, 2] - prev[:, 2], -envelope.jerk_z * dt_s, envelope.jerk_z * dt_s)
        out[:, 2] = prev[:, 2] + dz
    return out


class CommandShaper:
    """Per-vehicle (E1) then (E2), every control step of ``dt_s`` [s].

    Keeps the last command sent to each vehicle id. ``shape`` is the identity
    (the input array itself) while the envelope is unbounded in acceleration
    and jerk. A vehicle missing from a step keeps its last command (the
    autopilot holds it); one never seen or ``forget``-ten (it left) starts
    from zero acceleration (hover).
    """

    def __init__(self, envelope: Envelope, dt_s: float) -> None:
        if not 0.0 < dt_s < math.inf:
            raise ValueError(f"dt_s must be a positive period in seconds, got {dt_s}")
        self.envelope = envelope
        self.dt_s = dt_s
        self._last: dict[int, FloatArray] = {}

    @property
    def active(self) -> bool:
        """Whether ``shape`` can change a command (a finite accel or jerk bound)."""
        e = self.envelope
        return any(math.isfinite(x) for x in (e.accel_xy, e.accel_z, e.jerk_xy, e.jerk_z))

    def previous(self, ids: Sequence[int]) -> FloatArray:
        """The last command [m/s^2] sent to each of ``ids`` (N, 3); zero if none."""
        out = np.zeros((len(ids), 3))
        for j, vid in enumerate(ids):
            last = self._last.get(int(vid))
            if last is not None:
                out[j] = last
        return out

    def shape(self, ids: Sequence[int], accel_mps2: FloatArray) -> FloatArray:
        """The commands to send (N, 3) [m/s^2]: (E1) then (E2) from each
        vehicle's previous command; remembers them."""
        if not self.active:
            return accel_mps2
        capped = cap_accel(accel_mps2, self.envelope)
        out = jerk_limit(self.previous(ids), capped, self.envelope, self.dt_s)
        for j, vid in enumerate(ids):
            self._last[int(vid)] = out[j].copy()
        return out

    def forget(self, vid: int) -> None:
        """Vehicle ``vid`` left: its next command starts from hover."""
        self._last.pop(int(vid), None)

    def retain(self, ids: Sequence[int]) -> None:
        """Forget every vehicle not in ``ids`` (the simulator: absent = left)."""
        keep = {int(v) for v in ids}
        for vid in [v for v in self._last if v not in keep]:
            del self._last[vid]


@dataclass(frozen=True)
class Demand:
    """What a run asked of the vehicles: peaks over every vehicle and sample.

    accel_xy, accel_z [m/s^2] largest horizontal norm and |vertical| of the
    command; jerk_xy, jerk_z [m/s^3] largest rate of change of the command
    (horizontal vector, vertical), between samples; speed_xy, speed_up,
    speed_down [m/s] largest horizontal speed, climb and descent rate;
    t_form_s time to form [s] (None if it did not)."""

    accel_xy: float
    accel_z: float
    jerk_xy: float
    jerk_z: float
    speed_xy: float
    speed_up: float
    speed_down: float
    t_form_s: float | None = None

    def ratios(self, envelope: Envelope) -> dict[str, float]:
        """Demand / limit per quantity (0 for an unbounded limit)."""
        pairs = {
            "accel_xy": (self.accel_xy, envelope.accel_xy),
            "accel_z": (self.accel_z, envelope.accel_z),
            "jerk_xy": (self.jerk_xy, envelope.jerk_xy),
            "jerk_z": (self.jerk_z, envelope.jerk_z),
            "speed_xy": (self.speed_xy, envelope.speed_xy),
            "speed_up": (self.speed_up, envelope.speed_up),
            "speed_down": (self.speed_down, envelope.speed_down),
        }
        return {k: (d / lim if math.isfinite(lim) and lim > 0.0 else 0.0) for k, (d, lim) in
                pairs.items()}  # fmt: skip


_EXPONENT = {"accel": 2.0, "jerk": 3.0, "speed": 1.0}


def suggest_time_scale(demand: Demand, envelope: Envelope, *, current: float = 1.0) -> float:
    """(E3): the smallest time scale (a multiple of 0.1, >= ``current``) whose
    demand fits ``envelope``, given the ``demand`` measured at ``current``.

    Flying the law lambda times slower divides accelerations by lambda^2,
    jerk by lambda^3 and speeds by lambda (``Gains.time_scale``), so the
    factor needed on top of ``current`` is the largest of sqrt, cbrt and the
    plain ratio of demand to limit."""
    need = 1.0
    for name, ratio in demand.ratios(envelope).items():
        power = _EXPONENT[name.split("_")[0]]
        need = max(need, ratio ** (1.0 / power))
    lam = current * need
    return max(current, math.ceil(lam * 10.0 - 1e-9) / 10.0)


def demand_lines(demand: Demand, envelope: Envelope, *, current: float = 1.0) -> list[str]:
    """Words for each quantity over the envelope (empty if all fit), then the
    fix as one line: ``gains.time_scale: X``."""
    units = {"accel": "m/s^2", "jerk": "m/s^3", "speed": "m/s"}
    over = [
        f"{name} {getattr(demand, name):.3g} {units[name.split('_')[0]]}"
        f" > {getattr(envelope, name):.3g}"
        for name, ratio in demand.ratios(envelope).items()
        if ratio > 1.0
    ]
    if not over:
        return []
    lam = suggest_time_scale(demand, envelope, current=current)
    return [
        f"the gains demand more than the vehicle envelope ({', '.join(over)});"
        f" fly the law slower: gains.time_scale: {lam:g}"
    ]
