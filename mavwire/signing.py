"""MAVLink 2 message signing set-up, shared by the station and the emulator.

A signing peer is a pymavlink ``MAVLink`` object (the generated
``ardupilotmega`` dialect, never ``mavutil``) whose ``signing`` state is
set as ArduPilot uses it: ``secret_key`` (32 bytes), ``link_id`` 0,
``timestamp`` in 10 us units since 2015-01-01 UTC, ``sign_outgoing``. As a
parser it accepts a frame only if its signature is good and its timestamp
newer than the last of its stream (link id, system, component); only
RADIO_STATUS may come unsigned (ArduPilot's one exception). Rejections are
counted by pymavlink in ``signing.reject_count``.

Unlike pymavlink, a frame whose signature is wrong does not move its
stream's timestamp (``SigningMAVLink``): pymavlink records the timestamp
before it checks the signature, so one forged frame stamped far in the
future would make every genuine frame after it look replayed.

No I/O and no clock: the time a signer starts from is the caller's
``unix_s``. The key is never logged or shown.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as _dialect

from mavwire.protocols import MAVLinkInterface

__all__ = [
    "SIGNING_KEY_BYTES",
    "SigningMAVLink",
    "mavlink",
    "setup_signing",
    "signing_timestamp",
]

SIGNING_KEY_BYTES = 32
"""Length of a MAVLink 2 signing secret key."""
_SIGNING_EPOCH_S = 1420070400.0  # 2015-01-01T00:00:00Z, the signing timestamp's origin
_UNSIGNED_OK = frozenset({_dialect.MAVLINK_MSG_ID_RADIO_STATUS})


def signing_timestamp(unix_s: float) -> int:
    """The signing timestamp of Unix time ``unix_s``: 10 us units since 2015 (never negative)."""
    return max(0, int((unix_s - _SIGNING_EPOCH_S) * 1e5))


def _allow_unsigned(mav: Any, msg_id: int) -> bool:  # pymavlink's callback signature
    return msg_id in _UNSIGNED_OK


class SigningMAVLink(_dialect.MAVLink):  # type: ignore[misc]
    """pymavlink's ``MAVLink``, except that a frame whose signature check
    fails leaves its stream's timestamp where it was (see the module)."""

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


def setup_signing(mav: MAVLinkInterface, key: bytes, unix_s: float, *, link_id: int = 0) -> None:
    """Sign everything ``mav`` (a pymavlink ``MAVLink``) sends with ``key``,
    timestamps starting at Unix time ``unix_s``, and accept only well-signed,
    fresh frames (RADIO_STATUS may be unsigned). ValueError unless ``key``
    has ``SIGNING_KEY_BYTES`` bytes."""
    if len(key) != SIGNING_KEY_BYTES:
        raise ValueError(f"a MAVLink signing key has {SIGNING_KEY_BYTES} bytes, not {len(key)}")
    mav.signing.secret_key = bytes(key)
    mav.signing.link_id = link_id
    mav.signing.timestamp = signing_timestamp(unix_s)
    mav.signing.sign_outgoing = True
    mav.signing.allow_unsigned_callback = _allow_unsigned


def mavlink(
    sysid: int, compid: int, key: bytes | None = None, *, unix_s: float | None = None
) -> MAVLinkInterface:
    """A ``SigningMAVLink`` for (``sysid``, ``compid``) with robust parsing;
    with a ``key`` it signs and checks (``setup_signing`` from ``unix_s``,
    the Unix time now, which a key requires: ValueError without it)."""
    mav = SigningMAVLink(None, sysid, compid)
    mav.robust_parsing = True
    if key is not None:
        if unix_s is None:
            raise ValueError("a signing MAVLink peer needs unix_s, the time now")
        setup_signing(mav, key, unix_s)
    return mav
