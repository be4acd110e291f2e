"""MAVLink 2 message signing of the emulator (issue 9), as ArduPilot does it.

Owns ``mavlink(sysid, compid, key)``: ``mavwire.mavlink`` (the set-up the
station uses too) started from the emulator's wall clock. With a 32-byte
``key`` it signs every frame it packs (link id 0, timestamps in 10 us units
since 2015-01-01 UTC) and, as a parser, accepts only frames with a good
signature and a timestamp newer than the last of their stream; only
RADIO_STATUS may come unsigned (ArduPilot's exception). Rejections are
``signing.reject_count``. Unlike pymavlink, a frame with a wrong signature
does not move its stream's timestamp (``mavwire.SigningMAVLink``). The key
is never shown.
"""

from __future__ import annotations

import time

import mavwire
from mavwire.protocols import MAVLinkInterface

__all__ = ["mavlink"]


def mavlink(sysid: int, compid: int, key: bytes | None) -> MAVLinkInterface:
    """A pymavlink ``MAVLink`` for (sysid, compid), signing with ``key`` if given."""
    return mavwire.mavlink(sysid, compid, key, unix_s=time.time())
