"""Codec round trips, counted bad packets, builders' numbers, and the frame
conversion between each vehicle's LOCAL_NED and the mission frame."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.mavlink import (
    Codec,
    GeoOrigin,
    from_pymavlink,
    mission_to_ned,
    ned_to_mission,
    origin_offset_m,
    vector_mission_to_ned,
)
from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.coordinates import mission_to_ned_floats, vector_mission_to_ned_floats
from gcs_swarm.mavlink.inbound import LocalPositionNed


def _vehicle_bytes(sysid: int, seq_msgs: int = 1) -> bytes:
    mav = dialect.MAVLink(None, sysid, 1)
    out = b""
    for i in range(seq_msgs):
        msg = mav.local_position_ned_encode(1000 + i, 1.0, 2.0, -3.0, 0.5, 0.25, -0.75)
        out += msg.pack(mav)
        mav.seq += 1
    return out


def test_encode_decodes_on_the_other_side_with_station_ids_and_sequence() -> None:
    codec = Codec()
    rx = dialect.MAVLink(None, 1, 1)
    spec = b.accel_setpoint(7, 1, 1234, (0.5, -0.25, 1.0))
    frames = [codec.encode(spec) for _ in range(3)]
    msgs = [rx.parse_buffer(f)[0] for f in frames]
    assert [m.get_seq() for m in msgs] == [0, 1, 2]
    m = msgs[0]
    assert (m.get_srcSystem(), m.get_srcComponent()) == (255, 190)
    assert (m.target_system, m.coordinate_frame, m.type_mask) == (7, 1, 3135)
    assert (m.afx, m.afy, m.afz) == (0.5, -0.25, 1.0)
    ps = rx.parse_buffer(codec.encode(b.param_set(7, 1, "GUID_TIMEOUT", 0.5)))[0]
    assert ps.param_id == "GUID_TIMEOUT" and abs(ps.param_value - 0.5) < 1e-7
    assert codec.stats.sent == 4


def test_bad_and_unknown_packets_are_counted_and_do_not_spoil_the_next_datagram() -> None:
    codec = Codec()
    good = _vehicle_bytes(4)
    corrupt = bytearray(good)
    corrupt[12] ^= 0xFF  # payload byte: CRC mismatch
    assert codec.decode(bytes(corrupt)) == []
    assert codec.decode(b"\xfd\x09garbage that is not a frame") == []
    truncated = good[:-3]
    assert codec.decode(truncated) == []  # partial frame at datagram end: dropped
    (msg,) = codec.decode(good)
    view = from_pymavlink(msg)
    assert view == LocalPositionNed(
        4, 1, 1000, 1.0, 2.0, -3.0, 0.5, 0.25, -0.75
    )  # exact in float32
    assert codec.stats.bad_packets >= 3
    assert codec.stats.received == 1


def test_stream_decoding_reassembles_split_frames() -> None:
    codec = Codec()
    data = _vehicle_bytes(2, seq_msgs=3)
    got = codec.decode(data[:10], datagram=False) + codec.decode(data[10:], datagram=False)
    assert [m.time_boot_ms for m in got] == [1000, 1001, 1002]
    assert codec.stats.bad_packets == 0


def test_builders_match_the_protocol_sheet() -> None:
    # Spec: SET_MESSAGE_INTERVAL param2 in microseconds; takeoff altitude in param7;
    # GUIDED is custom mode 4 with MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.
    assert b.set_message_interval(1, 1, 32, 0.02)["param2"] == 20000
    assert b.takeoff(1, 1, 10.0)["param7"] == 10.0
    mode = b.set_mode(1, 1, 4)
    assert (mode["command"], mode["param1"], mode["param2"]) == (176, 1, 4)
    hb = b.heartbeat()
    assert (hb["type"], hb["autopilot"]) == (6, 8)  # a GCS, no autopilot
    assert b.position_setpoint(1, 1, 0, (1.0, 2.0, -3.0))["type_mask"] == 3576
    # Position with the velocity as its feed-forward: acceleration, yaw and yaw
    # rate ignored (64|128|256|1024|2048), as ArduCopter's pos-vel-accel branch takes it.
    posvel = b.posvel_setpoint(1, 1, 0, (1.0, 2.0, -3.0), (0.5, -0.25, 0.125))
    assert posvel["type_mask"] == 3520 == 64 | 128 | 256 | 1024 | 2048
    assert (posvel["x"], posvel["vx"], posvel["vy"], posvel["vz"]) == (1.0, 0.5, -0.25, 0.125)
    assert (posvel["afx"], posvel["afy"], posvel["afz"]) == (0.0, 0.0, 0.0)


def test_origin_offset_flat_earth() -> None:
    ref = GeoOrigin(-35.363261, 149.165230, 584.0)
    # Measured on SITL: homes 5 m apart east give origins 5.01 m apart.
    dlon = 5.0 / (6378137.0 * np.cos(np.radians(ref.lat_deg))) * 180 / np.pi
    east = GeoOrigin(ref.lat_deg, ref.lon_deg + dlon, 584.0)
    np.testing.assert_allclose(origin_offset_m(east, ref), [5.0, 0.0, 0.0], atol=1e-9)
    north_up = GeoOrigin(ref.lat_deg + 1e-4, ref.lon_deg, 590.0)
    np.testing.assert_allclose(
        origin_offset_m(north_up, ref), [0.0, np.radians(1e-4) * 6378137.0, 6.0], atol=1e-9
    )


def test_two_origins_see_one_mission_point_alike() -> None:
    point = np.array([3.0, -2.0, 7.5])  # mission frame: x east, y north, z up
    offsets = np.array([[0.0, 0.0, 0.0], [40.0, -25.0, -3.0]])
    ned = mission_to_ned(point, offsets)  # (2, 3): each vehicle's own NED
    np.testing.assert_allclose(ned[1], [-2.0 + 25.0, 3.0 - 40.0, -(7.5 + 3.0)])
    np.testing.assert_allclose(ned_to_mission(ned, offsets), [point, point])
    # Accelerations carry no offset: a_ned = (a_y, a_x, -a_z).
    np.testing.assert_array_equal(vector_mission_to_ned([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])


def test_one_point_as_floats_is_the_array_form_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    for p, o in rng.normal(0.0, 300.0, (200, 2, 3)):
        assert mission_to_ned_floats(p, o) == tuple(mission_to_ned(p, o).tolist())
        assert vector_mission_to_ned_floats(p) == tuple(vector_mission_to_ned(p).tolist())
