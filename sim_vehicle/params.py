"""The parameter table of one emulated vehicle (ArduCopter names and units).

Owns the names, defaults, MAVLink types and the PARAM_VALUE builder. The
ArduCopter parameters keep ArduCopter's units (RTL_ALT in cm, RTL_LOIT_TIME in
ms, WPNAV_* in cm/s); the emulator's own limits are ``SIM_*`` in SI units.
No I/O.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav

__all__ = ["PARAM_TABLE", "ParamStore"]

_R32 = mav.MAV_PARAM_TYPE_REAL32
_I8 = mav.MAV_PARAM_TYPE_INT8
_I16 = mav.MAV_PARAM_TYPE_INT16
_I32 = mav.MAV_PARAM_TYPE_INT32

#: name -> (default, MAV_PARAM_TYPE, meaning). Order is the PARAM_VALUE index order.
PARAM_TABLE: dict[str, tuple[float, int, str]] = {
    "SYSID_THISMAV": (1, _I16, "system id (takes effect at reboot, i.e. never here)"),
    "GUID_TIMEOUT": (3.0, _R32, "s, guided accel/velocity target timeout (min 0.1 applied)"),
    "WP_YAW_BEHAVIOR": (2, _I8, "0 never change yaw, 1/2/3 face the direction of travel"),
    "DISARM_DELAY": (10, _I8, "s, auto-disarm armed on the ground without takeoff (0 off)"),
    "RTL_ALT": (1500, _I32, "cm above home for the RTL return leg"),
    "RTL_LOIT_TIME": (5000, _I32, "ms hovering above home before the RTL descent"),
    "LAND_SPEED": (50, _I16, "cm/s final descent speed"),
    "LAND_ALT_LOW": (1000, _I16, "cm above ground where LAND slows to LAND_SPEED"),
    "WPNAV_SPEED": (1000, _R32, "cm/s horizontal speed for position targets and RTL"),
    "WPNAV_SPEED_UP": (250, _R32, "cm/s climb speed (takeoff, position targets)"),
    "WPNAV_SPEED_DN": (150, _R32, "cm/s descent speed"),
    "WPNAV_ACCEL": (250, _R32, "cm/s/s horizontal acceleration (caps PSC_JERK_XY, Eq. D5a)"),
    "WPNAV_ACCEL_Z": (100, _R32, "cm/s/s vertical acceleration limit during takeoff"),
    "PSC_JERK_XY": (5.0, _R32, "m/s/s/s horizontal jerk limit of GUIDED accel targets (Eq. D5)"),
    "PSC_JERK_Z": (5.0, _R32, "m/s/s/s vertical jerk limit (Eq. D5)"),
    "ANGLE_MAX": (3000, _I16, "cdeg max lean: horizontal accel <= g tan(ANGLE_MAX) (Eq. D6)"),
    "SYSID_MYGCS": (255, _I16, "system id whose HEARTBEATs feed the GCS failsafe"),
    "FS_GCS_ENABLE": (0, _I8, "GCS failsafe: 0 off, 1/3/6 RTL, 4/5 LAND, 7 BRAKE (other RTL)"),
    "FS_GCS_TIMEOUT": (5.0, _R32, "s without a SYSID_MYGCS HEARTBEAT before the GCS failsafe"),
    "FS_OPTIONS": (16, _I32, "bitmask: 8 continue if landing, 16 continue in pilot modes"),
    "FENCE_ENABLE": (0, _I8, "fence: 0 off, 1 on"),
    "FENCE_TYPE": (7, _I8, "bitmask: 1 max alt, 2 circle around home (4 polygon: stored only)"),
    "FENCE_ACTION": (1, _I8, "0 report, 1 RTL or LAND, 2 LAND, 3 -> RTL, 4 BRAKE, 5 -> LAND"),
    "FENCE_ALT_MAX": (100.0, _R32, "m above home, altitude fence"),
    "FENCE_ALT_MIN": (-10.0, _R32, "m above home, floor (stored only: never auto-enabled here)"),
    "FENCE_RADIUS": (300.0, _R32, "m from home, circle fence"),
    "FENCE_MARGIN": (2.0, _R32, "m, distance the autopilot keeps from the fence (stored only)"),
    "SIM_ACC_MAX": (5.0, _R32, "m/s/s, norm clamp of the acceleration command"),
    "SIM_ACC_TAU": (0.2, _R32, "s, first-order lag on the acceleration (0 = ideal)"),
    "SIM_DRAG": (0.0, _R32, "1/s, drag on raw acceleration setpoints (Eq. D7; PX4 SIH 1.0)"),
    "SIM_DRAG_VEL": (
        0.0,
        _R32,
        "1/s, drag the velocity loop leaves on velocity setpoints (Eq. D7; PX4 fit 0.45)",
    ),
    "SIM_SP_DELAY": (
        0.0,
        _R32,
        "s, dead time from an OFFBOARD setpoint's arrival to its effect (Eq. D8; PX4 only)",
    ),
    "SIM_BRAKE_ACC": (2.0, _R32, "m/s/s braking unshaped (fits 18.7 m); shaped: WPNAV_ACCEL"),
    "SIM_TKOFF_DLY": (3.3, _R32, "s spool-up before a takeoff climbs (fits the sheet's 9.4 s)"),
    "SIM_EKF_DELAY": (2.0, _R32, "s after boot before the EKF/GPS are ready and arming passes"),
    "SIM_BOOT_S": (0.0, _R32, "s after first contact: 'ArduPilot Ready', STABILIZE (0 = no event)"),
    "SIM_ACC_SHAPE": (1, _I8, "1: jerk and lean limits (Eqs. D5-D6) on the command; 0 ideal"),
    "SIM_NOISE_POS": (0.0, _R32, "m, std of noise added to LOCAL_POSITION_NED position"),
    "SIM_NOISE_VEL": (0.0, _R32, "m/s, std of noise added to LOCAL_POSITION_NED velocity"),
    "SIM_VBIAS_N": (0.0, _R32, "m/s, constant bias of the reported velocity, north"),
    "SIM_VBIAS_E": (0.0, _R32, "m/s, constant bias of the reported velocity, east"),
    "SIM_VBIAS_D": (0.0, _R32, "m/s, constant bias of the reported velocity, down"),
    "SIM_VBIAS_FLIP": (
        0.0,
        _R32,
        "s after boot when the velocity bias starts to reverse (0: never; ArduCopter SITL: 304)",
    ),
    "SIM_VBIAS_TAU": (14.0, _R32, "s, time constant of that reversal (ArduCopter SITL: 14)"),
    "SIM_LPN_MAX_HZ": (
        0.0,
        _R32,
        "Hz, most LOCAL_POSITION_NED served whatever is asked (0: as asked; a router "
        "lowering the stream rate, as MAVProxy's 4 Hz)",
    ),
}
_INT_TYPES = (_I8, _I16, _I32)


class ParamStore:
    """Values of one vehicle's parameters; typed rounding on set.

    ``table`` (default ``PARAM_TABLE``) names them; only ``visible`` ones
    (default all) are on the wire: read, listed and set by PARAM_* messages
    (the PX4 personality keeps ArduCopter's names inside, hidden)."""

    def __init__(
        self,
        overrides: dict[str, float] | None = None,
        *,
        table: dict[str, tuple[float, int, str]] | None = None,
        visible: frozenset[str] | None = None,
    ) -> None:
        self.table = PARAM_TABLE if table is None else table
        self.values: dict[str, float] = {k: float(v[0]) for k, v in self.table.items()}
        self.names = [n for n in self.table if visible is None or n in visible]
        """The names on the wire, in PARAM_VALUE index order."""
        self.generation = 0  # bumped by every ``set`` (lets callers cache derived values)
        for name, value in (overrides or {}).items():
            if not self.set(name, value):
                raise ValueError(f"params: unknown parameter {name!r}")

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def set(self, name: str, value: float) -> bool:
        """Set ``name``; False if unknown. Integer types are rounded, as ArduPilot stores them."""
        if name not in self.table:
            return False
        if self.table[name][1] in _INT_TYPES:
            value = float(round(value))
        self.values[name] = float(value)
        self.generation += 1
        return True

    def index(self, name: str) -> int:
        """Index of ``name`` in PARAM_VALUE order."""
        return self.names.index(name)

    def name_at(self, index: int) -> str | None:
        """Name at ``index``, or None when out of range."""
        return self.names[index] if 0 <= index < len(self.names) else None

    def on_wire(self, name: str) -> bool:
        """True when ``name`` is read and set by PARAM_* messages."""
        return name in self.values and name in self.names

    def wire_value(self, name: str) -> float:
        """The float PARAM_VALUE carries for ``name`` (ArduPilot: the value cast)."""
        return self.values[name]

    def decode_set(self, name: str, value: float, param_type: int) -> float | None:
        """The value a PARAM_SET of ``name`` means, None to ignore it
        (ArduPilot converts any type to its own)."""
        return value

    def message(self, name: str) -> mav.MAVLink_param_value_message:
        """PARAM_VALUE for ``name`` (value as float, its MAV_PARAM_TYPE, count, index)."""
        return mav.MAVLink_param_value_message(
            param_id=name.encode(),
            param_value=self.wire_value(name),
            param_type=self.table[name][1],
            param_count=len(self.names),
            param_index=self.names.index(name),
        )

    def all_messages(self) -> list[mav.MAVLink_param_value_message]:
        """Every PARAM_VALUE, in index order (the answer to PARAM_REQUEST_LIST)."""
        return [self.message(n) for n in self.names]
