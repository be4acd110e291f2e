"""MAVLink 2 signing set-up (``mavwire.signing``), both ends' one copy: a
frame signed by one side verifies on the other; a wrong key is rejected and
does not move its stream's timestamp; replays, unsigned frames (but
RADIO_STATUS) and bad keys are refused. Timestamps are exact integers."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from mavwire import SIGNING_KEY_BYTES, mavlink, setup_signing, signing_timestamp

KEY = bytes(range(32))
WRONG = bytes(range(1, 33))
T = 1.8e9  # Unix time [s] of the tests (2027): a fixed clock, no wall time


def _frame(mav: object, t_ms: int = 1) -> bytes:
    msg = dialect.MAVLink_local_position_ned_message(t_ms, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0)
    return bytes(msg.pack(mav))


def _good(mav: object, data: bytes) -> list[object]:
    """The messages ``mav`` parses from ``data`` (robust parsing hands rejected
    frames out as bad data: dropped here)."""
    msgs = mav.parse_buffer(data) or []  # type: ignore[attr-defined]
    return [m for m in msgs if not isinstance(m, dialect.MAVLink_bad_data)]


def test_signing_timestamp_counts_10us_since_2015() -> None:
    epoch = 1420070400.0
    assert signing_timestamp(epoch) == 0
    assert signing_timestamp(epoch + 1.0) == 100_000
    assert signing_timestamp(epoch - 5.0) == 0  # before 2015: clamped, never negative
    assert signing_timestamp(T) == int((T - epoch) * 1e5)


def test_a_frame_signed_by_one_side_verifies_on_the_other() -> None:
    vehicle = mavlink(1, 1, KEY, unix_s=T)
    station = mavlink(255, 190, KEY, unix_s=T)
    frame = _frame(vehicle)
    assert frame[2] & dialect.MAVLINK_IFLAG_SIGNED and len(frame) == 12 + frame[1] + 13
    (msg,) = _good(station, frame)
    assert msg.get_type() == "LOCAL_POSITION_NED" and msg.get_srcSystem() == 1
    stamp = int.from_bytes(frame[-12:-6], "little")
    assert station.signing.stream_timestamps == {(0, 1, 1): stamp}
    assert _good(station, frame) == []  # the same frame again: a replay
    assert station.signing.reject_count == 1


def test_a_wrong_key_is_rejected_and_does_not_move_the_stream_timestamp() -> None:
    """A forger with the wrong key, stamping 1000 s ahead: its frames are
    refused, the stream's timestamp stays where the genuine sender left it
    (also for a stream not heard yet), so the genuine frames still pass."""
    vehicle = mavlink(1, 1, KEY, unix_s=T)
    forger = mavlink(1, 1, WRONG, unix_s=T + 1000.0)
    station = mavlink(255, 190, KEY, unix_s=T)
    assert _good(station, _frame(forger)) == []
    assert station.signing.stream_timestamps == {}  # a new stream: not recorded
    assert _good(station, _frame(vehicle, 2))[0].time_boot_ms == 2
    before = dict(station.signing.stream_timestamps)
    assert _good(station, _frame(forger, 3)) == []
    assert station.signing.stream_timestamps == before  # an old stream: not moved
    assert _good(station, _frame(vehicle, 4))[0].time_boot_ms == 4
    assert station.signing.reject_count == 2


def test_pymavlinks_own_parser_lacks_that_protection() -> None:
    """Why ``SigningMAVLink`` exists: with pymavlink's plain ``MAVLink`` one
    forged future frame locks the genuine sender out. (If this fails, pymavlink
    has fixed it and ``SigningMAVLink.check_signature`` may go.)"""
    vehicle = mavlink(1, 1, KEY, unix_s=T)
    forger = mavlink(1, 1, WRONG, unix_s=T + 1000.0)
    plain = dialect.MAVLink(None, 255, 190)
    setup_signing(plain, KEY, T)
    plain.robust_parsing = True
    assert _good(plain, _frame(vehicle, 1))
    assert _good(plain, _frame(forger, 2)) == []
    assert _good(plain, _frame(vehicle, 3)) == []  # locked out


def test_only_radio_status_may_come_unsigned() -> None:
    unsigned = mavlink(1, 1)  # no key: packs unsigned
    station = mavlink(255, 190, KEY, unix_s=T)
    radio = dialect.MAVLink_radio_status_message(200, 190, 100, 30, 20, 0, 0)
    assert [m.get_type() for m in _good(station, bytes(radio.pack(unsigned)))] == ["RADIO_STATUS"]
    assert _good(station, _frame(unsigned)) == []
    assert station.signing.reject_count == 1


def test_bad_set_ups_are_refused() -> None:
    with pytest.raises(ValueError, match=f"{SIGNING_KEY_BYTES} bytes, not 31"):
        mavlink(1, 1, KEY[:31], unix_s=T)
    with pytest.raises(ValueError, match="needs unix_s"):
        mavlink(1, 1, KEY)
    peer = mavlink(1, 1)
    assert peer.robust_parsing and not peer.signing.sign_outgoing
