"""MAVLink wire plumbing shared by the station (``gcs_swarm``) and the
emulator (``sim_vehicle``): byte-level rules both ends must apply alike,
and nothing of either end's state machines or message semantics.

- ``mavwire.signing``: MAVLink 2 signing set-up (``mavlink``,
  ``setup_signing``, ``signing_timestamp``) and a parser whose failed
  signature checks do not move a stream's timestamp (``SigningMAVLink``);
- ``mavwire.crc``: the MAVLink checksum, pymavlink's C CRC when installed
  (``frame_crc``, ``MCRF4XX``), many frames' at once (``row_crcs``: by
  position tables, ``table_crcs``, from ``ROWS_MIN`` frames on, else
  ``frame_by_frame_crcs``), and its
  column-wise numpy step (``crc_step``);
- ``mavwire.datagrams``: frames joined into UDP datagrams of at most
  ``MAX_DATAGRAM_BYTES`` (``datagram_bounds``);
- ``mavwire.framing``: unsigned MAVLink 2 frames of one message type built
  many at once from numpy columns, or one from a packed payload
  (``FrameBuilder``, ``FrameBatch``);
- ``mavwire.protocols``: typed views of the pymavlink objects used
  (``MAVLinkInterface``, ``MAVLinkMessage``, ``MAVLinkSigning``,
  ``MAVLinkHeader``).

Imports only the standard library, numpy and pymavlink's generated dialect
(a test says so); does no I/O and reads no clock.
"""

from __future__ import annotations

from mavwire.crc import (
    CRC_INIT,
    CRC_TABLE,
    MCRF4XX,
    ROWS_MIN,
    crc_step,
    frame_by_frame_crcs,
    frame_crc,
    row_crcs,
    table_crcs,
)
from mavwire.datagrams import MAX_DATAGRAM_BYTES, datagram_bounds
from mavwire.framing import HEADER_BYTES, FrameBatch, FrameBuilder
from mavwire.protocols import MAVLinkHeader, MAVLinkInterface, MAVLinkMessage, MAVLinkSigning
from mavwire.signing import (
    SIGNING_KEY_BYTES,
    SigningMAVLink,
    mavlink,
    setup_signing,
    signing_timestamp,
)

__all__ = [
    "CRC_INIT",
    "CRC_TABLE",
    "HEADER_BYTES",
    "MAX_DATAGRAM_BYTES",
    "MCRF4XX",
    "ROWS_MIN",
    "SIGNING_KEY_BYTES",
    "FrameBatch",
    "FrameBuilder",
    "MAVLinkHeader",
    "MAVLinkInterface",
    "MAVLinkMessage",
    "MAVLinkSigning",
    "SigningMAVLink",
    "crc_step",
    "datagram_bounds",
    "frame_by_frame_crcs",
    "frame_crc",
    "mavlink",
    "row_crcs",
    "setup_signing",
    "signing_timestamp",
    "table_crcs",
]
