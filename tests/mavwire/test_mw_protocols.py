"""``mavwire.protocols`` describe pymavlink's real objects: every attribute
and method a protocol declares exists on the object it stands for (a
pymavlink upgrade that renamed one would fail here, not in a flight)."""

from __future__ import annotations

from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavwire import (
    MAVLinkHeader,
    MAVLinkInterface,
    MAVLinkMessage,
    MAVLinkSigning,
    mavlink,
)


def _members(protocol: type) -> set[str]:
    declared = set(protocol.__annotations__)
    declared |= {n for n, v in vars(protocol).items() if callable(v) and not n.startswith("__")}
    return declared


def _objects() -> dict[type, Any]:
    peer = mavlink(7, 1, bytes(range(32)), unix_s=1.8e9)
    frame = mav.MAVLink(None, 3, 1).heartbeat_encode(2, 3, 81, 4, 4).pack(mav.MAVLink(None, 3, 1))
    (msg,) = mav.MAVLink(None).parse_buffer(frame) or []
    return {MAVLinkInterface: peer, MAVLinkSigning: peer.signing, MAVLinkMessage: msg,
            MAVLinkHeader: msg.get_header()}  # fmt: skip


@pytest.mark.parametrize("protocol", [MAVLinkInterface, MAVLinkSigning, MAVLinkMessage,
                                      MAVLinkHeader], ids=lambda p: p.__name__)  # fmt: skip
def test_every_declared_member_exists_on_pymavlinks_object(protocol: type) -> None:
    obj = _objects()[protocol]
    members = _members(protocol)
    assert len(members) >= 6
    missing = {name for name in members if not hasattr(obj, name)}
    assert missing == set(), f"{type(obj).__name__} lacks {sorted(missing)}"


def test_the_messages_fields_are_attributes() -> None:
    """``MAVLinkMessage.__getattr__`` stands for the fields: each name in
    ``fieldnames`` reads as an attribute."""
    msg = _objects()[MAVLinkMessage]
    assert msg.fieldnames and all(hasattr(msg, name) for name in msg.fieldnames)
    assert (msg.get_type(), msg.custom_mode, msg.get_srcSystem()) == ("HEARTBEAT", 4, 3)
