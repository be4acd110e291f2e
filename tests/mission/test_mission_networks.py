"""Networks in the mission (issue 19 item 1): vehicles grouped in named
networks, each with its own system ids; a vehicle is (network, sysid),
keyed ``network index * 256 + sysid``; every mistake one line
``file:line: key.path: message``; a file without networks is one network
named ``default`` whose keys are the system ids."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import gcs_swarm
from gcs_swarm.errors import MissionError
from gcs_swarm.mission import describe, load_mission, parse_mission
from gcs_swarm.mission.model import DEFAULT_NETWORK, key_label, vehicle_key

MISSIONS = Path(__file__).resolve().parents[2] / "config" / "missions"

HEAD = "mission: {name: nets, duration: 10}\nemulator: {dynamics: ideal}\n"  # lines 1-2


def _problems(text: str) -> list[str]:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    return list(info.value.problems)


def test_two_networks_may_share_system_ids() -> None:
    m = parse_mission(
        HEAD
        + "networks:\n"
        + "  - name: blue\n"
        + "    vehicles:\n"
        + "      - {sysid: 1, start: [2, 1, 2]}\n"
        + "      - {sysid: 2, start: [-1, -1, -1], reserve: true}\n"
        + "  - name: red-2\n"
        + "    vehicles:\n"
        + "      - {sysid: 1, start: [3, 4, 2]}\n"
        + "      - {sysid: 2, start: [4, 2, 2]}\n"
        + "events:\n"
        + "  - {t: 1, join: 2, network: blue}\n"
        + "  - {t: 2, leave: 2, network: red-2}\n"
    )
    assert m.networks == ("blue", "red-2") and m.multi_network
    assert "4 vehicles (sim) on 2 networks" in describe(m)
    assert [(v.network, v.sysid, v.key) for v in m.vehicles] == [
        ("blue", 1, 1), ("blue", 2, 2), ("red-2", 1, 257), ("red-2", 2, 258)
    ]  # fmt: skip
    assert [m.label(v.key) for v in m.vehicles] == ["blue:1", "blue:2", "red-2:1", "red-2:2"]
    assert [(e.action, e.key) for e in m.events] == [("join", 2), ("leave", 258)]
    assert m.vehicle(258).start == (4.0, 2.0, 2.0)
    assert [v.key for v in m.network_vehicles(1)] == [257, 258]
    # Sim homes count every network's vehicles in file order: k * origin_spread east.
    assert [v.origin for v in m.vehicles] == [(k * 5.0, 0.0, -20.0) for k in range(4)]


#: The shipped missions that name no ``networks`` (the shards demos do).
ONE_NETWORK = sorted(
    p for p in MISSIONS.glob("*.yaml") if "networks" not in yaml.safe_load(p.read_text())
)


@pytest.mark.parametrize(
    ("name", "labels"),
    [("example1_networks", ["blue:1", "blue:2", "blue:3", "red:1", "red:2", "red:3"]),
     ("sitl_arducopter_networks", ["blue:1", "blue:2", "red:1", "red:2"])],
)  # fmt: skip
def test_the_shipped_missions_with_networks_are_the_shards_demos(
    name: str, labels: list[str]
) -> None:
    named = {p.stem for p in MISSIONS.glob("*.yaml")} - {p.stem for p in ONE_NETWORK}
    assert named == {"example1_networks", "sitl_arducopter_networks"}
    m = load_mission(MISSIONS / f"{name}.yaml")
    assert m.networks == ("blue", "red") and m.multi_network
    assert [m.label(v.key) for v in m.vehicles] == labels


@pytest.mark.parametrize("path", ONE_NETWORK, ids=lambda p: p.stem)
def test_a_mission_without_networks_is_one_network_keyed_by_sysid(path: Path) -> None:
    m = load_mission(path)
    assert m.networks == (DEFAULT_NETWORK,) and not m.multi_network
    assert all(v.network == DEFAULT_NETWORK and v.key == v.sysid for v in m.vehicles)
    assert all(m.label(v.key) == str(v.sysid) for v in m.vehicles)
    assert all(e.key == e.sysid for e in m.events)


def test_keys_and_labels() -> None:
    assert vehicle_key(0, 7) == 7 and vehicle_key(2, 7) == 519
    assert key_label(7) == "7"
    assert key_label(519, ("a", "b", "c")) == "c:7" and key_label(7, ("a", "b")) == "a:7"


_NETS = (
    "networks:\n"  # line 3
    "  - name: blue\n"  # 4
    "    vehicles:\n"  # 5
    "      - {sysid: 1, start: [2, 1, 2]}\n"  # 6
    "      - {sysid: 2, start: [-1, -1, -1]}\n"  # 7
    "  - name: red\n"  # 8
    "    vehicles:\n"  # 9
    "      - {sysid: 1, start: [3, 4, 2]}\n"  # 10
)


@pytest.mark.parametrize(
    ("text", "want"),
    [
        (  # the same name twice
            _NETS + "  - name: blue\n    vehicles:\n      - {sysid: 9, start: [0, 5, 5]}\n",
            ['m.yaml:11: networks[2].name: duplicate network name "blue" (also networks[0])'],
        ),
        (  # a system id twice within one network (in two networks it is fine)
            _NETS + "      - {sysid: 1, start: [0, 5, 5]}\n",
            [
                "m.yaml:11: networks[1].vehicles[1].sysid: duplicate system id 1"
                " (also networks[1].vehicles[0])"
            ],
        ),
        (  # both ways of listing vehicles
            _NETS + "vehicles:\n  - {sysid: 3, start: [0, 5, 5]}\n",
            ['m.yaml:3: networks: expected either "vehicles" or "networks", got both'],
        ),
        (  # a name that cannot name a file
            _NETS.replace("name: red", "name: red/1"),
            [
                "m.yaml:8: networks[1].name: expected a network name (a letter, then up to 31"
                ' letters, digits, _ or -), got "red/1"'
            ],
        ),
        (  # a network without vehicles
            _NETS + "  - name: green\n    vehicles: []\n",
            [
                "m.yaml:12: networks[2].vehicles: expected a list of vehicles (at least one),"
                " got a list of 0 items"
            ],
        ),
        (  # one link in two networks: the system ids would clash on it
            _NETS.replace(
                "{sysid: 2, start: [-1, -1, -1]}",
                "{sysid: 2, link: 'udpin:127.0.0.1:14550', start: [-1, -1, 1]}",
            ).replace(
                "{sysid: 1, start: [3, 4, 2]}",
                "{sysid: 1, link: 'udpin:127.0.0.1:14550', start: [3, 4, 2]}",
            ),
            [
                "m.yaml:10: networks[1].vehicles[0].link: udpin:127.0.0.1:14550 is network blue's"
                " link (networks[0].vehicles[1]); a link carries one network"
            ],
        ),
        (  # an event must say which vehicle 1 it means
            _NETS + "events:\n  - {t: 1, leave: 1}\n",
            [
                "m.yaml:12: events[0].network: expected the vehicle's network, one of blue, red"
                " (the mission has several)"
            ],
        ),
        (  # and name a network of the file
            _NETS + "events:\n  - {t: 1, leave: 1, network: green}\n",
            [
                'm.yaml:12: events[0].network: no network is named "green"; expected one of'
                " blue, red"
            ],
        ),
        (  # a vehicle the named network does not have
            _NETS + "events:\n  - {t: 1, leave: 2, network: red}\n",
            ["m.yaml:12: events[0].leave: no vehicle has system id 2 in network red"],
        ),
        (  # the same start in two networks is still the same point
            _NETS.replace("[3, 4, 2]", "[2, 1, 2]"),
            [
                "m.yaml:10: networks[1].vehicles[0].start: same start as networks[0].vehicles[0]"
                " [2, 1, 2]; vehicles must start apart"
            ],
        ),
        (  # neither
            "mission: {name: none}\n",
            ['m.yaml:1: (top level): missing required key "vehicles" (or "networks")'],
        ),
    ],
    ids=[
        "duplicate-name",
        "duplicate-sysid",
        "both",
        "bad-name",
        "empty",
        "shared-link",
        "event-no-network",
        "event-unknown-network",
        "event-unknown-vehicle",
        "same-start",
        "neither",
    ],
)
def test_network_mistakes_are_one_line_each(text: str, want: list[str]) -> None:
    assert _problems(HEAD + text if text.startswith("networks") else text) == want


def test_a_mission_flies_more_than_254_vehicles_on_two_networks() -> None:
    """Two networks of 150 vehicles, system ids 1-150 in both, in the
    in-process reference simulator (the law over all 300 at once)."""
    rng = np.random.default_rng(19)
    # 300 starts on a jittered 7 x 7 x 7 grid 2 m apart: apart, not on the leader.
    cells = rng.permutation(7**3)[:300]
    grid = np.stack(np.unravel_index(cells, (7, 7, 7)), axis=1) * 2.0 - 6.0 + 3.0
    starts = grid + rng.uniform(-0.3, 0.3, grid.shape)
    text = "mission: {name: three hundred, duration: 1}\nemulator: {dynamics: ideal}\nnetworks:\n"
    for j, name in enumerate(("north", "south")):
        text += f"  - name: {name}\n    vehicles:\n"
        for i in range(150):
            x, y, z = starts[150 * j + i]
            text += f"      - {{sysid: {i + 1}, start: [{x:.4f}, {y:.4f}, {z:.4f}]}}\n"
    mission = parse_mission(text)
    assert len(mission.vehicles) == 300 and len({v.key for v in mission.vehicles}) == 300
    t0 = time.perf_counter()
    result = gcs_swarm.simulate(mission)
    took = time.perf_counter() - t0
    ids = [int(s) for s in result.result.ids]
    assert ids == [v.key for v in mission.vehicles]  # 1..150, then 257..406
    assert np.isfinite(result.result.pos_m).all()
    assert took < 60.0  # measured 0.6 s (0.5 s of flight) on the 2-core machine
