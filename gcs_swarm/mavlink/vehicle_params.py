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

The values themselves (Eqs. E1, F1, F2, each autopilot's ``ParamProfile``)
are ``param_values.py``'s, re-exported here.

Units on the wire are ArduCopter's own (cm/s, cm/s^2, centidegrees, m, s);
the ``Envelope`` is SI. docs/vehicle-safety.md says why each value.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from functools import partial
from typing import Any

from gcs_swarm.control.params import Envelope, Vec3
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.codec import STATION_SYSID
from gcs_swarm.mavlink.commands import NO_ANSWER, CommandQueue, same_param_value
from gcs_swarm.mavlink.param_values import (
    ARDUCOPTER,
    ARDUCOPTER_DEFAULTS,
    ENVELOPE_PARAMS,
    FAILSAFE_PARAMS,
    FENCE_PARAMS,
    MEASURED_LAG_S,
    EndAction,
    ParamProfile,
    Setting,
    envelope_from_params,
    failsafe_values,
    fence_values,
)

__all__ = [
    "ARDUCOPTER",
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

Emit = Callable[[str, str], None]
"""``emit(kind, text)``: kind is ``param``, ``info`` or ``warning``."""

_QUICK_READ_ATTEMPTS = 2
"""Sends of each later read once one read went unanswered after the usual
retries: that vehicle does not know these names (8 x 10 s would eat the
start-up); a real ArduCopter answers every one."""
_RESTORE_ATTEMPTS = 3
"""Sends of each restoring PARAM_SET (best effort, inside the end timeout)."""


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
        label: str | None = None,
    ) -> None:
        self.sysid = sysid
        self.label = str(sysid) if label is None else label
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
            self._emit("info", f"vehicle {self.label}: {note}")
        for setting in settings:
            self._push_set(now, queue, compid, setting)

    def _read_done(self, name: str, result: int, now: float) -> None:
        value = self._values.get(name)
        if result == NO_ANSWER or value is None:
            self._silent = True
            if name not in self.unanswered:
                self.unanswered.append(name)
            self._emit("warning", f"vehicle {self.label}: no answer to PARAM_REQUEST_READ "
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
            f"vehicle {self.label}: envelope {e.describe()} ({source})",
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
            self._emit("param", f"vehicle {self.label}: {name} {ch.new:g} (unchanged; {ch.why})")
        else:
            self._emit("param", f"vehicle {self.label}: {name} {_fmt(ch.old)} -> {ch.new:g} "
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
            self._emit("param", f"vehicle {self.label}: {name} restored to {ch.old:g}")
        else:
            ch.note = f"not restored: the vehicle reports {_fmt(current)}"
            self._emit("warning", f"vehicle {self.label}: {name} not restored to {ch.old:g} "
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
