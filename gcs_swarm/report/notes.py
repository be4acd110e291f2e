"""The station's log annotations: what a ``.tlog`` needs beyond the traffic.

A telemetry log holds what went over the links; the virtual leader, the
behaviour and the safety filter's work exist only inside the station. The
station therefore writes a few extra frames into its ``.tlog`` (never sent
to a vehicle) from system 255, component 155 (MAV_COMP_ID_LOG), all
``DEBUG_VECT`` (message 250, understood by every MAVLink tool, plotted by
MAVExplorer) with ``time_usec`` = mission time [us] (vehicle time from the
formation start, formation-law.md s4):

===========  ===============================  =================================
name         x, y, z                          when
===========  ===============================  =================================
``AVOID``    1 avoidance / 0 formation,       first step and whenever the
             episodes started so far, 0       behaviour changes (Eqs. 29-30),
                                              just before that step's LEADER
``LEADER``   leader position [m], mission     every control step, before that
             frame (x east, y north, z up)    step's setpoints; it marks the
                                              step (the law used each member's
                                              latest LOCAL_POSITION_NED)
``SAFE``     system id, |a - a_des| [m/s^2]   each vehicle whose command the
             of the safety filter, 0          safety filter changed that step
``JOIN``     system id, 0, 0                  the vehicle enters the formation
``LEAVE``    system id, 0, 0                  it leaves (event, lost, ending)
===========  ===============================  =================================

``NoteWriter`` encodes them (its own sequence numbers); ``parse_note``
reads one back from a decoded pymavlink message.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs_swarm.mavlink.codec import STATION_SYSID, Codec, MessageSpec

__all__ = ["LOG_COMPID", "NOTE_NAMES", "Note", "NoteWriter", "parse_note"]

LOG_COMPID = 155
"""MAV_COMP_ID_LOG: the source component of every annotation."""
NOTE_NAMES = ("AVOID", "LEADER", "SAFE", "JOIN", "LEAVE")


@dataclass(frozen=True, slots=True)
class Note:
    """One annotation: ``name``, mission time [s] and its three values."""

    name: str
    t_s: float
    x: float
    y: float
    z: float


def _spec(name: str, t_s: float, x: float, y: float = 0.0, z: float = 0.0) -> MessageSpec:
    return MessageSpec(
        "DEBUG_VECT",
        {"name": name, "time_usec": max(0, round(t_s * 1e6)), "x": x, "y": y, "z": z},
    )


class NoteWriter:
    """Encodes annotations and hands each frame to ``sink`` (the tlog)."""

    def __init__(self, sink: Callable[[bytes], None]) -> None:
        self._sink = sink
        self._codec = Codec(sysid=STATION_SYSID, compid=LOG_COMPID)
        self._mode: tuple[str, int] | None = None

    def _emit(self, spec: MessageSpec) -> None:
        self._sink(self._codec.encode(spec))

    def step(
        self,
        t_s: float,
        leader_pos_m: npt.ArrayLike,
        behaviour: str,
        episode: int,
        ids: Sequence[int],
        correction_mps2: npt.ArrayLike | None,
    ) -> None:
        mode = (behaviour, int(episode))
        if mode != self._mode:
            self._mode = mode
            self._emit(_spec("AVOID", t_s, float(behaviour == "avoidance"), float(episode)))
        lead = np.asarray(leader_pos_m, dtype=np.float64).reshape(3)
        self._emit(_spec("LEADER", t_s, float(lead[0]), float(lead[1]), float(lead[2])))
        if correction_mps2 is not None:
            cor = np.asarray(correction_mps2, dtype=np.float64).reshape(-1)
            for i in np.flatnonzero(cor > 0.0):
                self._emit(_spec("SAFE", t_s, float(ids[int(i)]), float(cor[i])))

    def member(self, t_s: float, sysid: int, joined: bool) -> None:
        self._emit(_spec("JOIN" if joined else "LEAVE", t_s, float(sysid)))


def _text(value: Any) -> str:
    if isinstance(value, bytes | bytearray):
        value = bytes(value).decode("ascii", errors="replace")
    return str(value).split("\x00", 1)[0]


def parse_note(msg: Any) -> Note | None:
    """The annotation carried by a decoded pymavlink message, or None."""
    if msg.get_type() != "DEBUG_VECT":
        return None
    if msg.get_srcSystem() != STATION_SYSID or msg.get_srcComponent() != LOG_COMPID:
        return None
    name = _text(msg.name)
    if name not in NOTE_NAMES:
        return None
    return Note(name, int(msg.time_usec) * 1e-6, float(msg.x), float(msg.y), float(msg.z))
