"""The formation law of Chang, Xia & Huang: pure numpy, no I/O.

See ``shared/spec/formation-law.md`` for the equations and readings. Modules:

- ``params``: the parameter dataclasses (the mission <-> law contract);
- ``formation``: Eq. 1 and the formation force, Eqs. 7-12;
- ``leader``: the virtual leader, Eq. 13, and its force laws;
- ``expr``: the safe expression evaluator for leader forces;
- ``obstacles``: boxes, ellipsoids and rho, Eqs. 14-18;
- ``fields``: rotational and classic fields, Eqs. 19-28;
- ``lookahead``: plane selection by look-ahead;
- ``supervisor``: the behaviour switch, Eqs. 29-30;
- ``law``: the continuous law and ``SwarmController``;
- ``limits``, ``safety``, ``safety_stats``: the safety filter and its reports;
- ``envelope``, ``reaction``: the vehicle envelope (the command shaper, the
  demand check, the braking barrier of a jerk-limited, lagged vehicle);
- ``loop``: one control step of the station in vehicle time (law, safety
  filter, shaper), the core the station and the replay both drive;
- ``tracking``: Eq. V1, the velocity setpoint beside the acceleration.
"""

from __future__ import annotations

from gcs_swarm.control.envelope import ARDUCOPTER, CommandShaper, Demand
from gcs_swarm.control.expr import compile_expression, validate_expression
from gcs_swarm.control.fields import avoidance_force, desired_force
from gcs_swarm.control.formation import (
    R_MIN_M,
    eq1_acceleration,
    formation_force,
    repulsion_force,
    sphere_attraction,
)
from gcs_swarm.control.law import ControlOutput, SwarmController, law_accelerations
from gcs_swarm.control.leader import LeaderLaw, LeaderState
from gcs_swarm.control.lookahead import LookaheadJob, LookaheadResult
from gcs_swarm.control.obstacles import (
    Ellipsoids,
    box_signed_distance,
    ellipsoid_coeffs,
    rho,
)
from gcs_swarm.control.params import (
    Avoidance,
    AvoidMethod,
    Box,
    ConstantForce,
    Envelope,
    ExpressionForce,
    Gains,
    HeadingSource,
    LawConfig,
    Leader,
    LeaderForce,
    Limits,
    Plane,
    Readings,
    Safety,
    Sense,
    Vec3,
    WaypointForce,
)
from gcs_swarm.control.supervisor import Behaviour, Mode, Supervisor

__all__ = [
    "ARDUCOPTER",
    "R_MIN_M",
    "AvoidMethod",
    "Avoidance",
    "Behaviour",
    "Box",
    "CommandShaper",
    "ConstantForce",
    "ControlOutput",
    "Demand",
    "Ellipsoids",
    "Envelope",
    "ExpressionForce",
    "Gains",
    "HeadingSource",
    "LawConfig",
    "Leader",
    "LeaderForce",
    "LeaderLaw",
    "LeaderState",
    "Limits",
    "LookaheadJob",
    "LookaheadResult",
    "Mode",
    "Plane",
    "Readings",
    "Safety",
    "Sense",
    "Supervisor",
    "SwarmController",
    "Vec3",
    "WaypointForce",
    "avoidance_force",
    "box_signed_distance",
    "compile_expression",
    "desired_force",
    "ellipsoid_coeffs",
    "eq1_acceleration",
    "formation_force",
    "law_accelerations",
    "repulsion_force",
    "rho",
    "sphere_attraction",
    "validate_expression",
]
