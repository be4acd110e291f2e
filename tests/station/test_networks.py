"""Multi-network missions in lockstep (issue 19 item 1): two networks with
overlapping system ids fly one formation over real UDP on 127.0.0.1, each
network on an emulator of its own, and give the radii of the same vehicles
flown on one network.

The six vehicles are Example 1's (config/missions/example1_octahedron.yaml);
network ``blue`` has system ids 1-3 and ``red`` 1-3 again. Keys (network
index * 256 + sysid) sort the two flights' vehicles in the same order
(1, 2, 3, 257, 258, 259 against 1..6), so the law sums in the same order,
and each emulated vehicle's physics depends on its own setpoints only.
"""

from __future__ import annotations

import asyncio
import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from gcs_swarm.mission import Mission, parse_mission
from gcs_swarm.report import rebuild_report
from gcs_swarm.runtime import RunSummary, run_mission

_STARTS = ["[2, 1, 2]", "[-1, -1, -1]", "[3, 4, 2]", "[4, 2, 2]", "[3, 3, 3]", "[-2, -2, -2]"]
_HEAD = """\
mission: {{name: {name}, duration: {duration}, rate: 50, end: hold}}
emulator: {{dynamics: ideal, mode: lockstep, spawn: air}}
leader: {{start: [0, 0, 0], force: [0, 0, 0]}}
"""
DURATION_S = 20.0
"""Formation flight [s]: the radii are within 1 % of the octahedron's 2.48418 m
by then (the comparison is between two flights, not with the equilibrium)."""


def _one_network(duration: float = DURATION_S) -> Mission:
    rows = "".join(f"  - {{sysid: {i + 1}, start: {s}}}\n" for i, s in enumerate(_STARTS))
    return parse_mission(_HEAD.format(name="one-network", duration=duration) + "vehicles:\n" + rows)


def _two_networks(duration: float = DURATION_S) -> Mission:
    text = _HEAD.format(name="two-networks", duration=duration) + "networks:\n"
    for name, starts in (("blue", _STARTS[:3]), ("red", _STARTS[3:])):
        text += f"  - name: {name}\n    vehicles:\n"
        text += "".join(f"      - {{sysid: {i + 1}, start: {s}}}\n" for i, s in enumerate(starts))
    return parse_mission(text)


async def _fly(mission: Mission, log_dir: Path) -> RunSummary:
    async with asyncio.timeout(120):
        return await run_mission(mission, log_dir=log_dir, picture=False, end_timeout_s=5.0)


@cache
def _flights(tmp: Path) -> tuple[RunSummary, RunSummary, Path]:
    one = asyncio.run(_fly(_one_network(), tmp / "one"))
    two = asyncio.run(_fly(_two_networks(), tmp / "two"))
    (folder,) = (tmp / "two").iterdir()
    return one, two, folder


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunSummary, RunSummary, Path]:
    return _flights(tmp_path_factory.mktemp("networks"))


def test_two_networks_with_overlapping_sysids_fly_one_formation(
    flights: tuple[RunSummary, RunSummary, Path],
) -> None:
    one, two, _ = flights
    assert one.outcome == two.outcome == "completed"
    assert [v.label for v in two.vehicles] == ["blue:1", "blue:2", "blue:3",
                                               "red:1", "red:2", "red:3"]  # fmt: skip
    assert [v.sysid for v in two.vehicles] == [1, 2, 3, 257, 258, 259]  # keys
    # Lockstep is deterministic and the two flights compute the same numbers in
    # the same order: the radii agree to 1e-9 m (measured: equal bit for bit;
    # 1e-9 leaves room for nothing but rounding).
    r1 = np.array([v.radius_m for v in one.vehicles], dtype=float)
    r2 = np.array([v.radius_m for v in two.vehicles], dtype=float)
    np.testing.assert_allclose(r2, r1, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r2, 2.48418, atol=0.025)  # forming: within 1 % at 20 s
    p1 = np.array([v.position_m for v in one.vehicles], dtype=float)
    p2 = np.array([v.position_m for v in two.vehicles], dtype=float)
    np.testing.assert_allclose(p2, p1, rtol=0, atol=1e-9)
    assert (two.setpoints_dropped, two.bad_packets, two.unknown_sysid_messages) == (0, 0, 0)
    assert two.mission_time_s == pytest.approx(one.mission_time_s, abs=1e-9)


def test_each_network_has_its_own_tlog_that_pymavlink_reads(
    flights: tuple[RunSummary, RunSummary, Path],
) -> None:
    _, _, folder = flights
    assert sorted(p.name for p in folder.glob("*.tlog")) == ["flight-blue.tlog", "flight-red.tlog"]
    for name in ("blue", "red"):
        log = mavutil.mavlink_connection(str(folder / f"flight-{name}.tlog"))
        senders: set[int] = set()
        targets: set[int] = set()
        while (msg := log.recv_match()) is not None:
            senders.add(msg.get_srcSystem())
            if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                targets.add(msg.target_system)
        log.close()
        # One system-id space per file: the vehicles 1-3 and the station (255).
        assert senders == {1, 2, 3, 255} and targets == {1, 2, 3}


def test_summary_and_report_tell_vehicles_by_network_and_sysid(
    flights: tuple[RunSummary, RunSummary, Path],
) -> None:
    _, two, folder = flights
    summary = json.loads((folder / "summary.json").read_text())
    assert list(summary["vehicles"]) == ["blue:1", "blue:2", "blue:3", "red:1", "red:2", "red:3"]
    assert summary["vehicles"]["red:2"]["network"] == "red"
    assert summary["vehicles"]["red:2"]["sysid"] == 2
    assert summary["networks"]["red"] == {"index": 1, "tlog": "flight-red.tlog",
                                          "sysids": [1, 2, 3]}  # fmt: skip
    assert summary["overall"]["vehicles_final"][3:] == ["red:1", "red:2", "red:3"]
    # gcs-swarm report rebuilds it from the two tlogs and the mission alone.
    rebuilt, path, _ = rebuild_report(folder)
    assert path.name == "summary-1.json"
    radii = {k: v["final_radius_m"] for k, v in rebuilt["vehicles"].items()}
    live = {v.label: v.radius_m for v in two.vehicles}
    assert set(radii) == set(live)
    np.testing.assert_allclose([radii[k] for k in live], list(live.values()), atol=1e-6)
    assert rebuilt["log"]["station_annotations"] and rebuilt["log"]["undecodable"] == 0


def test_replay_view_labels_the_vehicles(flights: tuple[RunSummary, RunSummary, Path]) -> None:
    from gcs_swarm.report.artefacts import flown_run
    from gcs_swarm.report.replay import record_from_tlog
    from gcs_swarm.view import RecordFrames, scene_of

    _, _, folder = flights
    tlog, mission = flown_run(folder)
    record = record_from_tlog(tlog, mission)
    labels = {v.key: mission.label(v.key) for v in mission.vehicles}
    frames = RecordFrames(record, scene_of(mission.law, name=mission.settings.name), labels=labels)
    frame = frames.frame(DURATION_S)
    assert frame["vehicles"]["sysid"] == [1, 2, 3, 257, 258, 259]
    assert frame["vehicles"]["label"] == ["blue:1", "blue:2", "blue:3", "red:1", "red:2", "red:3"]
