"""MAVLink 2 message signing of the emulator (issue 9), as ArduPilot does it.

Owns ``mavlink(sysid, compid, key)``: a pymavlink ``MAVLink`` object that,
with a 32-byte ``key``, signs every frame it packs (``MAVLink.signing``:
``secret_key``, ``link_id`` 0, ``timestamp`` in 10 us units since
2015-01-01 UTC, ``sign_outgoing``) and, as a parser, accepts only frames
with a good signature and a timestamp newer than the last of their stream;
only RADIO_STATUS may come unsigned (ArduPilot's exception). Rejections are
``signing.reject_count``. Unlike pymavlink, a frame with a wrong signature
does not move its stream's timestamp (one forged frame stamped in the future
would otherwise lock out the genuine sender). No I/O; the key is never shown.
"""

from __future__ import annotations

import time
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

__all__ = ["mavlink"]

_EPOCH_S = 1420070400.0  # 2015-01-01T00:00:00Z
_UNSIGNED_OK = frozenset({mav.MAVLINK_MSG_ID_RADIO_STATUS})


class _Signed(mav.MAVLink):  # type: ignore[misc]
    def check_signature(self, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        key = (msgbuf[-13], src_system, src_component)
        before = self.signing.stream_timestamps.get(key)
        ok: bool = super().check_signature(msgbuf, src_system, src_component)
        if not ok:
            if before is None:
                self.signing.stream_timestamps.pop(key, None)
            else:
                self.signing.stream_timestamps[key] = before
        return ok


def _allow_unsigned(_mav: Any, msg_id: int) -> bool:
    return msg_id in _UNSIGNED_OK


def mavlink(sysid: int, compid: int, key: bytes | None) -> Any:
    """A pymavlink ``MAVLink`` for (sysid, compid), signing with ``key`` if given."""
    m = _Signed(None, sysid, compid)
    m.robust_parsing = True
    if key is not None:
        m.signing.secret_key = bytes(key)
        m.signing.link_id = 0
        m.signing.timestamp = max(0, int((time.time() - _EPOCH_S) * 1e5))
        m.signing.sign_outgoing = True
        m.signing.allow_unsigned_callback = _allow_unsigned
    return m
