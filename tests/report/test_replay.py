"""``report`` on a log the station annotated reproduces the live record and
summary exactly; a run folder is rebuilt by ``report_command``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from synthetic import LOST, STEPS, mission, write_run

from gcs_swarm.commands import report_command
from gcs_swarm.mavlink.coordinates import GeoOrigin
from gcs_swarm.report import (
    FlightRecord,
    record_from_tlog,
    report_from_tlog,
    summarize_record,
)
from gcs_swarm.report.artefacts import _clean


def _assert_same(a: FlightRecord, b: FlightRecord) -> None:
    for name in ("times_s", "ids", "pos_m", "leader_pos_m", "accel_mps2", "sent", "behaviour",
                 "episode", "correction_mps2"):  # fmt: skip
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.events == b.events
    assert a.telemetry == b.telemetry


def test_annotated_log_gives_back_the_live_record(tmp_path: Path) -> None:
    m = mission()
    live = write_run(tmp_path / "flight.tlog", m)
    replayed = record_from_tlog(tmp_path / "flight.tlog", m)
    _assert_same(live, replayed)
    # And so the same summary, figure for figure.
    assert json.dumps(_clean(summarize_record(live))) == json.dumps(
        _clean({**summarize_record(replayed), "source": "run"})
    )


def test_what_the_summary_says_about_that_run(tmp_path: Path) -> None:
    m = mission()
    write_run(tmp_path / "flight.tlog", m)
    s, _ = report_from_tlog(tmp_path / "flight.tlog", m)
    o = s["overall"]
    assert s["log"]["station_annotations"] and s["log"]["undecodable"] == 0
    assert [(e["action"], e["sysid"]) for e in o["events"] if e["t_s"] > 0] == [
        ("leave", 4), ("join", 4), ("leave", 1), ("leave", 2), ("leave", 3), ("leave", 4)
    ]  # fmt: skip
    assert [(x["event"], x["t_s"]) for x in o["behaviour_switches"]] == [
        ("start", pytest.approx(3.0)), ("end", pytest.approx(5.0))
    ]  # fmt: skip
    assert o["safety"]["interventions"] == 10 and o["safety"]["max_correction_mps2"] == 0.25
    assert o["telemetry"]["lost"] == len(LOST)
    assert s["vehicles"]["2"]["telemetry"]["lost"] == 2
    # The spike at step 210: |a| = |(0.4, -0.02625, 2)| for vehicle 4 (float32).
    assert o["peak_accel_at_s"] == pytest.approx(4.2) and o["peak_accel_vehicle"] == 4
    assert o["peak_accel_mps2"] == pytest.approx(np.hypot(np.hypot(0.4, 0.02625), 2.0), rel=1e-6)
    # Setpoints: vehicle 4 was out for 2 s, which is not a gap; 50 Hz.
    sp = s["vehicles"]["4"]["setpoints"]
    assert sp["sent"] == STEPS - 100 and sp["largest_gap_s"] == pytest.approx(0.02)
    # The path crosses the box's region: negative clearance is reported.
    assert o["min_clearance_m"] < 0.0


def test_first_vehicle_origin_when_the_mission_has_none(tmp_path: Path) -> None:
    # A log flown against a real first vehicle: the mission origin is that
    # vehicle's GPS_GLOBAL_ORIGIN; positions then shift by its offset.
    m = mission()
    live = write_run(tmp_path / "flight.tlog", m)
    geo = m.origin_geo()
    assert geo is not None
    import dataclasses

    real = dataclasses.replace(m.vehicles[0], link="udpin:0.0.0.0:14550", autopilot="ardupilot")
    m2 = dataclasses.replace(m, vehicles=(real, *m.vehicles[1:]))
    assert m2.origin_geo() is None
    rec = record_from_tlog(tmp_path / "flight.tlog", m2)
    from gcs_swarm.mavlink.coordinates import origin_offset_m
    from gcs_swarm.mission import geodetic_at

    home = geodetic_at(geo, (0.0, 1.0, -20.0))
    snapped = GeoOrigin.from_mavlink(round(home.lat * 1e7), round(home.lon * 1e7),
                                    round(home.alt * 1e3))  # fmt: skip
    shift = origin_offset_m(snapped, GeoOrigin(geo.lat, geo.lon, geo.alt))
    # Flat earth about a reference 1 m further north: offsets of ~15 m move by
    # ~1e-6 m (cos(lat) and the metres per degree change with the reference).
    np.testing.assert_allclose(rec.pos_m, live.pos_m - shift, atol=1e-5)


def _run_folder(path: Path) -> Path:
    """A run folder at ``path``: the synthetic run's log and its mission."""
    m = mission()
    path.mkdir()
    write_run(path / "flight.tlog", m)
    shutil.copyfile(m.source, path / "mission.yaml")
    return path


def test_report_command_on_a_run_folder_and_on_a_bare_tlog(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = _run_folder(tmp_path / "20250101-120000-scenario-3")
    # The copied mission has the filter off: the command reads the folder's copy.
    assert report_command(folder) == 0
    out = capsys.readouterr().out
    assert "summary written to" in out and "picture written to" in out
    data = json.loads((folder / "summary.json").read_text())
    assert data["source"] == "tlog" and data["overall"]["vehicles_final"] == [1, 2, 3, 4]
    assert (folder / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # A bare .tlog elsewhere, with --mission.
    other = tmp_path / "elsewhere" / "flight-7.tlog"
    other.parent.mkdir()
    shutil.copyfile(folder / "flight.tlog", other)
    assert report_command(other, mission_path=str(folder / "mission.yaml")) == 0
    assert (other.parent / "flight-7-summary.json").is_file()
    assert (other.parent / "flight-7.png").is_file()


def test_report_command_errors_are_one_line(tmp_path: Path) -> None:
    from gcs_swarm.errors import SwarmError

    with pytest.raises(SwarmError, match="no such telemetry log"):
        report_command(tmp_path / "nothing.tlog", mission_path=str(tmp_path / "m.yaml"))
    (tmp_path / "x.tlog").write_bytes(b"")
    with pytest.raises(SwarmError, match="--mission"):
        report_command(tmp_path / "x.tlog")


def test_report_on_a_run_folder_writes_beside_the_runs_own_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # issue 15, item 13: the run's own summary.json and report.png are kept
    folder = _run_folder(tmp_path / "run")
    (folder / "summary.json").write_text('{"outcome": "completed"}')
    (folder / "report.png").write_bytes(b"the run's own")
    assert report_command(folder) == 0
    assert report_command(folder) == 0
    assert (folder / "summary.json").read_text() == '{"outcome": "completed"}'
    assert (folder / "report.png").read_bytes() == b"the run's own"
    for n in (1, 2):
        assert json.loads((folder / f"summary-{n}.json").read_text())["source"] == "tlog"
        assert (folder / f"report-{n}.png").read_bytes()[:4] == b"\x89PNG"
    assert f"summary written to {folder / 'summary-2.json'}" in capsys.readouterr().out
    assert report_command(folder, force=True) == 0  # --force: overwrite
    assert json.loads((folder / "summary.json").read_text())["source"] == "tlog"


def test_a_px4_offboard_command_does_not_end_its_flight_but_hold_does() -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    from gcs_swarm.report.replay import _ends_flight

    def mode(main: float, sub: float) -> object:
        return mav.MAVLink_command_long_message(1, 1, 176, 0, 1, main, sub, 0, 0, 0, 0)

    # PX4: OFFBOARD (6, 0) is the fly mode; Hold (4, 3) and AUTO.LAND (4, 6) end.
    assert not _ends_flight(mode(6, 0), px4=True)
    assert _ends_flight(mode(4, 3), px4=True) and _ends_flight(mode(4, 6), px4=True)
    # ArduCopter: p2 = 4 is GUIDED, 6 is RTL (the same numbers, other meanings).
    assert not _ends_flight(mode(4, 0)) and _ends_flight(mode(6, 0))
