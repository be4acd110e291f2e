"""The vehicle's own safety rules: the GCS failsafe and the fence. PURE: no I/O, no state.

READING of ArduCopter 4.5.6 (``ArduCopter/events.cpp`` ``failsafe_gcs_on_event``,
``ArduCopter/fence.cpp`` ``fence_check``, ``libraries/AC_Fence``), facts only:

- GCS failsafe: only HEARTBEATs from system ``SYSID_MYGCS`` feed it; it never
  fires before the first one. After ``FS_GCS_TIMEOUT`` s without one, while
  armed: landed -> disarm; landing with ``FS_OPTIONS`` bit 8 -> keep landing;
  ``FS_OPTIONS`` bit 16 in a pilot-controlled mode (not GUIDED, RTL, LAND) ->
  nothing; else ``FS_GCS_ENABLE`` 1, 2, 3, 6 (and any other value) -> RTL
  (no SmartRTL path or mission here), 4, 5 -> LAND, 7 -> BRAKE.
  STATUSTEXT "GCS Failsafe" (WARNING), with " - <what>" for the exceptions.
- Fence (``FENCE_ENABLE`` 1): ``FENCE_TYPE`` bit 1 breaches above
  ``FENCE_ALT_MAX`` m over home, bit 2 beyond ``FENCE_RADIUS`` m from home
  (horizontal). A new breach while armed sends "Fence Breached" (NOTICE) and:
  landed -> disarm; more than 100 m outside -> LAND; else ``FENCE_ACTION`` 0
  report only, 1 RTL, 2 LAND, 3 (SmartRTL) -> RTL, 4 BRAKE, 5 (SmartRTL or
  LAND) -> LAND. A breach acts once; it acts again only after it has cleared.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["AUTOPILOT_MODES", "Action", "fence_action", "fence_breaches", "gcs_failsafe"]

RTL, LAND, BRAKE, GUIDED = 6, 9, 17, 4
#: Copter modes whose ``is_autopilot()`` is true among those emulated.
AUTOPILOT_MODES = frozenset({GUIDED, RTL, LAND})
FS_OPT_CONTINUE_IF_LANDING = 8
FS_OPT_GCS_CONTINUE_IF_PILOT_CONTROL = 16
FENCE_GIVE_UP_M = 100.0  # AC_FENCE_GIVE_UP_DISTANCE
FENCE_ALT_MAX_BIT, FENCE_CIRCLE_BIT = 1, 2
_FS_MODE = {1: RTL, 2: RTL, 3: RTL, 4: LAND, 5: LAND, 6: RTL, 7: BRAKE}
_FENCE_MODE = {1: RTL, 2: LAND, 3: RTL, 4: BRAKE, 5: LAND}


@dataclass(frozen=True)
class Action:
    """What a safety rule does: switch to ``mode`` (None: keep), ``disarm``, say ``text``."""

    mode: int | None
    disarm: bool
    text: str
    severity: int = 4  # MAV_SEVERITY_WARNING


def gcs_failsafe(
    fs_enable: int, fs_options: int, mode: int, landing: bool, land_complete: bool
) -> Action | None:
    """The GCS failsafe's action when it triggers on an armed vehicle (None: disabled)."""
    if fs_enable == 0:
        return None
    if land_complete:
        return Action(None, True, "GCS Failsafe - Disarming")
    if landing and fs_options & FS_OPT_CONTINUE_IF_LANDING:
        return Action(LAND, False, "GCS Failsafe - Continuing Landing")
    if fs_options & FS_OPT_GCS_CONTINUE_IF_PILOT_CONTROL and mode not in AUTOPILOT_MODES:
        return Action(None, False, "GCS Failsafe - Continuing Pilot Control")
    return Action(_FS_MODE.get(fs_enable, RTL), False, "GCS Failsafe")


def fence_breaches(
    enable: int, kinds: int, alt_max_m: float, radius_m: float, alt_m: float, dist_m: float
) -> tuple[int, float]:
    """(breached FENCE_TYPE bits, largest distance outside in m) at ``alt_m`` above home and
    ``dist_m`` from home horizontally."""
    if not enable:
        return 0, 0.0
    bits, out = 0, 0.0
    if kinds & FENCE_ALT_MAX_BIT and alt_m > alt_max_m:
        bits |= FENCE_ALT_MAX_BIT
        out = max(out, alt_m - alt_max_m)
    if kinds & FENCE_CIRCLE_BIT and dist_m > radius_m:
        bits |= FENCE_CIRCLE_BIT
        out = max(out, dist_m - radius_m)
    return bits, out


def fence_action(action: int, outside_m: float, land_complete: bool) -> Action:
    """What a new fence breach does (``FENCE_ACTION``, distance outside the fence)."""
    text, notice = "Fence Breached", 5  # MAV_SEVERITY_NOTICE
    if action == 0:
        return Action(None, False, text, notice)
    if land_complete:
        return Action(None, True, text, notice)
    if outside_m > FENCE_GIVE_UP_M:
        return Action(LAND, False, text, notice)
    return Action(_FENCE_MODE.get(action, RTL), False, text, notice)
