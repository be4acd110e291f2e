"""The velocity a vehicle should have if it had flown the law's accelerations
exactly: the velocity setpoint that goes beside the acceleration when a
vehicle is flown with ``setpoint: velocity+acceleration`` (docs/setpoints.md).

Why: an acceleration-only setpoint (type_mask 3135) bypasses PX4's velocity
loop, so nothing on the vehicle rejects what disturbs the acceleration.
PX4 v1.14 SIH, measured (docs/sitl.md, PX4 section): first-order drag of
1.0 1/s, and a slowly varying bias of 0.1-0.3 m/s^2 per axis, which moved
the tetrahedron's radii up to +1.28 % off the law's equilibrium. Given a
velocity setpoint and the acceleration as its feed-forward, PX4's velocity
PID (MPC_XY_VEL_P/I/D_ACC) closes on the difference and its integrator
takes the bias and the drag out, while the feed-forward keeps the law's
acceleration as the vehicle's response.

Eq. V1 (READING): per vehicle, in the mission frame, at the control step of
mission time ``t_k`` that sends the acceleration ``a_k``,

    v_ref(t_k) = v_ref(t_{k-1}) + a_{k-1} (t_k - t_{k-1})

the integral of what was sent (each acceleration held until the next), then
held within ``max_error_mps`` of the measured velocity on each axis, so a
vehicle that cannot follow (an acceleration limit, a gust) never winds the
reference up: at most ``P * max_error_mps`` of extra acceleration is asked
of it (1.8 m/s^2 with PX4's MPC_XY_VEL_P_ACC 1.8 and 1 m/s). A vehicle seen
for the first time, or not sent to for more than ``max_gap_s``, starts from
its measured velocity. A non-finite measurement holds nothing back (the
reference integrates on); one that would start a reference gives none (NaN:
the acceleration goes out alone).

Pure computation, no I/O; time is the caller's ``t``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["MAX_ERROR_MPS", "MAX_GAP_S", "VelocityReference"]

FloatArray = npt.NDArray[np.float64]

MAX_ERROR_MPS = 1.0
"""Largest distance of the reference from the measured velocity, per axis
[m/s]. The law asks at most a few m/s^2 (``limits.a_max``); a reference 1 m/s
ahead already asks PX4's velocity loop for 1.8 m/s^2 more."""

MAX_GAP_S = 0.5
"""A vehicle not sent to for longer than this [s] starts again from its
measured velocity (it left the formation, or its telemetry stopped)."""


@dataclass
class _Row:
    t: float
    v_ref: FloatArray
    a_sent: FloatArray


class VelocityReference:
    """Eq. V1 for a set of vehicles keyed by system id."""

    def __init__(self, max_error_mps: float = MAX_ERROR_MPS, max_gap_s: float = MAX_GAP_S):
        if not max_error_mps > 0.0 or not max_gap_s > 0.0:
            raise ValueError("max_error_mps and max_gap_s must be positive")
        self.max_error_mps = max_error_mps
        self.max_gap_s = max_gap_s
        self._rows: dict[int, _Row] = {}
        self.restarts = 0
        """How many times a known vehicle's reference started again (a gap)."""
        self.held = 0
        """How many setpoints had their reference held at ``max_error_mps``."""

    def setpoints(
        self,
        sysids: Sequence[int],
        t: float,
        vel_mps: FloatArray,
        accel_mps2: FloatArray,
    ) -> FloatArray:
        """The velocity setpoints ``(K, 3)`` [m/s] (Eq. V1) for the vehicles
        ``sysids`` sent ``accel_mps2[k]`` at mission time ``t``, whose measured
        velocity is ``vel_mps[k]`` (mission frame, as the law saw it)."""
        out = np.empty((len(sysids), 3))
        e = self.max_error_mps
        for k, sysid in enumerate(sysids):
            v = vel_mps[k]
            row = self._rows.get(sysid)
            if row is None or not 0.0 <= t - row.t <= self.max_gap_s:
                if row is not None:
                    self.restarts += 1
                ref = np.array(v, dtype=np.float64)
            else:
                ref = row.v_ref + row.a_sent * (t - row.t)
                lo, hi = v - e, v + e
                if ((ref < lo) | (ref > hi)).any():  # False where v is NaN: not held
                    self.held += 1
                    ref = np.clip(ref, lo, hi)
            if not np.isfinite(ref).all():  # only from a non-finite first measurement
                self._rows.pop(sysid, None)
                out[k] = np.nan  # no velocity setpoint: the acceleration alone goes out
                continue
            self._rows[sysid] = _Row(t, ref, np.array(accel_mps2[k], dtype=np.float64))
            out[k] = ref
        return out

    def forget(self, sysid: int) -> None:
        """Drop a vehicle (it left): it starts from its measured velocity if it
        comes back."""
        self._rows.pop(sysid, None)
