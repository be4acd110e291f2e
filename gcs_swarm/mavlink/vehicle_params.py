"""The parameters the station reads from and writes to each ArduCopter vehicle
(issue 14 items 2 and 3): the position controller's envelope, the vehicle's
own GCS-loss failsafe and fence, and putting the old values back at the end.

No I/O and no clock (STYLE.md habit 1): ``VehicleParams`` queues awaited
commands on the vehicle's ``CommandQueue`` and reads the answers from the
vehicle's parameter values (``VehicleProtocol.params``, filled from every
PARAM_VALUE); what the log should say goes to ``emit``. The owner calls:

- ``start`` in CONFIGURING: PARAM_REQUEST_READ of every parameter the station
  will change (their old values) and of the envelope's eight, then the
  PARAM_SETs of the GCS failsafe (SYSID_MYGCS, FS_GCS_TIMEOUT, FS_GCS_ENABLE);
- ``home_known`` once the vehicle's home is placed in the mission frame,
  before arming: the fence (FENCE_TYPE, FENCE_ALT_MAX, FENCE_RADIUS,
  FENCE_ACTION, FENCE_ENABLE);
- ``restore`` when the vehicle ends (ENDED or FAILED): the old values back,
  best effort;
- ``record`` for the run folder's ``vehicle_params.json``.

Every PARAM_SET is checked from its PARAM_VALUE echo: a vehicle that reports
another value fails its start-up with an error naming the parameter, the
value sent and the value reported (``CommandQueue``). A read nobody answers
(not an ArduCopter, or the emulator) is reported and never fails the
start-up: the envelope then takes the mission's value for what is missing.

Units on the wire are ArduCopter's own (cm/s, cm/s^2, centidegrees, m, s);
the ``Envelope`` is SI. docs/vehicle-safety.md says why each value.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from functools import partial
from typing import Any, Literal

from gcs_swarm.control.params import Envelope, Vec3
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import STATION_SYSID, MessageSpec
from gcs_swarm.mavlink.commands import NO_ANSWER, CommandQueue, same_param_value

__all__ = [
    "ARDUCOPTER_DEFAULTS",
    "ENVELOPE_PARAMS",
    "FAILSAFE_PARAMS",
    "FENCE_PARAMS",
    "MEASURED_LAG_S",
    "EndAction",
    "ParamChange",
    "ParamProfile",
    "ParamSettings",
    "Setting",
    "VehicleParams",
    "envelope_from_params",
    "failsafe_values",
    "fence_values",
]

EndAction = Literal["hold", "land", "rtl"]
Emit = Callable[[str, str], None]
"""``emit(kind, text)``: kind is ``param``, ``info`` or ``warning``."""
Setting = tuple[str, float, str]
"""(parameter name, value in ArduCopter's unit, why: for the log)."""

GRAVITY_MPS2 = 9.80665
MEASURED_LAG_S = 0.2
"""First-order lag of ArduCopter's achieved acceleration on the command [s]
(mavlink-protocol.md: the measured step response)."""

ENVELOPE_PARAMS = (
    "WPNAV_ACCEL",
    "WPNAV_ACCEL_Z",
    "PSC_JERK_XY",
    "PSC_JERK_Z",
    "WPNAV_SPEED",
    "WPNAV_SPEED_UP",
    "WPNAV_SPEED_DN",
    "ANGLE_MAX",
)
"""The position controller's limits read at start-up (ardupilot-facts.md)."""
FAILSAFE_PARAMS = ("SYSID_MYGCS", "FS_GCS_TIMEOUT", "FS_GCS_ENABLE")
FENCE_PARAMS = ("FENCE_TYPE", "FENCE_ALT_MAX", "FENCE_RADIUS", "FENCE_ACTION", "FENCE_ENABLE")

ARDUCOPTER_DEFAULTS: dict[str, float] = {
    "WPNAV_ACCEL": 250.0,
    "WPNAV_ACCEL_Z": 100.0,
    "PSC_JERK_XY": 5.0,
    "PSC_JERK_Z": 5.0,
    "WPNAV_SPEED": 1000.0,
    "WPNAV_SPEED_UP": 250.0,
    "WPNAV_SPEED_DN": 150.0,
    "ANGLE_MAX": 3000.0,
    "SYSID_MYGCS": 255.0,
    "FS_GCS_ENABLE": 0.0,
    "FS_GCS_TIMEOUT": 5.0,
    "FENCE_ENABLE": 0.0,
    "FENCE_TYPE": 7.0,
    "FENCE_ACTION": 1.0,
    "FENCE_ALT_MAX": 100.0,
    "FENCE_RADIUS": 300.0,
    "GUID_TIMEOUT": 3.0,
    "WP_YAW_BEHAVIOR": 2.0,
}
"""ArduCopter 4.5.6's defaults (ardupilot-facts.md), in its units."""

FS_GCS_FOR_END = {"land": 5, "rtl": 1, "hold": 5}
"""FS_GCS_ENABLE per end action: 5 Land, 1 RTL. A hold (BRAKE) end action
still lands: the failsafe is for a lost station, and a vehicle hovering with
nobody to end it must come down (docs/vehicle-safety.md)."""
FENCE_ACTION_FOR_END = {"rtl": 1, "land": 2, "hold": 2}
"""FENCE_ACTION per end action: 1 RTL (or Land), 2 always Land."""
FENCE_TYPE_ALT_MAX = 1
FENCE_TYPE_CIRCLE = 2
FENCE_RADIUS_MIN_M = 30.0
"""The least FENCE_RADIUS ArduCopter documents (range 30..10000 m)."""
FENCE_ALT_MAX_MIN_M = 10.0
"""The least FENCE_ALT_MAX ArduCopter documents (range 10..1000 m)."""
_QUICK_READ_ATTEMPTS = 2
"""Sends of each later read once one read went unanswered after the usual
retries: that vehicle does not know these names (8 x 10 s would eat the
start-up); a real ArduCopter answers every one."""
_RESTORE_ATTEMPTS = 3
"""Sends of each restoring PARAM_SET (best effort, inside the end timeout)."""


def _positive(values: Mapping[str, float], name: str) -> float | None:
    v = values.get(name)
    return v if v is not None and math.isfinite(v) and v > 0.0 else None


def envelope_from_params(
    values: Mapping[str, float],
    fallback: Envelope | None = None,
    *,
    lag_s: float = MEASURED_LAG_S,
) -> tuple[Envelope, tuple[str, ...]]:
    """The ``Envelope`` [SI] of a vehicle from its parameters [ArduCopter
    units], and the names missing from ``values`` (or not > 0), whose bound
    is then ``fallback``'s (default: unbounded).

    Eq. E1: accel_xy = min(WPNAV_ACCEL / 100, g tan(ANGLE_MAX / 100 deg)),
    the position controller's horizontal limit and the lean angle's
    (ardupilot-facts.md: accel_max = g tan(ANGLE_MAX)); accel_z =
    WPNAV_ACCEL_Z / 100; jerk_xy, jerk_z = PSC_JERK_XY, PSC_JERK_Z; speeds =
    WPNAV_SPEED, WPNAV_SPEED_UP, WPNAV_SPEED_DN / 100; lag_s measured. The
    lag is ``fallback``'s when no parameter was read at all."""
    fb = fallback if fallback is not None else Envelope()
    got = {n: _positive(values, n) for n in ENVELOPE_PARAMS}
    missing = tuple(n for n, v in got.items() if v is None)

    def cm(name: str, default: float) -> float:
        v = got[name]
        return default if v is None else v / 100.0

    def raw(name: str, default: float) -> float:
        v = got[name]
        return default if v is None else v

    wp_accel, angle = got["WPNAV_ACCEL"], got["ANGLE_MAX"]
    accel_xy = fb.accel_xy
    if wp_accel is not None or angle is not None:
        lean = math.inf if angle is None else GRAVITY_MPS2 * math.tan(math.radians(angle / 100.0))
        accel_xy = min(math.inf if wp_accel is None else wp_accel / 100.0, lean)  # Eq. E1
    envelope = Envelope(
        accel_xy=accel_xy,
        accel_z=cm("WPNAV_ACCEL_Z", fb.accel_z),
        jerk_xy=raw("PSC_JERK_XY", fb.jerk_xy),
        jerk_z=raw("PSC_JERK_Z", fb.jerk_z),
        speed_xy=cm("WPNAV_SPEED", fb.speed_xy),
        speed_up=cm("WPNAV_SPEED_UP", fb.speed_up),
        speed_down=cm("WPNAV_SPEED_DN", fb.speed_down),
        lag_s=fb.lag_s if len(missing) == len(ENVELOPE_PARAMS) else lag_s,
    )
    return envelope, missing


def failsafe_values(
    end: EndAction, timeout_s: float, station_sysid: int = STATION_SYSID
) -> tuple[Setting, ...]:
    """The GCS-loss failsafe for a mission ending with ``end``, in the order
    they are set: who the station is, how long its silence may last, then
    the action (switched on last, once the other two are right)."""
    fs = FS_GCS_FOR_END[end]
    action = "Land" if fs == 5 else "RTL"
    return (
        ("SYSID_MYGCS", float(station_sysid), "the station's system id feeds the failsafe"),
        ("FS_GCS_TIMEOUT", float(timeout_s), "s without the station's HEARTBEAT"),
        ("FS_GCS_ENABLE", float(fs), f"{action} after {timeout_s:g} s without the station"),
    )


def _ceil_dm(x: float) -> float:
    """Up to the next 0.1 m: a backstop rounded outwards, never inwards."""
    return math.ceil(x * 10.0 - 1e-9) / 10.0


def fence_values(
    geofence_min: Vec3,
    geofence_max: Vec3,
    home_m: Sequence[float],
    end: EndAction,
    margin_m: float,
) -> tuple[tuple[Setting, ...], tuple[str, ...]]:
    """The vehicle's own fence around the mission's geofence box (mission
    frame [m]) for a vehicle whose home is ``home_m`` (mission frame [m]),
    and notes on values raised to ArduCopter's least.

    The fence is a backstop outside the station's own: a circle centred on
    the home and a ceiling, both ``margin_m`` beyond the box.
    Eq. F1: FENCE_ALT_MAX = max z + margin - home z (m above home).
    Eq. F2: FENCE_RADIUS = max over the box's corners c of |c_xy - home_xy|
    + margin (the circle about home that holds the whole box).
    Both rounded up to 0.1 m."""
    hx, hy, hz = float(home_m[0]), float(home_m[1]), float(home_m[2])
    notes: list[str] = []
    alt_max = _ceil_dm(geofence_max[2] + margin_m - hz)  # Eq. F1
    corners = [(x, y) for x in (geofence_min[0], geofence_max[0])
               for y in (geofence_min[1], geofence_max[1])]  # fmt: skip
    radius = _ceil_dm(max(math.hypot(x - hx, y - hy) for x, y in corners) + margin_m)  # Eq. F2
    if alt_max < FENCE_ALT_MAX_MIN_M:
        notes.append(f"FENCE_ALT_MAX {alt_max:g} m raised to ArduCopter's least "
                     f"{FENCE_ALT_MAX_MIN_M:g} m")  # fmt: skip
        alt_max = FENCE_ALT_MAX_MIN_M
    if radius < FENCE_RADIUS_MIN_M:
        notes.append(f"FENCE_RADIUS {radius:g} m raised to ArduCopter's least "
                     f"{FENCE_RADIUS_MIN_M:g} m")  # fmt: skip
        radius = FENCE_RADIUS_MIN_M
    act = FENCE_ACTION_FOR_END[end]
    settings = (
        ("FENCE_TYPE", float(FENCE_TYPE_ALT_MAX | FENCE_TYPE_CIRCLE), "max altitude and circle"),
        ("FENCE_ALT_MAX", alt_max, f"m above home: geofence top + {margin_m:g} m"),
        ("FENCE_RADIUS", radius, f"m about home: holds the geofence box + {margin_m:g} m"),
        ("FENCE_ACTION", float(act), "RTL or Land on a breach" if act == 1 else "Land on a breach"),
        ("FENCE_ENABLE", 1.0, "the vehicle's own fence on"),
    )
    return settings, tuple(notes)


EnvelopeFn = Callable[
    [Mapping[str, float], Envelope | None, float], tuple[Envelope, tuple[str, ...]]
]
FailsafeFn = Callable[[EndAction, float, int], tuple[Setting, ...]]
ParamSetFn = Callable[[int, int, str, float], MessageSpec]


@dataclass(frozen=True)
class ParamProfile:
    """One autopilot's parameters as ``VehicleParams`` reads and sets them:
    the envelope's names and how they become an ``Envelope`` (Eq. E1 for
    ArduCopter), the failsafe's names and values, the fence's (empty: no
    fence), how a PARAM_SET is built, and the end modes after which the
    vehicle comes down on its own (its failsafe and fence may be restored)."""

    autopilot: str
    envelope_params: tuple[str, ...]
    envelope: EnvelopeFn
    failsafe_params: tuple[str, ...]
    failsafe: FailsafeFn
    fence_params: tuple[str, ...]
    param_set: ParamSetFn
    ends_on_own: frozenset[int]

    @property
    def safety_params(self) -> frozenset[str]:
        return frozenset(self.failsafe_params + self.fence_params)


def _envelope(
    values: Mapping[str, float], fallback: Envelope | None, lag_s: float
) -> tuple[Envelope, tuple[str, ...]]:
    return envelope_from_params(values, fallback, lag_s=lag_s)


ARDUCOPTER = ParamProfile(
    autopilot="ArduCopter",
    envelope_params=ENVELOPE_PARAMS,
    envelope=_envelope,
    failsafe_params=FAILSAFE_PARAMS,
    failsafe=lambda end, timeout, sysid: failsafe_values(end, timeout, sysid),
    fence_params=FENCE_PARAMS,
    param_set=b.param_set,
    ends_on_own=frozenset({b.COPTER_MODES["LAND"], b.COPTER_MODES["RTL"]}),
)
"""ArduCopter 4.5's parameters (ardupilot-facts.md)."""


@dataclass(frozen=True)
class ParamSettings:
    """What the station does with one vehicle's parameters (from the mission).

    - ``read_envelope``: read the eight envelope parameters at start-up;
      ``fallback`` is the envelope for whatever is not answered, ``lag_s``
      the lag of an envelope read from the vehicle [s].
    - ``gcs_failsafe``: set FS_GCS_ENABLE (from ``end``), FS_GCS_TIMEOUT
      (``gcs_timeout_s`` [s]) and SYSID_MYGCS (``station_sysid``).
    - ``fence``: set the vehicle's fence from the geofence box
      ``geofence_min``/``geofence_max`` (mission frame [m]; no box, no
      fence), ``fence_margin_m`` [m] beyond it.
    - ``restore``: put back the old value of every parameter changed
      (those above, and ``station_sets``: GUID_TIMEOUT, WP_YAW_BEHAVIOR)
      when the vehicle ends. Old values are read only when one of the three
      above is on (``active``): otherwise the station's traffic is as before.
    """

    read_envelope: bool = False
    gcs_failsafe: bool = False
    gcs_timeout_s: float = 5.0
    fence: bool = False
    fence_margin_m: float = 5.0
    restore: bool = True
    end: EndAction = "hold"
    geofence_min: Vec3 | None = None
    geofence_max: Vec3 | None = None
    station_sysid: int = STATION_SYSID
    fallback: Envelope = field(default_factory=Envelope)
    lag_s: float = MEASURED_LAG_S

    @property
    def fences(self) -> bool:
        """True when a fence will be set (asked for, and a box to set it from)."""
        return self.fence and self.geofence_min is not None and self.geofence_max is not None

    @property
    def active(self) -> bool:
        """True when the station reads (and perhaps writes) this vehicle's parameters."""
        return self.read_envelope or self.gcs_failsafe or self.fences


@dataclass
class ParamChange:
    """One parameter the station set: ``old`` read before [its unit] (None:
    not read or not answered), ``new`` sent, ``readback`` the vehicle's echo
    (None: not yet), ``restored`` (None: not attempted), ``note`` why not."""

    name: str
    new: float
    why: str
    old: float | None = None
    readback: float | None = None
    restored: bool | None = None
    note: str = ""

    @property
    def changed(self) -> bool:
        return self.old is None or not same_param_value(self.old, self.new)

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "changed": self.changed}


def _fmt(x: float | None) -> str:
    return "?" if x is None else f"{x:g}"


class VehicleParams:
    """The parameter work of one vehicle (system id ``sysid``).

    ``values`` is the vehicle's parameter values as last reported (the
    owner updates it from every PARAM_VALUE before the queue sees it);
    ``station_sets`` the parameters the owner itself sets at start-up
    (name -> value), recorded and restored like the others.
    """

    def __init__(
        self,
        sysid: int,
        settings: ParamSettings,
        values: Mapping[str, float],
        emit: Emit,
        *,
        station_sets: Mapping[str, float] | None = None,
        profile: ParamProfile = ARDUCOPTER,
    ) -> None:
        self.sysid = sysid
        self.settings = settings
        self.profile = profile
        self.envelope: Envelope = settings.fallback
        """The vehicle's envelope: read from it, or the mission's (``fallback``)."""
        self.envelope_missing: tuple[str, ...] = profile.envelope_params
        """Envelope parameters not (yet) read: their bounds are the mission's."""
        self.old: dict[str, float] = {}
        """First value read of each parameter (later reads may be our own)."""
        self.unanswered: list[str] = []
        self.changes: dict[str, ParamChange] = {}
        self.fence_notes: tuple[str, ...] = ()
        self._values = values
        self._emit = emit
        self._station_sets = dict(station_sets or {})
        self._silent = False
        self._envelope_due: set[str] = set()
        self._fence_pushed = False

    @property
    def fences(self) -> bool:
        """A fence will be set: asked for, a box to set it from, and an
        autopilot whose fence the station knows (ArduCopter's)."""
        return self.settings.fences and bool(self.profile.fence_params)

    # ----------------------------------------------------------- start-up
    def start(self, now: float, queue: CommandQueue, compid: int) -> None:
        """CONFIGURING: queue the reads, then the failsafe's PARAM_SETs."""
        cfg = self.settings
        self._fence_pushed = False
        for name, value in self._station_sets.items():
            self._change(name, value, "set by the station at start-up")
        if not (cfg.read_envelope or cfg.gcs_failsafe or self.fences):
            return
        names = list(self._station_sets)
        if cfg.gcs_failsafe:
            names += self.profile.failsafe_params
        if self.fences:
            names += self.profile.fence_params
        if cfg.read_envelope:
            names += self.profile.envelope_params
            self._envelope_due = set(self.profile.envelope_params)

        def attempts() -> int:
            return min(_QUICK_READ_ATTEMPTS, queue.attempts) if self._silent else queue.attempts

        for name in names:
            queue.push(
                now, f"PARAM_REQUEST_READ {name}",
                partial(b.param_request_read, self.sysid, compid, name),
                partial(self._read_done, name), param=name, optional=True, attempts=attempts,
            )  # fmt: skip
        if cfg.gcs_failsafe:
            for setting in self.profile.failsafe(cfg.end, cfg.gcs_timeout_s, cfg.station_sysid):
                self._push_set(now, queue, compid, setting)

    def home_known(
        self, now: float, queue: CommandQueue, compid: int, home_m: Sequence[float]
    ) -> None:
        """Before arming, once the vehicle's home (its EKF origin) is placed
        in the mission frame at ``home_m`` [m]: queue the fence (once per
        start-up)."""
        cfg = self.settings
        if self._fence_pushed or not self.fences:
            return
        assert cfg.geofence_min is not None and cfg.geofence_max is not None
        self._fence_pushed = True
        settings, self.fence_notes = fence_values(
            cfg.geofence_min, cfg.geofence_max, home_m, cfg.end, cfg.fence_margin_m
        )
        for note in self.fence_notes:
            self._emit("info", f"vehicle {self.sysid}: {note}")
        for setting in settings:
            self._push_set(now, queue, compid, setting)

    def _read_done(self, name: str, result: int, now: float) -> None:
        value = self._values.get(name)
        if result == NO_ANSWER or value is None:
            self._silent = True
            if name not in self.unanswered:
                self.unanswered.append(name)
            self._emit("warning", f"vehicle {self.sysid}: no answer to PARAM_REQUEST_READ "
                       f"{name} (not an {self.profile.autopilot}?)")  # fmt: skip
        else:
            self.old.setdefault(name, value)
            ch = self.changes.get(name)
            if ch is not None and ch.old is None:
                ch.old = self.old[name]
        if name in self._envelope_due:
            self._envelope_due.discard(name)
            if not self._envelope_due:
                self._envelope_read()

    def _envelope_read(self) -> None:
        cfg = self.settings
        self.envelope, self.envelope_missing = self.profile.envelope(
            self._values, cfg.fallback, cfg.lag_s
        )
        e = self.envelope
        source = "from its parameters"
        if self.envelope_missing:
            source += f"; {', '.join(self.envelope_missing)} unanswered: the mission's bound"
        self._emit(
            "info",
            f"vehicle {self.sysid}: envelope {e.describe()} ({source})",
        )

    def _change(self, name: str, value: float, why: str) -> ParamChange:
        ch = self.changes.get(name)
        if ch is None:
            ch = self.changes[name] = ParamChange(name, value, why, old=self.old.get(name))
        else:
            ch.new, ch.why, ch.readback, ch.restored, ch.note = value, why, None, None, ""
        return ch

    def _push_set(self, now: float, queue: CommandQueue, compid: int, setting: Setting) -> None:
        name, value, why = setting
        self._change(name, value, why)
        queue.push(
            now, f"PARAM_SET {name}",
            partial(self.profile.param_set, self.sysid, compid, name, value),
            partial(self._set_done, name), param=name, expect=value,
        )  # fmt: skip

    def _set_done(self, name: str, result: int, now: float) -> None:
        ch = self.changes[name]
        ch.readback = self._values.get(name)
        if ch.old is not None and not ch.changed:
            self._emit("param", f"vehicle {self.sysid}: {name} {ch.new:g} (unchanged; {ch.why})")
        else:
            self._emit("param", f"vehicle {self.sysid}: {name} {_fmt(ch.old)} -> {ch.new:g} "
                       f"({ch.why})")  # fmt: skip

    # ------------------------------------------------------------- ending
    def restore(
        self,
        now: float,
        queue: CommandQueue,
        compid: int,
        *,
        armed: bool,
        end_mode: int | None,
    ) -> None:
        """The vehicle ended (``end_mode`` confirmed) or failed (None): queue
        the old value of every parameter changed, best effort. An armed
        vehicle that will not come down on its own (BRAKE, or failed) keeps
        its failsafe and fence: with the station gone, they bring it down."""
        for name, ch in self.changes.items():
            current = self._values.get(name, ch.readback)
            if ch.readback is None:
                ch.readback = current  # the owner's own sets (GUID_TIMEOUT, ...) echo to it
            if ch.old is None:
                ch.note = "old value unknown (not read)"
                continue
            if current is None or same_param_value(current, ch.old):
                ch.note = "at its old value"
                continue
            if not self.settings.restore:
                ch.note = "not restored (mission.failsafe.restore false)"
                continue
            safety = name in self.profile.safety_params
            if safety and armed and end_mode not in self.profile.ends_on_own:
                ch.note = "kept: the vehicle is still armed and not landing or returning"
                continue
            queue.push(
                now, f"PARAM_SET {name} (restore)",
                partial(self.profile.param_set, self.sysid, compid, name, ch.old),
                partial(self._restore_done, name), param=name, expect=ch.old, optional=True,
                attempts=lambda: min(_RESTORE_ATTEMPTS, queue.attempts),
            )  # fmt: skip

    def _restore_done(self, name: str, result: int, now: float) -> None:
        ch = self.changes[name]
        assert ch.old is not None
        current = self._values.get(name)
        ch.restored = (
            result != NO_ANSWER and current is not None and same_param_value(current, ch.old)
        )
        if ch.restored:
            self._emit("param", f"vehicle {self.sysid}: {name} restored to {ch.old:g}")
        else:
            ch.note = f"not restored: the vehicle reports {_fmt(current)}"
            self._emit("warning", f"vehicle {self.sysid}: {name} not restored to {ch.old:g} "
                       f"(no answer; the vehicle reports {_fmt(current)})")  # fmt: skip

    # ------------------------------------------------------------- record
    def _final(self, ch: ParamChange) -> ParamChange:
        if ch.readback is None and ch.restored is None:
            ch.readback = self._values.get(ch.name)
        return ch

    def record(self) -> dict[str, Any]:
        """This vehicle's entry of ``vehicle_params.json``."""
        e, missing = self.envelope, self.envelope_missing
        source = "vehicle and mission"
        names = self.profile.envelope_params
        if len(missing) == len(names):
            source = "mission"
        elif not missing:
            source = "vehicle"
        return {
            "sysid": self.sysid,
            "envelope": {f.name: getattr(e, f.name) for f in fields(e)},
            "envelope_source": source,
            "envelope_unanswered": list(missing) if self.settings.read_envelope else [],
            "autopilot": self.profile.autopilot,
            "read": {n: self.old[n] for n in names if n in self.old},
            "unanswered": list(self.unanswered),
            "params": [self._final(ch).as_dict() for ch in self.changes.values()],
        }
