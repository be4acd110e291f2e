"""The sane magnitudes of a mission, and the check of the leader's whole path.

Bounds (docs/mission-format.md, "Bounds"); each is where the rest of the
system already stops believing numbers, so a mission outside them could
never fly:

- positions (starts, the leader, waypoints, boxes, fences, homes): every
  component within ``POSITION_LIMIT_M`` = 100 km of the mission origin, the
  station's own plausibility bound on LOCAL_POSITION_NED (telemetry farther
  out is refused, ``gcs_swarm.mavlink.inbound``);
- speeds (the leader's start velocity and path, a waypoint cruise speed):
  every component within ``SPEED_LIMIT_MPS`` = 200 m/s, the same telemetry
  bound;
- the leader's acceleration along its path: at most ``ACCEL_LIMIT_MPS2`` =
  1000 m/s^2, the largest acceleration the station sends
  (``gcs_swarm.mavlink.vehicle.ACCEL_CEILING_MPS2``);
- gains and charges: at most ``GAIN_MAX`` = 1e6, and the mass M, the one
  gain the law divides by, at least ``GAIN_MIN`` = 1e-6 (the others only
  > 0, damping from 0). With positions within 100 km and distances over
  1e-6 m (closer starts are refused) every term of Eqs. 1, 7, 9 and 13 is a
  product of a few factors below 1e12, so the law's outputs stay finite (far
  below 1.8e308; a test evaluates the law at the corners);
- ``mission.duration`` at most ``DURATION_MAX_S`` = 4 h (a battery lasts
  less; the leader check below costs time in proportion to it).

``leader_path_problem`` flies Eq. 13 over the whole mission as the station
does outside avoidance episodes (the same RK4 sub-steps of
``MAX_LEADER_STEP_S`` from ``leader.start`` at t = 0; a constant force in
closed form) and names the first sample where the force is not finite, an
expression cannot be evaluated, or the path leaves the bounds above.
"""

from __future__ import annotations

import functools
import math

from gcs_swarm.control.leader import MAX_LEADER_STEP_S, LeaderLaw
from gcs_swarm.control.params import ConstantForce, ExpressionForce, Gains, Leader
from gcs_swarm.errors import ExpressionError

__all__ = [
    "ACCEL_LIMIT_MPS2",
    "DURATION_MAX_S",
    "GAIN_MAX",
    "GAIN_MIN",
    "POSITION_LIMIT_M",
    "SPEED_LIMIT_MPS",
    "leader_path_problem",
]

POSITION_LIMIT_M = 1.0e5
SPEED_LIMIT_MPS = 200.0
ACCEL_LIMIT_MPS2 = 1000.0
GAIN_MIN = 1.0e-6
GAIN_MAX = 1.0e6
DURATION_MAX_S = 4 * 3600.0


def _g(x: float) -> str:
    return f"{x:.6g}"


def _beyond(t: float, pos: tuple[float, ...], vel: tuple[float, ...]) -> str | None:
    """Why the leader's state at ``t`` is out of bounds, or None."""
    for name, x in zip("xyz", pos, strict=True):
        if not abs(x) <= POSITION_LIMIT_M:  # also NaN
            return (
                f"the leader reaches {name} = {_g(x)} m at t = {t:.2f} s, beyond"
                f" {POSITION_LIMIT_M:g} m from the origin (where the station stops believing"
                " telemetry)"
            )
    for name, v in zip(("vx", "vy", "vz"), vel, strict=True):
        if not abs(v) <= SPEED_LIMIT_MPS:
            return (
                f"the leader reaches {name} = {_g(v)} m/s at t = {t:.2f} s, beyond"
                f" {SPEED_LIMIT_MPS:g} m/s"
            )
    return None


def leader_path_problem(leader: Leader, gains: Gains, duration_s: float) -> tuple[str, str] | None:
    """``(key path, message)`` of the first problem on the leader's path over
    ``[0, duration_s]`` (module docstring), or None. The key path is
    ``leader.force[i]`` for an expression that fails, else ``leader.force``."""
    return _problem(leader, gains, float(duration_s))


@functools.lru_cache(maxsize=32)
def _problem(leader: Leader, gains: Gains, duration_s: float) -> tuple[str, str] | None:
    force = leader.force
    if isinstance(force, ConstantForce):
        return _constant(force, leader, gains, duration_s)
    law = LeaderLaw(force, gains)
    state = law.initial_state(leader.start, leader.velocity)
    n = max(1, math.ceil(duration_s / MAX_LEADER_STEP_S - 1e-9))
    h = duration_s / n
    t = 0.0
    try:
        for i in range(n + 1):
            t = i * h
            a = law.accel(t, state.pos_m, state.vel_mps, state.wp_index)
            why = _beyond(t, state.pos_m, state.vel_mps)
            if why is None and not math.hypot(*a) <= ACCEL_LIMIT_MPS2:
                why = (
                    f"the leader's acceleration (Eq. 13) reaches {_g(math.hypot(*a))} m/s^2 at"
                    f" t = {t:.2f} s, over {ACCEL_LIMIT_MPS2:g} m/s^2"
                )
            if why is not None:
                return ("leader.force", why)
            if i < n:
                state = law.rk4_step(t, state, h)
    except ExpressionError as err:
        text = str(err)
        k = 0
        if isinstance(force, ExpressionForce):
            k = next((j for j, e in enumerate(force.exprs) if repr(e.strip()) in text), 0)
        return (
            f"leader.force[{k}]",
            f"{text} (on the leader's path, t = {t:.2f} s of the mission)",
        )
    return None


def _constant(
    force: ConstantForce, leader: Leader, gains: Gains, duration_s: float
) -> tuple[str, str] | None:
    """Eq. 13 with a constant force in closed form, per component, as flown
    (mass lambda^2 M, damping lambda (D + k)): with tau = M'/c' and terminal
    velocity w = f/c', v(t) = w + (v0 - w) e^(-t/tau) and
    p(t) = p0 + w t + (v0 - w) tau (1 - e^(-t/tau)). Each velocity component
    is monotone, so each position component is extreme at t = 0, at the end,
    or where its velocity crosses zero; the acceleration is largest at t = 0."""
    m, c = gains.mass_scaled, gains.damping_scaled
    tau = m / c
    a0 = [(f - c * v) / m for f, v in zip(force.force, leader.velocity, strict=True)]
    if not math.hypot(*a0) <= ACCEL_LIMIT_MPS2:
        return (
            "leader.force",
            f"the leader's acceleration (Eq. 13) is {_g(math.hypot(*a0))} m/s^2 at t = 0,"
            f" over {ACCEL_LIMIT_MPS2:g} m/s^2",
        )

    def state(t: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        decay = math.exp(-t / tau)
        pos, vel = [], []
        for p0, v0, f in zip(leader.start, leader.velocity, force.force, strict=True):
            w = f / c
            vel.append(w + (v0 - w) * decay)
            pos.append(p0 + w * t + (v0 - w) * tau * -math.expm1(-t / tau))
        return tuple(pos), tuple(vel)

    times = {0.0, duration_s}
    for v0, f in zip(leader.velocity, force.force, strict=True):
        w = f / c
        if w != v0 and 0.0 < -w / (v0 - w) < 1.0:  # v crosses zero: e^(-t/tau) = -w/(v0-w)
            times.add(min(duration_s, -tau * math.log(-w / (v0 - w))))
    inside = 0.0
    for t in sorted(times):
        if _beyond(t, *state(t)) is not None:
            # Between the extremes every component is monotone: bisect for
            # the first moment out of bounds (to 1 ms).
            lo, hi = inside, t
            while hi - lo > 1e-3:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if _beyond(mid, *state(mid)) is not None else (mid, hi)
            why = _beyond(hi, *state(hi))
            assert why is not None
            return ("leader.force", why)
        inside = t
    return None
