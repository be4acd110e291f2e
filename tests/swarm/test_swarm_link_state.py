"""One link's policy without sockets (``gcs_swarm.swarm.LinkState``): bytes
in with their peer and a hand-set arrival time, datagrams out."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as dialect

from gcs_swarm.mavlink import builders as b
from gcs_swarm.mavlink.inbound import LocalPositionNed
from gcs_swarm.mavlink.states import Phase, ProtocolConfig
from gcs_swarm.mavlink.telemetry_table import TelemetryTable
from gcs_swarm.mavlink.vehicle import VehicleProtocol
from gcs_swarm.swarm import MESSAGE_QUEUE_SIZE, REBIND_S, LinkState
from mavwire import MAX_DATAGRAM_BYTES
from mavwire.signing import mavlink

A, B, C = ("10.0.0.2", 5760), ("10.0.0.3", 5770), ("10.6.6.6", 4242)
KEY = bytes(range(32))


def _lpn(sysid: int, t_ms: int = 1, mav: object | None = None) -> bytes:
    m = mav if mav is not None else dialect.MAVLink(None, sysid, 1)
    return bytes(m.local_position_ned_encode(t_ms, 1.0, 2.0, 3.0, 0, 0, 0).pack(m))  # type: ignore[attr-defined]


def _state(**kw: object) -> tuple[LinkState, list[str]]:
    notices: list[str] = []
    kw.setdefault("sysids", [1, 2])
    st = LinkState("udpin:0.0.0.0:14550", unix_clock=lambda: 1.7e9, on_notice=notices.append,
                   **kw)  # type: ignore[arg-type]  # fmt: skip
    return st, notices


def _parse(data: bytes) -> list[object]:
    return dialect.MAVLink(None, 255, 190).parse_buffer(data) or []


def test_a_system_id_stays_on_its_first_address_and_others_are_refused() -> None:
    st, notices = _state()
    items = st.receive(_lpn(1) + _lpn(2), A, 0.0, datagram=True)
    assert [m.get_srcSystem() for m in items] == [1, 2]  # type: ignore[attr-defined]
    for k in range(5):
        assert st.receive(_lpn(1, 2 + k), C, 1.0 + k, datagram=True) == []
    assert st.stats.spoofed == 5 and st.rebinds_refused == {1: 5}
    assert len(notices) == 1 and "from 10.6.6.6:4242 refused" in notices[0]
    assert st.peer_count == 1 and st.route(1) == A  # the forger got nothing
    st.send(b.heartbeat())
    assert [peer for peer, _, _ in st.datagrams_to_send()] == [A]


def _flying(table: TelemetryTable, sysid: int) -> VehicleProtocol:
    """A READY vehicle (its last report at 1 ms) put into FLYING with ``table``."""
    vp = VehicleProtocol(sysid, ProtocolConfig(), goto_m=(0.0, 0.0, 0.0))
    vp.phase = Phase.READY
    vp.offset_m = np.zeros(3)
    vp.position = LocalPositionNed(sysid, 1, 1, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0)
    vp.begin_flying(0.0, table)
    return vp


def test_a_flying_vehicles_reports_go_into_the_table_in_the_datagrams_order() -> None:
    """With a telemetry table: a FLYING vehicle's newer report from its own
    address is written into its row and not handed on; a report of a
    vehicle not flying, a stale one, and one after another message of the
    same vehicle in the datagram come out as pymavlink's messages, in order;
    a forged one is refused before the table sees it."""
    table = TelemetryTable([1, 2])
    st, _ = _state(telemetry=table)
    vp = _flying(table, 1)
    items = st.receive(_lpn(1, 20) + _lpn(2, 20) + _lpn(1, 20), A, 0.5, datagram=True)
    assert st.positions_written == 1 and table.taken == 1
    assert [(m.get_srcSystem(), m.time_boot_ms) for m in items] == [(2, 20), (1, 20)]  # type: ignore[attr-defined]
    assert vp.position == LocalPositionNed(1, 1, 20, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0)
    assert vp.position_at == 0.5 and table.arrival_s[0] == 0.5
    assert table.take_fresh() == {1: 20} and table.fresh_count == 0
    mav = dialect.MAVLink(None, 1, 1)
    hb = bytes(mav.heartbeat_encode(2, 3, 0, 4, 4).pack(mav))
    items = st.receive(hb + _lpn(1, 40, mav), A, 0.6, datagram=True)
    assert st.positions_written == 0  # after its HEARTBEAT: a message, in order
    assert [m.get_type() for m in items] == ["HEARTBEAT", "LOCAL_POSITION_NED"]  # type: ignore[attr-defined]
    assert st.receive(_lpn(1, 60), C, 0.7, datagram=True) == []  # forged: refused
    assert st.positions_written == 0 and st.stats.spoofed == 1
    assert vp.position is not None and vp.position.time_boot_ms == 20


def test_strangers_keep_no_state_and_draw_no_reply() -> None:
    st, _ = _state()
    for port in range(100):
        st.receive(b"\xfd\x09garbage" + bytes(port), ("10.9.9.9", port), 0.0, datagram=True)
        st.receive(_lpn(42), ("10.9.9.9", port), 0.0, datagram=True)  # an id not served
    assert st.peer_count == 0 and st.stats.bad_packets > 0 and not st.peer_added
    assert not st.send(b.heartbeat()) and st.datagrams_to_send() == []


def test_setpoints_newest_wins_and_messages_are_a_bounded_fifo() -> None:
    st, _ = _state()
    for k in range(MESSAGE_QUEUE_SIZE + 3):  # queued while nobody is connected
        st.send(b.param_request_read(1, 1, f"P{k}"), 1)
    st.send(b.accel_setpoint(1, 1, 10, (1.0, 0.0, 0.0)), 1)
    st.send(b.accel_setpoint(1, 1, 20, (2.0, 0.0, 0.0)), 1)
    assert st.stats.messages_dropped == 3 and st.stats.setpoints_dropped == 1
    assert st.datagrams_to_send() == []  # no peer yet: the queues wait
    st.receive(_lpn(1), A, 0.0, datagram=True)
    assert st.peer_added
    msgs = [m for _, data, _ in st.datagrams_to_send() for m in _parse(data)]
    names = [m.param_id for m in msgs if m.get_type() == "PARAM_REQUEST_READ"]  # type: ignore[attr-defined]
    assert names == [f"P{k}" for k in range(3, MESSAGE_QUEUE_SIZE + 3)]  # the oldest went
    sp = [m for m in msgs if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert [(m.time_boot_ms, m.afx) for m in sp] == [(20, 2.0)]  # type: ignore[attr-defined]


def test_a_steps_setpoints_are_joined_into_datagrams_within_the_limit() -> None:
    n = 60
    st, _ = _state(sysids=range(1, n + 1))
    for s in range(1, n + 1):
        st.receive(_lpn(s), A, 0.0, datagram=True)
    accel = np.arange(3 * n, dtype=np.float64).reshape(n, 3) * 0.01
    since = [0.5 + s for s in range(n)]
    writes = st.accel_setpoints(list(range(1, n + 1)), [1] * n, [7] * n, accel, since)
    assert len(writes) > 1 and all(len(d) <= MAX_DATAGRAM_BYTES for _, d, _ in writes)
    assert {p for p, _, _ in writes} == {A}
    assert [t for _, _, ts in writes for t in ts] == since  # latency per frame, in order
    msgs = [m for _, d, _ in writes for m in _parse(d)]
    assert [m.target_system for m in msgs] == list(range(1, n + 1))  # type: ignore[attr-defined]
    np.testing.assert_allclose([m.afy for m in msgs], accel[:, 1], rtol=1e-6)  # type: ignore[attr-defined]
    assert st.stats.sent == n


def test_a_signed_vehicle_silent_for_rebind_s_may_move_to_a_new_address() -> None:
    st, notices = _state(signing_key=KEY, allow_rebind=True)
    mav = mavlink(1, 1, KEY, unix_s=1.7e9)
    assert len(st.receive(_lpn(1, 1, mav), A, 0.0, datagram=True)) == 1
    assert st.receive(_lpn(1, 2, mav), B, REBIND_S - 0.5, datagram=True) == []  # too soon
    assert st.rebinds_refused == {1: 1}
    assert len(st.receive(_lpn(1, 3, mav), B, REBIND_S + 0.1, datagram=True)) == 1
    assert st.route(1) == B and st.peer_count == 1  # A speaks for nobody: its state went
    assert "vehicle 1 rebound from 10.0.0.2:5760 to 10.0.0.3:5770" in notices[-1]
    unsigned, _ = _state(allow_rebind=True)  # without signing: never handed over
    unsigned.receive(_lpn(1), A, 0.0, datagram=True)
    assert unsigned.receive(_lpn(1, 2), B, 100.0, datagram=True) == []


def test_a_steps_setpoints_follow_a_vehicle_that_moved_to_a_new_address() -> None:
    """The rows each peer gets are kept from one step to the next
    (``LinkState._peer_rows``); a rebinding drops them, so the next step's
    setpoint goes to the vehicle's new address, and a new peer's first frame
    too."""
    st, _ = _state(signing_key=KEY, allow_rebind=True)
    mav1, mav2 = mavlink(1, 1, KEY, unix_s=1.7e9), mavlink(2, 1, KEY, unix_s=1.7e9)
    st.receive(_lpn(1, 1, mav1) + _lpn(2, 1, mav2), A, 0.0, datagram=True)
    accel = np.zeros((2, 3))

    def step() -> dict[object, list[int]]:
        writes = st.accel_setpoints([1, 2], [1, 1], [7, 7], accel, [None, None])
        return {p: [m.target_system for m in _parse(d)] for p, d, _ in writes}  # type: ignore[attr-defined]

    assert step() == {A: [1, 2]}
    assert step() == {A: [1, 2]}  # the same rows again
    assert len(st.receive(_lpn(2, 2, mav2), B, REBIND_S + 0.1, datagram=True)) == 1
    assert st.route(2) == B
    assert step() == {A: [1], B: [2]}


def test_a_later_networks_link_speaks_system_ids_on_the_wire_and_keys_above() -> None:
    """Issue 19: a link of network 1 (``base`` 256) serves keys 257, 258 as
    system ids 1, 2: a flying vehicle's report goes into key 257's row, and
    what the station sends to keys goes out to the system ids."""
    table = TelemetryTable([1, 257])  # key 1 is network 0's vehicle 1, on another link
    st, _ = _state(telemetry=table, sysids=[257, 258], base=256)
    _flying(table, 257)
    items = st.receive(_lpn(1, 20) + _lpn(2, 20), A, 0.5, datagram=True)
    assert st.positions_written == 1 and table.take_fresh() == {257: 20}
    assert [m.get_srcSystem() for m in items] == [2]  # on the wire's id: the core adds the base
    st.send(b.arm(258, 1), 258)
    writes = st.accel_setpoints([257], [1], [20], np.zeros((1, 3)), [None])
    sent = [m for _, data, _ in writes for m in _parse(data)]
    assert [(m.get_type(), m.target_system) for m in sent] == [  # type: ignore[attr-defined]
        ("COMMAND_LONG", 2), ("SET_POSITION_TARGET_LOCAL_NED", 1)
    ]  # fmt: skip
