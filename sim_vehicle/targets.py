"""What each flight-controller state tracks: the inputs of dynamics Eq. D3. NO I/O.

Owns ``ControlTarget`` (one vehicle's row of ``dynamics.Targets`` and
``DynParams``) and ``TargetBuilder``, which turns a control state of the
autopilot (``Autopilot.control``: accel, vel, pos, posvel, hold, brake,
takeoff, land, rtl_*, ground, spool, fall) into its target, from the
parameters (WPNAV_*, the jerk and lean limits of Eqs. D5a and D6, SIM_DRAG
of Eq. D7) and the setpoint in force. The state machine that decides which
control runs stays in ``autopilot`` (docs/emulator.md, "Autopilot").
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from sim_vehicle.dynamics import GRAVITY_M_S2
from sim_vehicle.params import ParamStore
from sim_vehicle.telemetry import Kin, Vec3

__all__ = ["NO_KIN", "ZERO", "ControlTarget", "TargetBuilder"]

_INF = math.inf
_TUPLE_NEW = tuple.__new__
ZERO: Vec3 = (0.0, 0.0, 0.0)
_ONE: Vec3 = (1.0, 1.0, 1.0)
NO_KIN = Kin(ZERO, ZERO, ZERO, False)
"""What an acceleration target reads of the kinematics: nothing (``TargetBuilder.accel``;
the streamed setpoint is applied without a ``Kin`` of its own)."""
_SNAP_RAD_S4 = math.radians(1100.0) * GRAVITY_M_S2
"""ATC_ACCEL_R/P_MAX default (110000 cdeg/s^2) times g: the snap of Eq. D5a (per m, m/s^4)."""


class ControlTarget(NamedTuple):
    """Inputs of dynamics Eq. D3 for one vehicle (NED, SI units); see ``dynamics.Targets``.

    Immutable. A named tuple rather than a frozen dataclass: a streamed setpoint
    builds one per vehicle per step, and a frozen dataclass's ``__init__``
    (one ``object.__setattr__`` per field) costs about 2 us against 0.45 us."""

    a_ff: Vec3 = ZERO
    p_t: Vec3 = ZERO
    v_t: Vec3 = ZERO
    wp: Vec3 = ZERO
    wv: float = 0.0
    vmax_xy: float = 10.0
    vmax_up: float = 2.5
    vmax_dn: float = 1.5
    acc_lim: float = 5.0
    acc_max: float = 5.0
    tau_s: float = 0.2
    jerk_xy: float = _INF
    jerk_z: float = _INF
    lean_acc: float = _INF
    drag: float = 0.0
    """Eq. D7's drag over mass (1/s): on raw acceleration setpoints (SIM_DRAG) and,
    what a velocity loop leaves of it, on velocity setpoints (SIM_DRAG_VEL)."""


class TargetBuilder:
    """The target of each control state of one autopilot (module docstring).

    The base limits are cached until a parameter changes (``ParamStore.generation``);
    ``drag`` and ``drag_vel`` stay the very same float objects while unchanged, which
    ``Fleet.set_target`` relies on (it compares fields by identity)."""

    def __init__(self, params: ParamStore) -> None:
        self.params = params
        self._base: tuple[int, ControlTarget] | None = None  # (params generation, base target)
        self.drag = 0.0  # SIM_DRAG as of the cached base target
        self.drag_vel = 0.0  # SIM_DRAG_VEL likewise
        self._accel_rest: tuple[ControlTarget, tuple[Any, ...]] | None = None
        """(base target, the accel target's fields after a_ff) (``target``)."""

    def base(self) -> ControlTarget:
        """The limits every target starts from (cached until a parameter changes)."""
        p = self.params
        if self._base is not None and self._base[0] == p.generation:
            return self._base[1]
        acc_max = p["SIM_ACC_MAX"]
        vxy, vup, vdn = p["WPNAV_SPEED"] / 100, p["WPNAV_SPEED_UP"] / 100, p["WPNAV_SPEED_DN"] / 100
        jxy = jz = lean = _INF
        if p["SIM_ACC_SHAPE"] != 0:
            # Eq. D5a (AC_PosControl::set_max_speed_accel_xy): the horizontal jerk is
            # PSC_JERK_XY, at most 0.5 sqrt(WPNAV_ACCEL * snap); WPNAV_ACCEL <= 0 -> 250 cm/s^2.
            wp_acc = p["WPNAV_ACCEL"] / 100 if p["WPNAV_ACCEL"] > 0 else 2.5
            jxy = max(0.0, min(p["PSC_JERK_XY"], 0.5 * math.sqrt(wp_acc * _SNAP_RAD_S4)))
            jz = max(0.0, p["PSC_JERK_Z"])
            # Eq. D6: lean-angle cap g tan(ANGLE_MAX), ANGLE_MAX in cdeg (kept below 85 deg).
            angle = math.radians(min(max(p["ANGLE_MAX"], 0.0), 8500.0) / 100)
            lean = GRAVITY_M_S2 * math.tan(angle)
        base = ControlTarget(
            vmax_xy=vxy, vmax_up=vup, vmax_dn=vdn, tau_s=p["SIM_ACC_TAU"],
            acc_lim=acc_max, acc_max=acc_max, jerk_xy=jxy, jerk_z=jz, lean_acc=lean,
        )  # fmt: skip
        self._base = (p.generation, base)
        self.drag = p["SIM_DRAG"]  # the same float object while unchanged (Fleet.set_target)
        self.drag_vel = p["SIM_DRAG_VEL"]
        return base

    def accel(self, a: Vec3) -> ControlTarget:
        """The target of control "accel" flying the acceleration ``a`` (local NED m/s^2).

        All but a_ff come from the base target: kept as one tuple per base, so
        the 50 Hz stream makes its target with one C call (the same fields, the
        same objects: ``Fleet.set_target``'s identity test holds)."""
        b = self.base()
        rest = self._accel_rest
        if rest is None or rest[0] is not b:
            rest = self._accel_rest = (b, (
                ZERO, ZERO, ZERO, 0.0, b.vmax_xy, b.vmax_up, b.vmax_dn, b.acc_lim,
                b.acc_max, b.tau_s, b.jerk_xy, b.jerk_z, b.lean_acc, self.drag,
            ))  # fmt: skip
        return _TUPLE_NEW(ControlTarget, (a, *rest[1]))

    def target(
        self,
        ctl: str,
        kin: Kin,
        sp: dict[str, Any],
        hold_ned: Vec3,
        home: Vec3,
        takeoff_d_m: float,
    ) -> tuple[ControlTarget, Vec3, bool | None]:
        """(target, the hold point, LAND's "low" flag or None) of control ``ctl``.

        ``sp``: the GUIDED setpoint in force (keys a, v, p; local NED); ``hold_ned``:
        the current hold point, returned changed where the control moves it (pos,
        brake, land, takeoff, rtl_*); ``takeoff_d_m``: the take-off's target (down m)."""
        p = self.params
        hold = kin.pos
        low: bool | None = None
        b = base = self.base()
        # The streamed kinds build their target field by field: ``replace`` costs
        # several times more, 50 times a second per vehicle.
        if ctl == "accel":
            tg = self.accel(sp["a"])
        elif ctl == "vel":
            tg = ControlTarget(
                sp.get("a", ZERO), ZERO, sp["v"], ZERO, 1.0, b.vmax_xy, b.vmax_up, b.vmax_dn,
                b.acc_lim, b.acc_max, b.tau_s, b.jerk_xy, b.jerk_z, b.lean_acc, self.drag_vel,
            )  # fmt: skip
        elif ctl in ("pos", "posvel"):
            hold_ned = sp["p"]
            tg = ControlTarget(
                sp.get("a", ZERO), sp["p"], sp.get("v", ZERO), _ONE, 1.0, b.vmax_xy, b.vmax_up,
                b.vmax_dn, b.acc_lim, b.acc_max, b.tau_s, b.jerk_xy, b.jerk_z, b.lean_acc,
            )  # fmt: skip
        elif ctl in ("ground", "spool"):
            tg = base
        elif ctl == "fall":
            g = GRAVITY_M_S2
            tg = base._replace(  # motors off: no position controller, no jerk limit
                a_ff=(0.0, 0.0, g), acc_lim=g, acc_max=g, jerk_xy=_INF, jerk_z=_INF,
                lean_acc=_INF,
            )  # fmt: skip
        elif ctl == "brake":
            # ArduCopter brakes with input_vel_accel(0, 0) at WPNAV_ACCEL, jerk-limited (Eq. D5);
            # without shaping (ideal) the deceleration fitted to the sheet's 18.7 m
            shaped = p["SIM_ACC_SHAPE"] != 0 and p["WPNAV_ACCEL"] > 0
            acc = p["WPNAV_ACCEL"] / 100 if shaped else p["SIM_BRAKE_ACC"]
            tg = base._replace(wv=1.0, acc_lim=acc)
            hold_ned = hold
        elif ctl == "land":
            hold_ned = hold
            low = home[2] - kin.pos[2] < p["LAND_ALT_LOW"] / 100
            speed = p["LAND_SPEED"] / 100 if low else base.vmax_dn
            tg = base._replace(p_t=hold, v_t=(0.0, 0.0, speed), wp=(1.0, 1.0, 0.0), wv=1.0)
        else:
            if ctl == "takeoff":
                hold_ned = (hold[0], hold[1], takeoff_d_m)
            elif ctl == "rtl_climb":
                hold_ned = (hold[0], hold[1], min(hold[2], home[2] - p["RTL_ALT"] / 100))
            elif ctl in ("rtl_return", "rtl_loiter"):
                hold_ned = (home[0], home[1], hold_ned[2])
            elif ctl != "hold":  # pragma: no cover - programming error
                raise AssertionError(ctl)
            tg = base._replace(p_t=hold_ned, wp=_ONE, wv=1.0)
            if ctl == "takeoff":
                tg = tg._replace(acc_lim=p["WPNAV_ACCEL_Z"] / 100)
        return tg, hold_ned, low
