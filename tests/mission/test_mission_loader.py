"""Unit tests of the loader: whole-file problems, defaults, YAML corner
cases, limits on what one file may cost, origins, and that no input gives
anything but a Mission or a MissionError."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import gcs_swarm.mission as mission_pkg
from gcs_swarm.commands import check_command
from gcs_swarm.control.params import ExpressionForce, LawConfig
from gcs_swarm.errors import MissionError
from gcs_swarm.mission import (
    DEFAULT_SIM_HOME,
    GeoPoint,
    enu_offset_m,
    geodetic_at,
    load_mission,
    parse_mission,
)
from gcs_swarm.mission.context import MAX_PER_KIND
from gcs_swarm.mission.loader import MAX_FILE_BYTES, MAX_PROBLEMS

TWO = "vehicles:\n  - {sysid: 1, start: [2, 1, 2]}\n  - {sysid: 2, start: [-1, -1, -1]}\n"
EXAMPLE = Path(__file__).resolve().parents[2] / "config" / "missions" / "scenario2_join.yaml"


def problems(text: str) -> list[str]:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    return str(info.value).splitlines()


def test_exported_names_exist() -> None:
    for name in mission_pkg.__all__:
        assert hasattr(mission_pkg, name), name


def test_missing_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "nope.yaml"
    assert check_command(str(path)) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err == f"{path}:1: (file): cannot read the file: No such file or directory\n"


def test_a_directory_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert check_command(str(tmp_path)) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"{tmp_path}:1: (file): cannot read the file: ")


def test_an_oversized_file_is_refused_unread(tmp_path: Path) -> None:
    path = tmp_path / "big.yaml"
    path.write_bytes(b"#" * (MAX_FILE_BYTES + 1))
    with pytest.raises(MissionError, match=r"big\.yaml:1: \(file\): .* too large"):
        load_mission(path)


def test_defaults_are_the_dataclass_defaults() -> None:
    m = parse_mission(TWO, "m.yaml", name="two")
    assert m.law == LawConfig()
    assert m.settings.name == "two"
    assert all(v.q == LawConfig().gains.q_default and v.autopilot == "sim" for v in m.vehicles)


def test_command_attempts_reach_the_station_and_default_to_its_own() -> None:
    from gcs_swarm.mavlink.states import ProtocolConfig
    from gcs_swarm.runtime.run import station_config

    assert parse_mission(TWO).settings.startup.command_attempts == ProtocolConfig.command_attempts
    m = parse_mission("mission: {startup: {command_attempts: 20}}\n" + TWO)
    links = {1: "sim", 2: "sim"}
    assert station_config(m, links).protocol_config().command_attempts == 20
    assert problems("mission: {startup: {command_attempts: 0}}\n" + TWO) == [
        "m.yaml:1: mission.startup.command_attempts: expected an integer 1..100, got 0"
    ]


def test_handshakes_per_network_reach_the_station_and_default_to_no_bound() -> None:
    from gcs_swarm.runtime.run import station_config

    links = {1: "sim", 2: "sim"}
    assert station_config(parse_mission(TWO), links).handshakes_per_network is None
    m = parse_mission("mission: {startup: {handshakes_per_network: 16}}\n" + TWO)
    assert station_config(m, links).handshakes_per_network == 16
    assert parse_mission("mission: {startup: {handshakes_per_network: null}}\n" + TWO) == (
        parse_mission(TWO)
    )
    for bad, shown in (("0", "0"), ("255", "255"), ("1.5", "1.5"), ("two", '"two"')):
        assert problems(f"mission: {{startup: {{handshakes_per_network: {bad}}}}}\n" + TWO) == [
            "m.yaml:1: mission.startup.handshakes_per_network: expected an integer 1..254 "
            f"or null, got {shown}"
        ]


def test_vehicle_charge_defaults_to_gains_q() -> None:
    m = parse_mission("gains: {q: 3}\n" + TWO + "  - {sysid: 3, start: [5, 5, 5], q: 7}\n")
    assert [v.q for v in m.vehicles] == [3, 3, 7]


def test_exponent_without_a_dot_is_a_number_but_a_quoted_number_is_not() -> None:
    m = parse_mission("gains: {k_s: 2e-9}\n" + TWO)
    assert m.law.gains.k_s == 2e-9
    assert problems('gains: {k_s: "2"}\n' + TWO) == [
        'm.yaml:1: gains.k_s: expected a number > 0 and <= 1000000, got "2"'
    ]


def test_integers_are_accepted_where_numbers_are_but_not_the_reverse() -> None:
    assert parse_mission("mission: {rate: 20}\n" + TWO).settings.rate == 20.0
    assert problems("vehicles:\n  - {sysid: 2.0, start: [0, 0, 0]}\n") == [
        "m.yaml:2: vehicles[0].sysid:"
        " expected an integer 1..254 (255 is the ground station), got 2.0"
    ]


def test_mixed_numbers_and_expressions_become_expressions() -> None:
    m = parse_mission(TWO + "leader:\n  force: [1.5, t, -2]\n")
    assert m.law.leader.force == ExpressionForce(("1.5", "t", "-2.0"))


def test_events_replay_in_time_order_and_a_vehicle_may_leave_and_rejoin() -> None:
    text = TWO + "events:\n  - {t: 20, join: 2}\n  - {t: 10, leave: 2}\n"
    m = parse_mission(text)
    assert [(e.t, e.action) for e in m.events] == [(10, "leave"), (20, "join")]
    # the same events the other way round: a join for a flying vehicle, then fine
    bad = TWO + "events:\n  - {t: 10, join: 2}\n  - {t: 20, leave: 2}\n"
    assert problems(bad) == [
        "m.yaml:5: events[0].join: vehicle 2 is already in the formation at t = 10 s"
        " (it flies from the start: mark it reserve: true)"
    ]


def test_the_number_of_printed_problems_is_capped() -> None:
    # 150 different kinds (one unknown key each): the first MAX_PROBLEMS and a count
    n = MAX_PROBLEMS + 50
    text = "".join(f"key{i}: 1\n" for i in range(n)) + TWO
    lines = problems(text)
    assert len(lines) == MAX_PROBLEMS + 1
    assert lines[-1] == "m.yaml:1: (file): 50 more problems not shown"


def test_problems_of_one_kind_are_capped_at_20_and_counted() -> None:
    # issue 15 item 6: 150 vehicles with sysid 0 are one kind, vehicles[].sysid
    n = 150
    text = "vehicles:\n" + "".join(f"  - {{sysid: 0, start: [{i}, 0, 0]}}\n" for i in range(n))
    lines = problems(text)
    assert len(lines) == MAX_PER_KIND + 1 == 21
    assert lines[0].startswith("m.yaml:2: vehicles[0].sysid: expected an integer")
    assert lines[19].startswith("m.yaml:21: vehicles[19].sysid: ")
    assert lines[-1] == (
        "m.yaml:22: vehicles[].sysid: 130 more problems of this kind not shown (the first 20 are)"
    )


def test_aliases_cannot_make_a_small_file_expensive() -> None:
    # 11 000 aliases of one 10-node vehicle: a 77 kB file that expands past
    # the cap of 100 000 nodes
    text = "vehicles:\n  - &v {sysid: 1, link: sim, autopilot: sim, start: [0, 0, 0], q: 1,"
    text += " reserve: false}\n" + "  - *v\n" * 11_000
    lines = problems(text)
    assert len(lines) == 1 and "expands to more than" in lines[0]


def test_origin_of_sim_missions_and_homes() -> None:
    m = parse_mission(TWO)
    origin = m.origin_geo()
    assert origin is not None
    assert origin.alt == pytest.approx(DEFAULT_SIM_HOME.alt + 20.0, abs=1e-9)
    explicit = parse_mission(
        "mission:\n  origin: {lat: 47.0, lon: 8.0, alt: 500}\nemulator: {ground: -10}\n"
        + TWO
        + "  - {sysid: 3, start: [0, 0, 5], origin: [30, 40, -12]}\n"
    )
    home = explicit.sim_origins(explicit.origin_geo())  # type: ignore[arg-type]
    assert enu_offset_m(GeoPoint(47.0, 8.0, 500.0), home[2]) == pytest.approx((5, 0, -10), abs=1e-6)
    assert enu_offset_m(GeoPoint(47.0, 8.0, 500.0), home[3]) == pytest.approx(
        (30, 40, -12), abs=1e-6
    )


def test_geodetic_round_trip() -> None:
    # flat earth both ways: exact inverse to float rounding (1e-9 m)
    o = GeoPoint(-35.363261, 149.165230, 584.0)
    p = geodetic_at(o, (123.4, -56.7, 8.9))
    assert enu_offset_m(o, p) == pytest.approx((123.4, -56.7, 8.9), abs=1e-9)


def test_real_first_vehicle_leaves_the_origin_to_the_station() -> None:
    m = parse_mission("vehicles:\n  - {sysid: 1, link: 'udpin:0.0.0.0:14550', start: [0, 0, 5]}\n")
    assert m.origin_geo() is None and m.vehicles[0].origin is None


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=300))
def test_any_text_gives_a_mission_or_a_mission_error(text: str) -> None:
    try:
        parse_mission(text, "m.yaml")
    except MissionError as err:
        assert all(line.startswith("m.yaml:") for line in str(err).splitlines())


_SCALARS = st.one_of(
    st.integers(-1000, 1000),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.none(),
    st.text(max_size=12),
    st.lists(st.integers(-5, 5), max_size=4),
)


_DOC = yaml.safe_load(EXAMPLE.read_text())


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_any_value_anywhere_in_a_real_mission_gives_a_mission_or_a_mission_error(
    data: st.DataObject,
) -> None:
    doc = copy.deepcopy(_DOC)
    leaves: list[tuple[object, object]] = []

    def walk(node: object) -> None:
        items = node.items() if isinstance(node, dict) else enumerate(node)  # type: ignore[call-overload]
        for key, value in list(items):
            if isinstance(value, dict | list):
                walk(value)
            leaves.append((node, key))

    walk(doc)
    parent, key = data.draw(st.sampled_from(leaves))
    parent[key] = data.draw(_SCALARS)  # type: ignore[index]
    try:
        parse_mission(yaml.safe_dump(doc), "m.yaml")
    except MissionError as err:
        assert all(line.startswith("m.yaml:") for line in str(err).splitlines())


REAL = (
    "mission: {origin: {lat: -35.363261, lon: 149.165230, alt: 584}}\n"
    "vehicles:\n"
    "  - {sysid: 1, start: [2, 1, 12], link: 'udpin:127.0.0.1:14550', autopilot: ardupilot}\n"
    "  - {sysid: 2, start: [-1, -1, 11], link: 'udpin:127.0.0.1:14560', autopilot: ardupilot}\n"
)


@pytest.mark.parametrize(
    ("text", "enabled", "heading"),
    [
        (TWO, False, "velocity"),  # all sim: the paper exactly
        (REAL, True, "desired"),  # a real autopilot: the filter on
        ("limits: {safety: {enabled: null}}\n" + REAL, True, "desired"),
        ("limits: {safety: {enabled: false}}\n" + REAL, False, "velocity"),
        ("limits: {safety: {enabled: true}}\n" + TWO, True, "desired"),
        ("obstacles: {heading: velocity}\nlimits: {safety: {enabled: true}}\n" + TWO, True,
         "velocity"),
    ],
)  # fmt: skip
def test_safety_filter_defaults_on_for_real_autopilots(
    text: str, enabled: bool, heading: str
) -> None:
    law = parse_mission(text, "m.yaml").law
    assert law.safety.enabled is enabled
    assert law.avoidance.heading == heading


def test_delay_compensation_needs_real_time_for_sim_vehicles() -> None:
    ok = "mission: {delay_compensation: true}\n" + TWO
    assert parse_mission(ok, "m.yaml").settings.delay_compensation is True
    lockstep = "mission: {delay_compensation: true}\nemulator: {mode: lockstep}\n" + TWO
    assert parse_mission(lockstep, "m.yaml").settings.delay_compensation  # ignored there
    fast = "mission: {delay_compensation: true}\nemulator: {speedup: 5}\n" + TWO
    assert problems(fast) == [
        "m.yaml:1: mission.delay_compensation: needs real time: emulator.speedup 1, got 5"
    ]


def test_setpoint_defaults_by_autopilot_and_can_be_chosen() -> None:
    m = parse_mission(
        "mission:\n  origin: {lat: 47.0, lon: 8.0, alt: 500}\n"
        "vehicles:\n"
        "  - {sysid: 1, start: [0, 0, 5], link: 'udpin:127.0.0.1:14550'}\n"
        "  - {sysid: 2, start: [3, 0, 5], link: 'udpout:127.0.0.1:18571', autopilot: px4}\n"
        "  - {sysid: 3, start: [0, 3, 5], autopilot: px4}\n"
        "  - {sysid: 4, start: [3, 3, 5], link: 'udpout:127.0.0.1:18573', autopilot: px4,"
        " setpoint: acceleration}\n"
        "  - {sysid: 5, start: [6, 3, 5], setpoint: velocity+acceleration}\n"
    )
    got = {v.sysid: v.setpoint for v in m.vehicles}
    assert got == {
        1: "acceleration",  # ArduCopter: measured with the acceleration alone
        2: "velocity+acceleration",  # PX4 (docs/setpoints.md)
        3: "velocity+acceleration",  # the emulator's PX4
        4: "acceleration",
        5: "velocity+acceleration",
    }


def test_a_bad_setpoint_names_the_line_and_the_choices() -> None:
    lines = problems("vehicles:\n  - {sysid: 1, start: [0, 0, 5],\n     setpoint: velocity}\n")
    assert len(lines) == 1, lines
    assert lines[0].startswith("m.yaml:3: vehicles[0].setpoint: "), lines
    assert "acceleration" in lines[0] and "velocity+acceleration" in lines[0]
