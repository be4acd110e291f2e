"""The virtual leader (Eq. 13): its force laws and its fixed-step RK4 integration.

Eq. 13, READING (third row ``D z_v`` is ``D z_v'``):
``M p_v'' + D p_v' = f_v - k p_v'``, i.e. ``a_v = (f_v - (D + k) v_v) / M``,
the same model as Eq. 1. The leader is integrated in vehicle time [s].

Force laws (``params.LeaderForce``):

- ``ConstantForce``: ``f_v`` is constant [N].
- ``ExpressionForce``: three expressions in ``x y z vx vy vz t`` compiled once
  by :mod:`gcs_swarm.control.expr` (never ``eval``).
- ``WaypointForce``: ``f_v = (D + k) s u``, ``u`` the unit vector to the current
  waypoint, so the terminal speed of Eq. 13 is ``s`` = the cruise speed. The
  leader switches to the next waypoint once within ``accept_radius`` of the
  current one (a discrete decision, taken once per integration step). At the
  last waypoint ``s = min(cruise, dist / T)`` with ``T = 4 M / (D + k)``: the
  closed loop ``M x'' + (D + k) x' + (D + k) x / T = 0`` is then critically
  damped, so the leader slows to a stop on the waypoint without overshoot.

READING (time scale, ``Gains.time_scale`` = lambda, docs/vehicle-envelope.md):
the leader is slowed like the vehicles, so the formation keeps its shape
around it. If X_v(s) solves Eq. 13 with force f_v(s, X, X') then
x_v(t) = X_v(t / lambda) solves
``lambda^2 M x'' = f_v(t / lambda, x, lambda x') - lambda (D + k) x'``:
the force law is read in the unscaled time and velocity, so a waypoint
leader cruises at ``speed / lambda`` and an expression in ``t`` or ``vx``
sees the paper's values. lambda = 1 multiplies and divides by 1.0: the
paper's leader bit for bit.

The leader's state is plain floats (it is one body, and numpy's per-call cost
would dominate); :class:`LeaderState` is immutable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gcs_swarm.control.expr import compile_expression
from gcs_swarm.control.params import (
    ConstantForce,
    ExpressionForce,
    Gains,
    LeaderForce,
    WaypointForce,
)

__all__ = ["MAX_LEADER_STEP_S", "LeaderLaw", "LeaderState"]

F64 = NDArray[np.float64]
_V3 = tuple[float, float, float]

#: Longest RK4 sub-step [s] used when the leader is advanced over a time jump.
MAX_LEADER_STEP_S = 0.02


@dataclass(frozen=True)
class LeaderState:
    """Leader position [m] and velocity [m/s] (mission frame) and the index of
    the waypoint it is heading for (0 for non-waypoint laws)."""

    pos_m: _V3
    vel_mps: _V3
    wp_index: int = 0

    @property
    def pos_array(self) -> F64:
        """Position as a ``(3,)`` array [m]."""
        return np.array(self.pos_m, dtype=np.float64)

    @property
    def vel_array(self) -> F64:
        """Velocity as a ``(3,)`` array [m/s]."""
        return np.array(self.vel_mps, dtype=np.float64)


def _v3(a: object) -> _V3:
    x, y, z = (float(c) for c in np.asarray(a, dtype=np.float64).reshape(3))
    return (x, y, z)


class LeaderLaw:
    """Eq. 13 with one of the mission's leader force laws; pure and reusable."""

    def __init__(self, force: LeaderForce, gains: Gains) -> None:
        self._gains = gains
        self._c = gains.D + gains.k
        self._lam = gains.time_scale
        self._c_flown = gains.damping_scaled
        self._inv_m = 1.0 / gains.mass_scaled
        self._spec = force
        if isinstance(force, ConstantForce):
            self._const: _V3 = _v3(force.force)
        elif isinstance(force, ExpressionForce):
            if len(force.exprs) != 3:
                raise ValueError(f"ExpressionForce needs 3 expressions, got {len(force.exprs)}")
            self._exprs = tuple(compile_expression(e) for e in force.exprs)
        elif isinstance(force, WaypointForce):
            if not force.waypoints:
                raise ValueError("WaypointForce needs at least one waypoint")
            if not force.cruise_speed > 0.0:
                raise ValueError(f"cruise_speed must be > 0, got {force.cruise_speed}")
            self._wps = tuple(_v3(w) for w in force.waypoints)
            self._t_slow = 4.0 * gains.M / self._c
        else:  # pragma: no cover - the union is closed
            raise TypeError(f"unknown leader force {force!r}")

    @property
    def spec(self) -> LeaderForce:
        """The force law this was built from."""
        return self._spec

    def force(self, t: float, pos: _V3, vel: _V3, wp_index: int = 0) -> _V3:
        """Leader force ``f_v`` [N] at time ``t`` [s] and state ``pos, vel``."""
        spec = self._spec
        if isinstance(spec, ConstantForce):
            return self._const
        if isinstance(spec, ExpressionForce):
            env = {
                "x": pos[0],
                "y": pos[1],
                "z": pos[2],
                "vx": vel[0],
                "vy": vel[1],
                "vz": vel[2],
                "t": t,
            }
            fx, fy, fz = self._exprs
            return (fx(env), fy(env), fz(env))
        assert isinstance(spec, WaypointForce)
        i = min(wp_index, len(self._wps) - 1)
        wx, wy, wz = self._wps[i]
        dx, dy, dz = wx - pos[0], wy - pos[1], wz - pos[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dist <= 0.0:
            return (0.0, 0.0, 0.0)
        speed = spec.cruise_speed
        if i == len(self._wps) - 1:
            speed = min(speed, dist / self._t_slow)
        g = self._c * speed / dist
        return (g * dx, g * dy, g * dz)

    def accel(self, t: float, pos: _V3, vel: _V3, wp_index: int = 0) -> _V3:
        """Eq. 13: ``a_v = (f_v - (D + k) v_v) / M`` [m/s^2], with the time
        scale's READING (module docstring): ``f_v`` at ``(t / lambda, x,
        lambda v)``, M and D + k as flown."""
        lam = self._lam
        if lam == 1.0:
            fx, fy, fz = self.force(t, pos, vel, wp_index)
        else:
            fx, fy, fz = self.force(
                t / lam, pos, (lam * vel[0], lam * vel[1], lam * vel[2]), wp_index
            )
        c, im = self._c_flown, self._inv_m
        return ((fx - c * vel[0]) * im, (fy - c * vel[1]) * im, (fz - c * vel[2]) * im)

    def next_waypoint(self, pos: _V3, wp_index: int) -> int:
        """Discrete waypoint switch: skip every waypoint within ``accept_radius``
        (never past the last one). Identity for the other force laws."""
        spec = self._spec
        if not isinstance(spec, WaypointForce):
            return wp_index
        last = len(self._wps) - 1
        while wp_index < last:
            w = self._wps[wp_index]
            if math.dist(w, pos) > spec.accept_radius:
                break
            wp_index += 1
        return wp_index

    def initial_state(self, pos: object, vel: object) -> LeaderState:
        """A state at ``pos, vel`` with the waypoint index already switched."""
        p = _v3(pos)
        return LeaderState(p, _v3(vel), self.next_waypoint(p, 0))

    def restart(self, state: LeaderState, pos: object, vel: object) -> LeaderState:
        """The state ``pos, vel`` keeping the waypoint progress of ``state``
        (Eq. 13 restarting from the centroid after an avoidance episode)."""
        p = _v3(pos)
        return LeaderState(p, _v3(vel), self.next_waypoint(p, state.wp_index))

    def rk4_step(self, t: float, state: LeaderState, h: float) -> LeaderState:
        """One classical RK4 step of length ``h`` [s]; the waypoint index is held
        within the step and switched after it."""
        w = state.wp_index
        p0, v0 = state.pos_m, state.vel_mps
        a1 = self.accel(t, p0, v0, w)
        p2 = _axpy(p0, 0.5 * h, v0)
        v2 = _axpy(v0, 0.5 * h, a1)
        a2 = self.accel(t + 0.5 * h, p2, v2, w)
        p3 = _axpy(p0, 0.5 * h, v2)
        v3 = _axpy(v0, 0.5 * h, a2)
        a3 = self.accel(t + 0.5 * h, p3, v3, w)
        p4 = _axpy(p0, h, v3)
        v4 = _axpy(v0, h, a3)
        a4 = self.accel(t + h, p4, v4, w)
        h6 = h / 6.0
        pos = tuple(p0[i] + h6 * (v0[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i]) for i in range(3))
        vel = tuple(v0[i] + h6 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]) for i in range(3))
        p = (pos[0], pos[1], pos[2])
        return LeaderState(p, (vel[0], vel[1], vel[2]), self.next_waypoint(p, w))

    def advance(
        self, t0: float, state: LeaderState, t1: float, max_step_s: float = MAX_LEADER_STEP_S
    ) -> LeaderState:
        """Integrate from ``t0`` to ``t1`` [s] in equal RK4 sub-steps of at most
        ``max_step_s``; ``t1 <= t0`` returns ``state`` unchanged. The cost grows
        linearly with ``t1 - t0``."""
        span = t1 - t0
        if not span > 0.0:
            return state
        n = max(1, math.ceil(span / max_step_s - 1e-9))
        h = span / n
        for i in range(n):
            state = self.rk4_step(t0 + i * h, state, h)
        return state

    def predict(
        self, t0: float, state: LeaderState, h: float, n_steps: int
    ) -> tuple[F64, F64, LeaderState]:
        """The leader's obstacle-free path: ``n_steps`` RK4 steps of ``h`` [s]
        from ``state`` at ``t0``. Returns ``times (n+1,)``, ``pos_m (n+1, 3)``
        (including the start) and the final state."""
        pos = np.empty((n_steps + 1, 3))
        pos[0] = state.pos_m
        for i in range(n_steps):
            state = self.rk4_step(t0 + i * h, state, h)
            pos[i + 1] = state.pos_m
        times: F64 = t0 + h * np.arange(n_steps + 1, dtype=np.float64)
        return times, pos, state


def _axpy(x: _V3, a: float, y: _V3) -> _V3:
    return (x[0] + a * y[0], x[1] + a * y[1], x[2] + a * y[2])
