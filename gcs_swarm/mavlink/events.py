"""PX4's EVENT message (MAVLink 410) and the few event ids the station names.

PX4 v1.14 gives the reasons for a refused arming only as EVENT messages, not
STATUSTEXT (mavlink-protocol.md, PX4 section). pymavlink 2.4.50's
``ardupilotmega`` dialect does not define EVENT (it is a work-in-progress
message of common.xml), so ``register`` adds its class to the dialect the
codec decodes with: the class below is what pymavlink's generator makes of
common.xml's definition (wire order id, event_time_boot_ms, sequence,
destination_component, destination_system, log_levels, arguments[40];
CRC_EXTRA 160). No I/O.

An event's id is PX4's hash of its name (component metadata,
``all_events.json`` of the build); ``describe`` turns the ids the station
meets into words, and any other into its id, log level and leading argument
bytes, so that a refusal always says something.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any, ClassVar

from pymavlink.dialects.v20 import ardupilotmega as _dialect

from gcs_swarm.mavlink.px4_events import PX4_EVENT_MESSAGES

__all__ = ["MSG_ID_EVENT", "PX4_EVENTS", "EventMessage", "describe", "register"]

MSG_ID_EVENT = 410
_ARGS = 40


class EventMessage(_dialect.MAVLink_message):  # type: ignore[misc]
    """EVENT (410), as pymavlink's generator writes it from common.xml."""

    id = MSG_ID_EVENT
    msgname = "EVENT"
    fieldnames: ClassVar[list[str]] = [
        "destination_component", "destination_system", "id", "event_time_boot_ms", "sequence",
        "log_levels", "arguments",
    ]  # fmt: skip
    ordered_fieldnames: ClassVar[list[str]] = [
        "id", "event_time_boot_ms", "sequence", "destination_component", "destination_system",
        "log_levels", "arguments",
    ]  # fmt: skip
    fieldtypes: ClassVar[list[str]] = [
        "uint8_t", "uint8_t", "uint32_t", "uint32_t", "uint16_t", "uint8_t", "uint8_t",
    ]  # fmt: skip
    fielddisplays_by_name: ClassVar[dict[str, str]] = {}
    fieldenums_by_name: ClassVar[dict[str, str]] = {}
    fieldunits_by_name: ClassVar[dict[str, str]] = {"event_time_boot_ms": "ms"}
    native_format = bytearray(b"<IIHBBBB")
    orders: ClassVar[list[int]] = [3, 4, 0, 1, 2, 5, 6]
    lengths: ClassVar[list[int]] = [1, 1, 1, 1, 1, 1, _ARGS]
    array_lengths: ClassVar[list[int]] = [0, 0, 0, 0, 0, 0, _ARGS]
    crc_extra = 160
    unpacker = struct.Struct(f"<IIHBBB{_ARGS}B")
    instance_field = None
    instance_offset = -1

    def __init__(
        self,
        destination_component: int,
        destination_system: int,
        id: int,  # the field's name in common.xml
        event_time_boot_ms: int,
        sequence: int,
        log_levels: int,
        arguments: Sequence[int],
    ) -> None:
        _dialect.MAVLink_message.__init__(self, MSG_ID_EVENT, "EVENT")
        self._fieldnames = EventMessage.fieldnames
        self._instance_field = None
        self._instance_offset = -1
        self.destination_component = destination_component
        self.destination_system = destination_system
        self.id = id
        self.event_time_boot_ms = event_time_boot_ms
        self.sequence = sequence
        self.log_levels = log_levels
        args = list(arguments)[:_ARGS]
        self.arguments = args + [0] * (_ARGS - len(args))

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        payload = self.unpacker.pack(
            self.id, self.event_time_boot_ms, self.sequence, self.destination_component,
            self.destination_system, self.log_levels, *self.arguments,
        )  # fmt: skip
        packed: bytes = self._pack(mav, self.crc_extra, payload, force_mavlink1=force_mavlink1)
        return packed


def register() -> None:
    """Let the dialect decode EVENT (idempotent; the emulator registers the
    same definition on its own side)."""
    _dialect.mavlink_map.setdefault(MSG_ID_EVENT, EventMessage)


PX4_EVENTS: dict[int, str] = {i: m for i, (_, m) in PX4_EVENT_MESSAGES.items()}
"""Event id -> what it says, for PX4 v1.14's arming, health and failsafe
events (px4_events.py, from the build's all_events.json)."""

_LEVELS = ("emergency", "alert", "critical", "error", "warning", "notice", "info", "debug")


def describe(event_id: int, log_levels: int, arguments: Sequence[int]) -> str:
    """Words for one EVENT: the table's text, else its id, its external log
    level and its first argument bytes (PX4 packs its arguments little-endian)."""
    known = PX4_EVENTS.get(event_id)
    if known is not None:
        return known
    level = log_levels & 0x0F
    name = _LEVELS[level] if level < len(_LEVELS) else str(level)
    head = bytes(arguments[:8]).hex()
    return f"PX4 event {event_id} ({name}, arguments {head})"


register()
