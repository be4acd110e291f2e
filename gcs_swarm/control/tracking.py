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


_UNKNOWN = (float("nan"),) * 7
"""The state row of a vehicle with no reference: NaN time fails the gap test."""


class VelocityReference:
    """Eq. V1 for a set of vehicles keyed by system id, one step's rows at once
    (numpy over the rows: it runs for every velocity-tracked vehicle at the
    control rate)."""

    def __init__(self, max_error_mps: float = MAX_ERROR_MPS, max_gap_s: float = MAX_GAP_S):
        if not max_error_mps > 0.0 or not max_gap_s > 0.0:
            raise ValueError("max_error_mps and max_gap_s must be positive")
        self.max_error_mps = max_error_mps
        self.max_gap_s = max_gap_s
        self._rows: dict[int, tuple[float, ...]] = {}
        """sysid -> (t, v_ref (3), a_sent (3)) of its last setpoint."""
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
        rows = self._rows
        known = [rows.get(s) for s in sysids]
        state = np.array([r if r is not None else _UNKNOWN for r in known]).reshape(-1, 7)
        v = np.asarray(vel_mps, dtype=np.float64)
        dt = t - state[:, 0]
        ok = np.asarray((dt >= 0.0) & (dt <= self.max_gap_s))  # False for NaN: unknown
        self.restarts += sum(
            1 for r, o in zip(known, ok.tolist(), strict=True) if r is not None and not o
        )
        ref = state[:, 1:4] + state[:, 4:7] * dt[:, None]
        e = self.max_error_mps
        lo, hi = v - e, v + e
        below, above = ref < lo, ref > hi  # False where v is NaN: not held
        held = ok & (below | above).any(axis=1)
        self.held += int(held.sum())
        ref = np.where(below, lo, np.where(above, hi, ref))
        ref = np.where(ok[:, None], ref, v)
        # Only a non-finite first measurement leaves no reference: NaN, the
        # acceleration goes out alone.
        finite = np.asarray(np.isfinite(ref).all(axis=1))
        out: FloatArray = np.where(finite[:, None], ref, np.nan)
        a = np.asarray(accel_mps2, dtype=np.float64)
        for s, good, r, acc in zip(sysids, finite.tolist(), ref.tolist(), a.tolist(), strict=True):
            if good:
                rows[s] = (t, *r, *acc)
            else:
                rows.pop(s, None)
        return out

    def forget(self, sysid: int) -> None:
        """Drop a vehicle (it left): it starts from its measured velocity if it
        comes back."""
        self._rows.pop(sysid, None)
