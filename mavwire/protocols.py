"""Typed views of the pymavlink objects both ends use (typing.Protocol).

pymavlink ships no type information, so to mypy its objects are ``Any``.
These protocols name the part of them the station and the emulator rely
on: a ``MAVLinkInterface`` (the generated dialect's ``MAVLink(None, sysid,
compid)``: ids, sequence, signing state, parser), its ``MAVLinkSigning``
state, and a ``MAVLinkMessage`` (a decoded or to-be-packed message: type,
header, source, raw bytes, and its fields by name). Annotating with them
documents what a function touches and lets mypy check those uses; pymavlink's
classes satisfy them without inheriting. Nothing here runs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

__all__ = ["MAVLinkHeader", "MAVLinkInterface", "MAVLinkMessage", "MAVLinkSigning"]


class MAVLinkHeader(Protocol):
    """A frame's header as pymavlink decodes it (``MAVLink_header``)."""

    msgId: int
    incompat_flags: int
    compat_flags: int
    mlen: int
    seq: int
    srcSystem: int
    srcComponent: int


class MAVLinkMessage(Protocol):
    """A pymavlink message object (``MAVLink_message`` and the generated
    ``MAVLink_<name>_message`` classes). Its fields are attributes named as
    in the message definition (``msg.custom_mode``), hence ``__getattr__``."""

    fieldnames: list[str]

    def get_type(self) -> str: ...
    def get_msgId(self) -> int: ...
    def get_srcSystem(self) -> int: ...
    def get_srcComponent(self) -> int: ...
    def get_seq(self) -> int: ...
    def get_signed(self) -> bool: ...
    def get_header(self) -> MAVLinkHeader: ...
    def get_msgbuf(self) -> bytearray: ...
    def to_dict(self) -> dict[str, Any]: ...
    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes: ...
    def __getattr__(self, name: str) -> Any: ...


class MAVLinkSigning(Protocol):
    """``MAVLink.signing``: MAVLink 2 signing state (mavwire.signing)."""

    secret_key: bytes | None
    link_id: int
    timestamp: int
    sign_outgoing: bool
    allow_unsigned_callback: Callable[[Any, int], bool] | None
    stream_timestamps: dict[tuple[int, int, int], int]
    reject_count: int


class MAVLinkInterface(Protocol):
    """The generated dialect's ``MAVLink`` object used with no file: its ids
    and next sequence number (``pack`` reads them; the owner of the I/O
    advances ``seq``), its signing state, and its parser (``parse_buffer``,
    ``decode`` of one whole frame, and the buffer state a robust parser is
    reset through). The ``<name>_encode`` builders are looked up by name."""

    seq: int
    srcSystem: int
    srcComponent: int
    robust_parsing: bool
    signing: MAVLinkSigning
    buf: bytearray
    buf_index: int
    expected_length: int
    have_prefix_error: bool

    def parse_buffer(self, s: bytes) -> list[MAVLinkMessage] | None: ...
    def decode(self, msgbuf: bytearray) -> MAVLinkMessage: ...
    def buf_len(self) -> int: ...
