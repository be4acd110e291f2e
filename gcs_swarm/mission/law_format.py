"""The law's sections of the mission format: ``gains``, ``leader``,
``obstacles``, ``limits`` and ``readings``, declared once and built into the
dataclasses of ``gcs_swarm.control.params`` (whose defaults they reuse).

Units are SI; positions are in the mission frame (x east, y north, z up) [m].
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

import yaml

from gcs_swarm.control.envelope import ARDUCOPTER
from gcs_swarm.control.expr import validate_expression
from gcs_swarm.control.formation import R_MIN_M
from gcs_swarm.control.params import (
    Avoidance,
    Box,
    ConstantForce,
    Envelope,
    ExpressionForce,
    Gains,
    Leader,
    Limits,
    Readings,
    Safety,
    WaypointForce,
)
from gcs_swarm.errors import ExpressionError
from gcs_swarm.mission.bounds import GAIN_MAX, GAIN_MIN, POSITION_LIMIT_M, SPEED_LIMIT_MPS
from gcs_swarm.mission.context import TAG, Context, describe_node
from gcs_swarm.mission.declarations import INVALID, REQUIRED, ByKind, Field, Key, ListOf, Obj
from gcs_swarm.mission.scalars import (
    Bool,
    Const,
    Enum,
    NonNeg,
    Num,
    Pos,
    Vec3,
)

__all__ = ["GAINS", "LEADER", "LIMITS", "OBSTACLES", "READINGS"]

_G = Gains()
#: A gain or charge: positive and at most ``GAIN_MAX``, so the law stays finite (``bounds``).
_GAIN = Pos(hi=GAIN_MAX)
_AV = Avoidance()
_SAFE = Safety()


def _default(cls: type, name: str) -> Any:
    """The dataclass default of ``cls.name`` (for classes with required fields)."""
    return next(f.default for f in fields(cls) if f.name == name)


# ---------------------------------------------------------------- gains:
def _build_gains(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    ctx.defaults["q"] = v["q"]
    if v["D"] + v["k"] <= 0.0:
        ctx.add(
            ctx.line_of("gains.k"),
            "gains.k",
            f"expected D + k > 0 (the damping of Eq. 1), got D = {v['D']:g}, k = {v['k']:g}",
        )
        return INVALID
    names = ("M", "D", "k", "k_s", "k_r", "alpha", "time_scale", "repulsion_cutoff")
    return Gains(**{k: v[k] for k in names}, q_default=v["q"])


GAINS = Obj(
    name="gains",
    cls=Gains,
    build=_build_gains,
    keys=(
        Key("M", Num(lo=GAIN_MIN, hi=GAIN_MAX), _G.M, "mass of Eq. 1 [kg]"),
        Key("D", NonNeg(GAIN_MAX), _G.D, "damping of Eq. 1 [N s/m]"),
        Key("k", NonNeg(GAIN_MAX), _G.k, "extra damping of Eq. 1 [N s/m]; D + k > 0"),
        Key("k_s", _GAIN, _G.k_s, "sphere spring of Eq. 7 [N/m^3]"),
        Key("k_r", _GAIN, _G.k_r, "repulsion gain of Eq. 9 [N m^2/C^2]"),
        Key("alpha", _GAIN, _G.alpha, "sphere parameter of Eq. 7 [m]"),
        Key("q", _GAIN, _G.q_default, "charge of a vehicle naming none [C]", target="q_default"),
        Key(
            "time_scale",
            Num(lo=1.0, hi=100.0),
            _G.time_scale,
            "fly the law this many times slower, same shape: M -> lambda^2 M, D, k -> lambda D,"
            " lambda k, and the leader slowed alike (docs/vehicle-envelope.md)",
        ),
        Key(
            "repulsion_cutoff",
            Num(lo=R_MIN_M, lo_open=True, hi=POSITION_LIMIT_M, nullable=True),
            None,
            "cut-off radius of Eq. 9's repulsion [m]: only vehicles closer than this push"
            " (Eq. 9c, a cell list, O(N log N)); null: every pair, the paper's exact law"
            " (docs/formation-law.md section 3a)",
        ),
    ),
)


# ---------------------------------------------------------------- leader:
class _ForceVector(Field):
    """``[fx, fy, fz]`` [N]: all numbers give a constant force; any string
    makes the three of them expressions in x, y, z, vx, vy, vz, t (the
    leader's own state), checked by ``gcs_swarm.control.expr``."""

    def expected(self) -> str:
        return "a list of 3 numbers or expressions [fx, fy, fz]"

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        if not isinstance(node, yaml.SequenceNode) or len(node.value) != 3:
            return self._bad(node, path, ctx)
        parts: list[float | str] = []
        ok = True
        for i, item in enumerate(node.value):
            sub = f"{path}[{i}]"
            x = Num().parse(item, sub, _Quiet(ctx))
            if x is not INVALID:
                parts.append(x)
            elif (
                isinstance(item, yaml.ScalarNode) and item.tag == TAG + "str" and item.value.strip()
            ):
                try:
                    validate_expression(item.value)
                except ExpressionError as err:
                    ctx.add(item, sub, str(err))
                    ok = False
                parts.append(item.value)
            else:
                ctx.add(item, sub, f"expected a number or an expression, got {describe_node(item)}")
                ok = False
        if not ok:
            return INVALID
        if all(isinstance(p, float) for p in parts):
            return ConstantForce((float(parts[0]), float(parts[1]), float(parts[2])))
        exprs = [p if isinstance(p, str) else repr(p) for p in parts]
        return ExpressionForce((exprs[0], exprs[1], exprs[2]))

    def schema(self) -> dict[str, Any]:
        item = {"oneOf": [{"type": "number"}, {"type": "string", "minLength": 1}]}
        return {"type": "array", "items": item, "minItems": 3, "maxItems": 3}


class _Quiet(Context):
    """A context that drops problems: to try one reading of a node."""

    def __init__(self, parent: Context) -> None:
        super().__init__()
        self.lines = parent.lines


WAYPOINTS = Obj(
    name="waypoints",
    cls=WaypointForce,
    keys=(
        Key(
            "waypoints",
            ListOf(item=Vec3(), min_items=1, what="a list of [x, y, z] positions"),
            REQUIRED,
            "points the leader flies through, mission frame [m]",
        ),
        Key(
            "speed", Pos(hi=SPEED_LIMIT_MPS), REQUIRED, "cruise speed [m/s]", target="cruise_speed"
        ),
        Key(
            "accept_radius",
            Pos(),
            _default(WaypointForce, "accept_radius"),
            "the leader heads for the next waypoint this close to the current one [m]",
        ),
    ),
)

_FORCE = ByKind(
    sequence=_ForceVector(),
    mapping=WAYPOINTS,
    what="[fx, fy, fz] (numbers or expressions) or a mapping {waypoints, speed}",
)


def _build_leader(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    force = ConstantForce(v["force"]) if isinstance(v["force"], tuple) else v["force"]
    return Leader(start=v["start"], velocity=v["velocity"], force=force)


LEADER = Obj(
    name="leader",
    cls=Leader,
    build=_build_leader,
    keys=(
        Key("start", Vec3(), (0.0, 0.0, 0.0), "initial position, mission frame [m]"),
        Key("velocity", Vec3(limit=SPEED_LIMIT_MPS), (0.0, 0.0, 0.0), "initial velocity [m/s]"),
        Key(
            "force",
            _FORCE,
            (0.0, 0.0, 0.0),
            "force of Eq. 13 [N]: constant, expressions, waypoints",
        ),
    ),
)


# ---------------------------------------------------------------- obstacles:
BOX = Obj(
    name="box",
    cls=Box,
    keys=(
        Key("centre", Vec3(), REQUIRED, "box centre, mission frame [m]"),
        Key("half_extents", Vec3("[v1, v2, v3]", positive=True), REQUIRED, "half-lengths [m]"),
    ),
)

_PLANE_OF_SENSE = {"cw": "horizontal", "ccw": "horizontal", "up": "vertical", "down": "vertical"}
_AVOIDANCE_KEYS = ("method", "plane", "sense", "r0", "F_D", "target_margin", "heading")


def _build_obstacles(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    sense, plane = v["sense"], v["plane"]
    if sense in _PLANE_OF_SENSE and plane != _PLANE_OF_SENSE[sense]:
        ctx.add(
            ctx.line_of("obstacles.sense"),
            "obstacles.sense",
            f"sense {sense} needs plane {_PLANE_OF_SENSE[sense]}, got plane {plane}",
        )
        return INVALID
    return (v["boxes"], Avoidance(**{k: v[k] for k in _AVOIDANCE_KEYS}))


OBSTACLES = Obj(
    name="obstacles",
    cls=Avoidance,
    build=_build_obstacles,
    keys=(
        Key("boxes", ListOf(item=BOX), (), "axis-aligned boxes (Eq. 14)", target=None),
        Key(
            "method",
            Enum(choices=("rotational", "classic", "none")),
            _AV.method,
            "rotational (the paper), classic radial field, or none",
        ),
        Key(
            "plane",
            Enum(choices=("auto", "horizontal", "vertical")),
            _AV.plane,
            "field plane: auto by look-ahead, or forced",
        ),
        Key(
            "sense",
            Enum(choices=("auto", "cw", "ccw", "up", "down")),
            _AV.sense,
            "turning sense: auto (acute-angle rule, latched) or forced",
        ),
        Key(
            "r0",
            Num(lo=1.0, lo_open=True, hi=GAIN_MAX),
            _AV.r0,
            "field range, ellipsoidal-radius units",
        ),
        Key("F_D", Pos(hi=GAIN_MAX), _AV.F_D, "size of the desired force of Eq. 28 [N]"),
        Key(
            "target_margin",
            NonNeg(POSITION_LIMIT_M),
            _AV.target_margin,
            "slot targets at rho >= r0 + this",
        ),
        Key(
            "heading",
            Enum(choices=("auto", "velocity", "desired")),
            "auto",
            "vertical field's phi: velocity azimuth (spec) or desired force's; "
            "auto: desired with the safety filter on, velocity otherwise",
        ),
    ),
)


# ---------------------------------------------------------------- limits:
def _fmt(p: tuple[float, ...]) -> str:
    return "[" + ", ".join(f"{x:g}" for x in p) + "]"


def _build_geofence(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    lo, hi = v["min"], v["max"]
    if any(a >= b for a, b in zip(lo, hi, strict=True)):
        ctx.add(
            ctx.line_of(f"{path}.max"),
            f"{path}.max",
            f"expected every component above {path}.min {_fmt(lo)}, got {_fmt(hi)}",
        )
        return INVALID
    return (lo, hi)


GEOFENCE = Obj(
    name="geofence",
    build=_build_geofence,
    keys=(
        Key("min", Vec3(), REQUIRED, "lowest corner, mission frame [m]"),
        Key("max", Vec3(), REQUIRED, "highest corner, mission frame [m]"),
    ),
)

SAFETY = Obj(
    name="safety",
    cls=Safety,
    keys=(
        Key(
            "enabled",
            Bool(nullable=True),
            None,
            "safety filter on; null (default): on when any vehicle is a real autopilot "
            "(link not sim), off for an all-sim mission (the paper exactly)",
        ),
        Key(
            "clearance",
            NonNeg(POSITION_LIMIT_M),
            _SAFE.clearance,
            "minimum distance to every box [m]",
        ),
        Key(
            "separation",
            NonNeg(POSITION_LIMIT_M),
            _SAFE.separation,
            "minimum distance between vehicles [m]",
        ),
    ),
)


_ENV_KEYS = (
    ("accel_xy", "accel_xy", "horizontal acceleration bound |a_xy| [m/s^2] (WPNAV_ACCEL)"),
    ("accel_z", "accel_z", "vertical acceleration bound |a_z| [m/s^2] (WPNAV_ACCEL_Z)"),
    ("jerk_xy", "jerk_xy", "horizontal jerk bound [m/s^3] (PSC_JERK_XY)"),
    ("jerk_z", "jerk_z", "vertical jerk bound [m/s^3] (PSC_JERK_Z)"),
    ("speed_xy", "speed_xy", "horizontal speed [m/s] (WPNAV_SPEED)"),
    ("speed_up", "speed_up", "climb rate [m/s] (WPNAV_SPEED_UP)"),
    ("speed_down", "speed_down", "descent rate [m/s] (WPNAV_SPEED_DN)"),
)


def _build_envelope(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    bounds = {name: math.inf if v[name] is None else v[name] for name, _, _ in _ENV_KEYS}
    return Envelope(**bounds, lag_s=v["lag"])


ENVELOPE_MAP = Obj(
    name="envelope",
    cls=Envelope,
    build=_build_envelope,
    extra_fields=("lag_s",),
    keys=(
        *(Key(n, Pos(nullable=True), None, f"{doc}; null: unbounded") for n, _, doc in _ENV_KEYS),
        Key("lag", Num(lo=0.0, hi=5.0), 0.0, "lag of the achieved acceleration [s]", target=None),
    ),
)


class _Named(Const):
    """``arducopter``: ArduCopter 4.5's default envelope (``control.envelope``)."""

    def _parse(self, node: yaml.Node, path: str, ctx: Context) -> Any:
        value = super()._parse(node, path, ctx)
        return ARDUCOPTER if value is not INVALID else INVALID


ENVELOPE = ByKind(
    scalar=_Named(value="arducopter"),
    mapping=ENVELOPE_MAP,
    what='"arducopter" or a mapping {accel_xy, accel_z, jerk_xy, jerk_z, speed_xy,'
    " speed_up, speed_down, lag}",
)


def _build_limits(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    fence = v["geofence"]
    limits = Limits(
        a_max=math.inf if v["a_max"] is None else v["a_max"],
        v_max=math.inf if v["v_max"] is None else v["v_max"],
        z_floor=-math.inf if v["z_floor"] is None else v["z_floor"],
        geofence_min=None if fence is None else fence[0],
        geofence_max=None if fence is None else fence[1],
        envelope=Envelope() if v["envelope"] is None else v["envelope"],
    )
    return (limits, v["safety"])


LIMITS = Obj(
    name="limits",
    cls=Limits,
    build=_build_limits,
    extra_fields=("geofence_min", "geofence_max", "envelope"),
    keys=(
        Key("a_max", Pos(nullable=True), None, "largest commanded acceleration [m/s^2]"),
        Key("v_max", Pos(nullable=True), None, "speed the commands may not push past [m/s]"),
        Key(
            "z_floor",
            Num(lo=-POSITION_LIMIT_M, hi=POSITION_LIMIT_M, nullable=True),
            None,
            "altitude floor, mission-frame z [m]",
        ),
        Key("geofence", GEOFENCE, None, "box {min, max}, mission frame [m]", target=None),
        Key("safety", SAFETY, Safety, "safety filter settings", target=None),
        Key(
            "envelope",
            ENVELOPE,
            None,
            "what the vehicles' position controllers deliver: arducopter (4.5 defaults) or"
            " the bounds; simulate models it, check compares the gains' demand with it",
            target=None,
        ),
    ),
)

_READING_DOCS = {
    "eq10_printed": "Eq. 10 as printed (q_n twice)",
    "eq11_printed": "Eq. 11 as printed (F - f: diverges)",
    "eq12_printed": "Eq. 12 as printed (no alpha^2)",
    "eq27_printed": "Eq. 27 per-component form",
    "repulsion_in_avoidance": "keep inter-vehicle repulsion during avoidance",
}

READINGS = Obj(
    name="readings",
    cls=Readings,
    keys=tuple(
        Key(f.name, Bool(), f.default, _READING_DOCS.get(f.name, "")) for f in fields(Readings)
    ),
)
