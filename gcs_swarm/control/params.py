"""Parameters of the formation law: frozen dataclasses, the contract between
the mission file (``gcs_swarm.mission``) and the law (``gcs_swarm.control``).

Every quantity is SI (metres, seconds, kilograms, newtons) in the mission
frame: x east, y north, z up (formation-law.md section 1). NED never appears
here.

The printed-variant switches of formation-law.md live in one place,
``Readings``: each field is False for the spec's READING and True for the
equation as printed in the paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

__all__ = [
    "AvoidMethod",
    "Avoidance",
    "Box",
    "ConstantForce",
    "Envelope",
    "ExpressionForce",
    "Gains",
    "HeadingSource",
    "LawConfig",
    "Leader",
    "LeaderForce",
    "Limits",
    "Plane",
    "Readings",
    "Safety",
    "Sense",
    "Vec3",
    "WaypointForce",
]

Vec3 = tuple[float, float, float]
AvoidMethod = Literal["rotational", "classic", "none"]
Plane = Literal["auto", "horizontal", "vertical"]
Sense = Literal["auto", "cw", "ccw", "up", "down"]
HeadingSource = Literal["velocity", "desired"]


@dataclass(frozen=True)
class Readings:
    """Printed-variant switches (formation-law.md). False = the spec's READING.

    - ``eq10_printed``: Eq. 10 as printed, q_n twice in the repulsion
      (READING: Eqs. 8-9, one q_n).
    - ``eq11_printed``: Eq. 11 literal ``F - f`` (diverges; READING: ``F + f_s``).
    - ``eq12_printed``: Eq. 12 without alpha^2 (READING: keep alpha^2).
    - ``eq27_printed``: Eq. 27 per-component form (READING: vector form).
    - ``repulsion_in_avoidance``: keep inter-vehicle repulsion during an
      avoidance episode. False is the paper mode (Eq. 29 as printed drops it).
    """

    eq10_printed: bool = False
    eq11_printed: bool = False
    eq12_printed: bool = False
    eq27_printed: bool = False
    repulsion_in_avoidance: bool = False


@dataclass(frozen=True)
class Gains:
    """Gains of Eqs. 1, 7, 9 (paper defaults of Example 1).

    M [kg] mass, D and k [N s/m] damping (total D + k), k_s [N/m^3] sphere
    spring (Eq. 7), k_r [N m^2/C^2] repulsion (Eq. 9), alpha [m] sphere
    parameter (Eq. 7), q_default [C] charge of a vehicle that names none.

    time_scale (lambda >= 1, dimensionless) is a READING of Eqs. 1 and 13
    (docs/vehicle-envelope.md, "time scale"): if X(s) solves
    ``M X'' + (D + k) X' = f(X)`` then x(t) = X(t / lambda) solves
    ``lambda^2 M x'' + lambda (D + k) x' = f(x)``, so the same equilibrium
    shape is flown lambda times slower, with accelerations / lambda^2, jerk /
    lambda^3 and speeds / lambda. The law uses ``mass_scaled`` and
    ``damping_scaled``; lambda = 1 is the paper, bit for bit. The virtual
    leader is slowed the same way (``gcs_swarm.control.leader``).

    repulsion_cutoff [m] (an option, not the paper's): Eq. 9 summed only over
    the vehicles closer than it (Eq. 9c, docs/formation-law.md section 3a),
    through a cell list, O(N log N) instead of O(N^2). None (the default) is
    the exact all-pairs sum, unchanged bit for bit.
    """

    M: float = 1.0
    D: float = 1.0
    k: float = 9.0
    k_s: float = 1.0
    k_r: float = 0.2
    alpha: float = 2.0
    q_default: float = 10.0
    time_scale: float = 1.0
    repulsion_cutoff: float | None = None

    @property
    def mass_scaled(self) -> float:
        """READING (time scale, docs/vehicle-envelope.md): the M of Eqs. 1/13
        flown, ``lambda^2 M`` [kg] with lambda = ``time_scale``."""
        return self.M * (self.time_scale * self.time_scale)

    @property
    def damping_scaled(self) -> float:
        """READING (time scale): the total damping of Eqs. 1/13 flown,
        ``lambda (D + k)`` [N s/m]."""
        return (self.D + self.k) * self.time_scale


@dataclass(frozen=True)
class Box:
    """Axis-aligned box obstacle (Eq. 14): centre p_0 [m] and half-extents
    (v1, v2, v3) [m], mission frame."""

    centre: Vec3
    half_extents: Vec3


@dataclass(frozen=True)
class Avoidance:
    """Obstacle avoidance settings (Eqs. 19-28).

    - ``method``: ``rotational`` (the paper), ``classic`` (radial baseline
      field), ``none`` (obstacles ignored by the law).
    - ``plane``: ``auto`` picks by look-ahead (rule after Eq. 25), or forced.
    - ``sense``: ``auto`` is the acute-angle rule latched at field entry, or
      forced (``cw``/``ccw`` horizontal, ``up``/``down`` vertical).
    - ``r0``: field range in ellipsoidal-radius units (formation-law.md s5).
    - ``F_D`` [N]: size of the desired force of Eq. 28.
    - ``target_margin``: slot targets lie at rho >= r0 + target_margin (s8).
    - ``heading``: phi of the vertical field (Eqs. 20/23). ``velocity`` is the
      spec's reading (azimuth of the velocity, of the desired force when
      nearly at rest); ``desired`` always takes the desired force's azimuth
      (Eq. 28), which stays steady when a safety filter holds a vehicle
      against a face and its velocity direction swings.
    """

    method: AvoidMethod = "rotational"
    plane: Plane = "auto"
    sense: Sense = "auto"
    r0: float = 2.0
    F_D: float = 10.0
    target_margin: float = 0.5
    heading: HeadingSource = "velocity"


@dataclass(frozen=True)
class ConstantForce:
    """Leader force f_v [N], constant (Eq. 13)."""

    force: Vec3


@dataclass(frozen=True)
class ExpressionForce:
    """Leader force f_v [N] as three expressions in x, y, z, vx, vy, vz, t
    (the leader's own state, mission frame), e.g. ``("10", "10*sin(x/8)", "2")``.
    Evaluated by the safe evaluator in ``gcs_swarm.control.expr``."""

    exprs: tuple[str, str, str]


@dataclass(frozen=True)
class WaypointForce:
    """Leader flies through ``waypoints`` [m] at ``cruise_speed`` [m/s]; the
    force is chosen so that Eq. 13's terminal speed is the cruise speed.

    ``accept_radius`` [m]: the leader heads for the next waypoint once it is
    this close to the current one; it slows to a stop at the last one
    (``gcs_swarm.control.leader``)."""

    waypoints: tuple[Vec3, ...]
    cruise_speed: float
    accept_radius: float = 0.5


LeaderForce = ConstantForce | ExpressionForce | WaypointForce


@dataclass(frozen=True)
class Leader:
    """Virtual leader (Eq. 13): initial position [m], velocity [m/s], force law."""

    start: Vec3 = (0.0, 0.0, 0.0)
    velocity: Vec3 = (0.0, 0.0, 0.0)
    force: LeaderForce = ConstantForce((0.0, 0.0, 0.0))


@dataclass(frozen=True)
class Envelope:
    """What a vehicle's own position controller can deliver (mission frame, SI).

    ArduCopter feeds a GUIDED acceleration target through its position
    controller, which rate-limits it by a jerk (PSC_JERK_XY, PSC_JERK_Z) and
    bounds what it will fly (WPNAV_ACCEL, WPNAV_ACCEL_Z, WPNAV_SPEED,
    WPNAV_SPEED_UP, WPNAV_SPEED_DN; docs/vehicle-envelope.md). ``inf`` means
    unbounded: the default envelope is the paper's ideal point mass.

    accel_xy [m/s^2] bound on the horizontal norm |(a_x, a_y)|; accel_z
    [m/s^2] bound on |a_z|; jerk_xy, jerk_z [m/s^3] bounds on the rate of
    change of the horizontal (norm) and vertical acceleration; speed_xy
    [m/s] horizontal speed; speed_up, speed_down [m/s] climb and descent
    speed; lag_s [s] first-order lag of the achieved acceleration on the
    (jerk-limited) command.
    """

    accel_xy: float = math.inf
    accel_z: float = math.inf
    jerk_xy: float = math.inf
    jerk_z: float = math.inf
    speed_xy: float = math.inf
    speed_up: float = math.inf
    speed_down: float = math.inf
    lag_s: float = 0.0

    def tighter(self, other: Envelope) -> Envelope:
        """The envelope inside both (per-field minimum; the larger lag)."""
        return Envelope(
            accel_xy=min(self.accel_xy, other.accel_xy),
            accel_z=min(self.accel_z, other.accel_z),
            jerk_xy=min(self.jerk_xy, other.jerk_xy),
            jerk_z=min(self.jerk_z, other.jerk_z),
            speed_xy=min(self.speed_xy, other.speed_xy),
            speed_up=min(self.speed_up, other.speed_up),
            speed_down=min(self.speed_down, other.speed_down),
            lag_s=max(self.lag_s, other.lag_s),
        )

    def describe(self) -> str:
        """One line for logs: the bounds with their units."""
        return (
            f"accel {self.accel_xy:.2f} xy {self.accel_z:.2f} z m/s^2, jerk {self.jerk_xy:g} xy "
            f"{self.jerk_z:g} z m/s^3, speed {self.speed_xy:g} xy {self.speed_up:g} up "
            f"{self.speed_down:g} down m/s, lag {self.lag_s:g} s"
        )

    @property
    def bounded(self) -> bool:
        """True when any bound is finite (the ideal point mass has none)."""
        return any(
            math.isfinite(v)
            for v in (self.accel_xy, self.accel_z, self.jerk_xy, self.jerk_z,
                      self.speed_xy, self.speed_up, self.speed_down)
        ) or self.lag_s > 0.0  # fmt: skip


@dataclass(frozen=True)
class Limits:
    """Hard limits applied to every commanded acceleration (formation-law.md s11).

    a_max [m/s^2] bound on |a|; v_max [m/s] bound on |v| (the command is
    limited so the speed does not grow past it); z_floor [m] altitude floor,
    mission frame; geofence_min/max [m] corners of an axis-aligned fence, or None;
    envelope: what the vehicles' own position controllers can deliver (the
    mission's ``limits.envelope``; unbounded by default, the paper's point
    mass). The station may tighten it with what it reads from the vehicles
    (``gcs_swarm.control.loop.ControlLoop.set_envelope``).
    """

    a_max: float = math.inf
    v_max: float = math.inf
    z_floor: float = -math.inf
    geofence_min: Vec3 | None = None
    geofence_max: Vec3 | None = None
    envelope: Envelope = field(default_factory=Envelope)


@dataclass(frozen=True)
class Safety:
    """Safety filter settings (control-barrier-function filter).

    enabled: on for real autopilots, off reproduces the paper exactly;
    clearance [m] minimum signed distance to every box; separation [m]
    minimum distance between vehicles.
    """

    enabled: bool = False
    clearance: float = 0.5
    separation: float = 1.0


@dataclass(frozen=True)
class LawConfig:
    """Everything the law needs apart from the vehicles' own states and charges."""

    gains: Gains = field(default_factory=Gains)
    leader: Leader = field(default_factory=Leader)
    obstacles: tuple[Box, ...] = ()
    avoidance: Avoidance = field(default_factory=Avoidance)
    readings: Readings = field(default_factory=Readings)
    limits: Limits = field(default_factory=Limits)
    safety: Safety = field(default_factory=Safety)
