"""Issue 7 end to end: a real ``run_mission`` on the real emulator (lockstep,
UDP on 127.0.0.1) writes its run folder; pymavlink's own reader finds every
frame the station counted in the ``.tlog``; ``gcs-swarm report`` on that
folder reproduces the live summary figure for figure; the picture has its
panels.

Scenario 3 (a moving tetrahedron meets a box) for 30 s of mission time: the
avoidance episode starts at about 16 s, so the log holds behaviour switches.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import math
from collections import Counter
from functools import cache
from pathlib import Path
from typing import Any

import pytest

from gcs_swarm.cli import main
from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.report import RunFolder, report_from_tlog
from gcs_swarm.runtime import RunSummary, run_mission

MISSION = Path(__file__).resolve().parents[2] / "config" / "missions" / "scenario3_obstacle.yaml"
FLY_S = 30.0

# Keys only the live run can know (wall time, link counters) or that say
# where the record came from; everything else must agree.
LIVE_ONLY = {"outcome", "wall_time_s", "links", "source", "log", "startup", "station"}


def _mission() -> Mission:
    m = load_mission(MISSION)
    return dataclasses.replace(
        m,
        settings=dataclasses.replace(m.settings, duration=FLY_S),
        emulator=dataclasses.replace(m.emulator, mode="lockstep"),
    )


@dataclasses.dataclass(frozen=True)
class Flown:
    summary: RunSummary
    folder: RunFolder
    status: list[str]


@cache
def _flown(base: str) -> Flown:
    folders: list[RunFolder] = []
    status: list[str] = []

    async def fly() -> RunSummary:
        async with asyncio.timeout(120):
            return await run_mission(_mission(), sim_airborne=True, end_timeout_s=5.0,
                                     log_dir=base, on_folder=folders.append,
                                     on_status=status.append)  # fmt: skip

    summary = asyncio.run(fly())
    return Flown(summary, folders[0], status)


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> Flown:
    return _flown(str(tmp_path_factory.mktemp("runs")))


def test_run_folder_records_the_vehicle_parameters(flown: Flown) -> None:
    # Sim vehicles: nothing read or set on them but the station's own two.
    record = json.loads(flown.folder.vehicle_params.read_text())
    assert [v["sysid"] for v in record["vehicles"]] == [1, 2, 3, 4]
    for v in record["vehicles"]:
        assert v["envelope_source"] == "mission" and v["unanswered"] == []
        params = {p["name"]: p for p in v["params"]}
        assert set(params) == {"GUID_TIMEOUT", "WP_YAW_BEHAVIOR"}
        assert params["GUID_TIMEOUT"]["old"] is None  # not read: not restored
        assert (params["GUID_TIMEOUT"]["readback"], params["GUID_TIMEOUT"]["restored"]) == (
            0.5, None
        )  # fmt: skip


def test_run_folder_holds_log_mission_summary_and_picture(flown: Flown) -> None:
    f = flown.folder
    assert f.path.name.endswith("scenario-3-moving-tetrahedron-meets-a-box")
    assert f.mission.read_text() == MISSION.read_text()
    assert f.picture.stat().st_size > 10_000
    live = json.loads(f.summary.read_text())
    assert live["outcome"] == "completed"
    assert live["overall"]["vehicles_final"] == [1, 2, 3, 4]
    assert live["overall"]["avoidance_episodes"] >= 1
    assert len(live["overall"]["behaviour_switches"]) >= 1


def test_live_status_shows_the_figures_as_they_evolve(flown: Flown) -> None:
    flying = [line for line in flown.status if "1:flying/GUIDED" in line]
    assert flying, flown.status
    for line in flying:
        # Control rate in vehicle time: the mission's 50 Hz, lockstep or not
        # (the first line has no earlier one to take a rate from).
        assert " 50.0 Hz" in line or line is flying[0], line
        assert "sep " in line and "peak |a|" in line
    # The mission has a box: the minimum clearance so far is shown.
    assert any("min clearance" in line for line in flying)


def test_pymavlink_reads_every_counted_frame(flown: Flown) -> None:
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(flown.folder.tlog))
    seen: Counter[str] = Counter()
    accel_setpoints = 0
    while (msg := conn.recv_match()) is not None:
        assert msg.get_type() != "BAD_DATA"
        if msg.get_srcSystem() == 255 and msg.get_srcComponent() == 155:
            seen["note"] += 1  # the station's annotations (DEBUG_VECT), never sent
            assert msg.get_type() == "DEBUG_VECT"
        elif msg.get_srcSystem() == 255:
            seen["out"] += 1
            if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED" and msg.type_mask == 3135:
                accel_setpoints += 1
        else:
            seen["in"] += 1
    conn.close()
    live = json.loads(flown.folder.summary.read_text())
    # Counts match the station's own counters exactly: every frame sent (the
    # links' counter) and every message received (the recorder's counter).
    assert seen["out"] == flown.summary.messages_sent == live["links"]["messages_sent"]
    assert seen["in"] == live["overall"]["telemetry"]["received"]
    # Every formation setpoint is there; the rest are the ending's zero commands.
    formation = sum(v["setpoints"]["sent"] for v in live["vehicles"].values())
    assert formation >= FLY_S * 50 * 4 * 0.99  # 4 vehicles at 50 Hz, less the first step
    assert formation <= accel_setpoints
    assert seen["note"] > FLY_S * 50  # one LEADER per step at least


def _same(a: Any, b: Any, path: str = "") -> list[str]:
    """Where two JSON values differ (floats to 1e-9 relative: the replay does
    the same arithmetic on the same bytes)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}/{k}: missing" for k in set(a) ^ set(b)]
        for k in set(a) & set(b):
            out += _same(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} vs {len(b)} items"]
        return [
            d
            for i, (x, y) in enumerate(zip(a, b, strict=True))
            for d in _same(x, y, f"{path}[{i}]")
        ]
    if isinstance(a, float) and isinstance(b, float):
        return [] if math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12) else [f"{path}: {a} vs {b}"]
    return [] if a == b else [f"{path}: {a!r} vs {b!r}"]


def test_report_command_reproduces_the_live_summary(
    flown: Flown, capsys: pytest.CaptureFixture[str]
) -> None:
    live = json.loads(flown.folder.summary.read_text())
    replayed, _ = report_from_tlog(flown.folder.tlog, load_mission(flown.folder.mission))
    assert replayed["log"]["station_annotations"] is True
    assert replayed["log"]["undecodable"] == 0 and replayed["log"]["damaged_bytes"] == 0
    strip = lambda d: {k: v for k, v in d.items() if k not in LIVE_ONLY}  # noqa: E731
    assert _same(strip(live), strip(json.loads(json.dumps(replayed)))) == []

    # The command itself, on the folder: rewrites summary.json and report.png.
    flown.folder.summary.unlink()
    flown.folder.picture.unlink()
    assert main(["report", str(flown.folder.path)]) == 0
    out = capsys.readouterr().out
    assert str(flown.folder.summary) in out and str(flown.folder.picture) in out
    rebuilt = json.loads(flown.folder.summary.read_text())
    assert _same(strip(live), strip(rebuilt)) == []
    assert flown.folder.picture.stat().st_size > 10_000


def test_report_of_a_missing_log_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["report", str(tmp_path / "nope.tlog")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope.tlog" in err
