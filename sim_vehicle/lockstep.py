"""The lockstep rule's tests on the fleet rows. NO I/O.

The rule itself (rules 1-4) is written in the ``sim_vehicle`` package
docstring (docs/emulator.md, "How the code is laid out", says where each
piece lives). Here: which vehicle blocks
the next step (rules 2-3: ``blocked``), when the answers count (``answered``,
``setpoint_rows``:
a setpoint heard, even one the uplink then loses), when the clock may start
(``started``, rule 1) and how long an unblocked clock waits (``pace_delay``,
rule 4). The asyncio shell (``server``) waits on these with one timer.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle.fleet import Fleet
from sim_vehicle.small import few

if TYPE_CHECKING:
    from sim_vehicle.vehicles import HostedVehicle, Port

__all__ = ["GRACE_TURNS", "answered", "blocked", "pace_delay", "setpoint_rows", "started"]

_SETPOINT_ID = mav.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED

GRACE_TURNS = 8
"""Event-loop turns a lockstep step still waits for its answers once the
wall-clock timeout has passed (microseconds on a quiet machine: a lost answer
still times out; after a stall of the process the answers that are on their
way get in)."""


def blocked(fleet: Fleet) -> bool:
    """Rules 2-3: some holding vehicle blocks the next step (it was sent a
    LOCAL_POSITION_NED and has not answered, or it is streamed none)."""
    f = fleet
    if few(f.n):  # twice per lockstep step: three tolist() beat four numpy calls
        isinf = math.isinf
        for h, a, iv in zip(
            f.holding.tolist(), f.awaiting.tolist(), f.lpn_interval.tolist(), strict=True
        ):
            if h and (a or isinf(iv)):
                return True
        return False
    return bool((f.holding & (f.awaiting | np.isinf(f.lpn_interval))).any())


def answered(fleet: Fleet, rows: Iterable[int]) -> None:
    """Rule 3: the vehicles of ``rows`` heard a setpoint; they no longer block."""
    for row in rows:
        fleet.awaiting[row] = False


def started(contacted: Iterable[bool]) -> bool:
    """Rule 1: sim time may run once every vehicle present at start has heard a station."""
    return all(contacted)


def pace_delay(last_wall_s: float, period_s: float, now_wall_s: float) -> float:
    """Rule 4: wall seconds to wait before the next step while nobody holds (>= 0)."""
    return max(last_wall_s + period_s - now_wall_s, 0.0)


def setpoint_rows(vehicles: Mapping[int, HostedVehicle], ep: Port, msgs: list[Any]) -> list[int]:
    """Rule 3: the rows of the vehicles of port ``ep`` a setpoint of ``msgs``
    is for (``answered``: it counts even if the uplink then loses it)."""
    rows = []
    sysids = ep.sysids
    for m in msgs:
        if m.get_msgId() == _SETPOINT_ID:
            ts = m.target_system
            for sysid in sysids if ts == 0 else (ts,):
                v = vehicles.get(sysids.get(sysid, -1))
                if v is not None and v.ep is ep:
                    rows.append(v.row)
    return rows
