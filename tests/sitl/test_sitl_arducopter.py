"""The station against real ArduCopter 4.5.6 SITL (issue 14, item 6).

Skipped, with the reason, unless ``GCS_SWARM_ARDUCOPTER`` names an ArduCopter
SITL binary (``docs/sitl.md``); CI has none. Every test starts its own fresh
instances (default parameters, fresh EEPROM) on 127.0.0.1 and stops them by
PID. Each one flies in real time (speed-up 1: SITL's EKF needs 20-40 s to be
ready, then the mission itself), so the whole file takes about 30 minutes.

What each asserts is what the issue's "Figures to reach" ask, on SITL, and the
same mission flown by the emulator from the state SITL's formation started in
is set beside it (``sitl_flights.emulator_replay_twin``, ``compare``): time to
form within 10 % (the octahedron's: within 10 % of the range of an ensemble
of twins, ``_assert_twin_agrees``), final radii within 1 %, minimum
separation within 0.2 m; how closely the formation's RMS error against the
law's equilibrium follows SITL's is reported. The figures are written as JSON
(``GCS_SWARM_SITL_REPORT``) and copied into docs/sitl.md by hand.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gcs_swarm.control.params import Limits
from gcs_swarm.mission import Mission, load_mission
from gcs_swarm.offline import simulate_mission
from gcs_swarm.runtime import run_mission
from tests.sitl.mavmonitor import Monitor
from tests.sitl.sitl_flights import (
    MISSIONS,
    ROOT,
    compare,
    convergence_times,
    curve_difference,
    emulator_replay_twin,
    error_curve,
    fly_acting,
    formation_series,
    gcs_swarm_run,
    load,
    rms_position_difference,
    summary_of,
    trajectories,
    with_links,
    write_figures,
)
from tests.sitl.sitl_harness import binary_or_skip, sitl_swarm

pytestmark = [pytest.mark.sitl, pytest.mark.slow]

LAND, RTL = 9, 6


def _fly_in_process(mission: Mission, log_dir: Path, **kw: Any) -> tuple[dict[str, Any], Path]:
    """Fly ``mission`` with ``run_mission`` (links as the mission says); its
    summary.json and run folder."""
    holder: list[Any] = []
    asyncio.run(run_mission(mission, log_dir=log_dir, picture=False, on_folder=holder.append, **kw))
    return summary_of(holder[0].path), holder[0].path


def _twin_figures(
    mission: Mission, sitl_folder: Path, tmp: Path, *, ensemble: int = 0
) -> dict[str, Any]:
    """Fly the emulator twin of the SITL run (``emulator_replay_twin``: from the
    state SITL's formation started in) and compare the two; with ``ensemble``,
    that many more twins from starts moved by ``ENSEMBLE_JITTER_M`` (seeds 1,
    2, ...), whose times to form are reported with the replay twin's."""
    twin = emulator_replay_twin(mission, sitl_folder)
    emu_summary, emu_folder = _fly_in_process(twin, tmp)
    out = compare(summary_of(sitl_folder), emu_summary)
    if ensemble:
        times = [out["emulator"]["time_to_form_s"]]
        for seed in range(1, ensemble + 1):
            jittered = emulator_replay_twin(
                mission, sitl_folder, jitter_m=ENSEMBLE_JITTER_M, seed=seed
            )
            s, _ = _fly_in_process(jittered, tmp / f"jitter{seed}")
            times.append(s["overall"]["time_to_form_s"])
        out["ensemble_time_to_form_s"] = times
    # Reported, not asserted: a formation on a sphere is free to turn about its
    # leader, so two flights that form the same shape may hold it turned.
    out["rms_position_difference_m"] = rms_position_difference(
        trajectories(sitl_folder, mission), trajectories(emu_folder, twin)
    )
    law = _law_errors(mission)
    sitl_series = formation_series(sitl_folder, mission)
    emu_series = formation_series(emu_folder, twin)
    out["error_band_entry_s"] = {
        "sitl": convergence_times(*sitl_series, law, BANDS),
        "emulator": convergence_times(*emu_series, law, BANDS),
    }
    sitl_curve, emu_curve = error_curve(*sitl_series, law), error_curve(*emu_series, law)
    out["error_curve_difference"] = curve_difference(sitl_curve, emu_curve)
    out["error_curve_difference_first_30s"] = curve_difference(sitl_curve, emu_curve, until_s=30.0)
    return out


ENSEMBLE_JITTER_M = 0.01
"""[m] per axis, how far the octahedron's ensemble twins start from SITL's
recorded starts: SITL's vehicles began its formation still moving (up to
0.18 m/s; the replay twin's start at rest), and this mission's time to form
moves by tens of percent for 1 cm there (docs/sitl.md, 2026-12-07)."""


BANDS = (0.05, 0.02, 0.01)
"""RMS relative errors of the formation against the law's equilibrium whose
entry times are reported (where the error falls slowly they move a lot for a
small difference, so they are not asserted)."""


def _law_errors(mission: Mission) -> np.ndarray:
    """Every radius and pairwise distance of the law's equilibrium for the
    mission's vehicles, in ``formation_series`` order (the ideal point mass,
    no limits: the time scale keeps the equilibrium)."""
    law = mission.law
    ideal = dataclasses.replace(
        mission,
        law=dataclasses.replace(
            law,
            gains=dataclasses.replace(law.gains, time_scale=1.0),
            limits=Limits(),
            safety=dataclasses.replace(law.safety, enabled=False),
        ),
        settings=dataclasses.replace(mission.settings, duration=150.0),
    )
    f = simulate_mission(ideal).result.figures()
    return np.concatenate([f.final_radii_m, f.final_distances_m])


def _assert_twin_agrees(fig: dict[str, Any]) -> None:
    """The twin predicts SITL: the time to form (the summary's, every radius
    and distance within 1 % of its last value) within 10 %, final radii within
    1 %, minimum separation within 0.2 m. With an ensemble (the octahedron,
    whose slow phase passes near a saddle of the law, so that 1 cm at the
    start moves its time to form by a third: docs/sitl.md, 2026-12-07) SITL's
    time to form is to lie within 10 % of the twins' range instead. How
    closely the twin's error curve follows SITL's (``error_curve_difference``)
    is reported, not asserted: SITL's own band entries on the octahedron
    spread by 40 % between runs from similar starts (docs/sitl.md,
    2026-12-03, later)."""
    s, e = fig["sitl"], fig["emulator"]
    ensemble = [t for t in fig.get("ensemble_time_to_form_s", ()) if t is not None]
    if s["time_to_form_s"] is not None and ensemble:
        lo, hi = min(ensemble), max(ensemble)
        assert 0.9 * lo <= s["time_to_form_s"] <= 1.1 * hi, fig
    elif s["time_to_form_s"] is not None and e["time_to_form_s"] is not None:
        assert abs(e["time_to_form_s"] - s["time_to_form_s"]) <= 0.10 * s["time_to_form_s"], fig
    for k in ("radius_min_m", "radius_max_m"):
        assert abs(e[k] - s[k]) <= 0.01 * s[k], fig
    assert abs(e["min_separation_m"] - s["min_separation_m"]) <= 0.2, fig


def test_readme_procedure_works_first_try_three_times(tmp_path: Path) -> None:
    """Fresh SITL, then the README's command as written: 3 of 3 runs complete."""
    binary_or_skip()
    mission_path = MISSIONS / "sitl_arducopter.yaml"
    runs: list[dict[str, Any]] = []
    for k in range(3):
        with sitl_swarm(4, tmp_path / f"sitl{k}"):
            rc, out, folder = gcs_swarm_run(mission_path, tmp_path / f"runs{k}", timeout_s=900)
        assert rc == 0, f"run {k + 1}: exit {rc}\n{out[-4000:]}"
        assert folder is not None
        s = summary_of(folder)
        assert s["outcome"] == "completed", out[-4000:]
        o = s["overall"]
        runs.append({
            "run": k + 1, "outcome": s["outcome"], "time_to_form_s": o["time_to_form_s"],
            "radius_m": o["final_radius_m"], "min_separation_m": o["min_separation_m"],
            "rate_hz_min": o["setpoints"]["rate_hz_min"],
            "largest_gap_s": o["setpoints"]["largest_gap_s"], "folder": str(folder),
        })  # fmt: skip
    fig = _twin_figures(load("sitl_arducopter.yaml"), Path(runs[-1]["folder"]), tmp_path / "emu")
    write_figures(tmp_path, "sitl_readme", {"runs": runs, "emulator_vs_sitl": fig})
    _assert_twin_agrees(fig)


def test_octahedron_in_the_envelope(tmp_path: Path) -> None:
    """Six vehicles, gains the product recommends for ArduCopter's default
    envelope: radii within 1 % of the law's equilibrium, edges and diagonals
    within 2 %, separation never below the configured value."""
    binary_or_skip()
    mission = load("sitl_octahedron.yaml")
    # The law's equilibrium: the same gains on the ideal point mass, no limits,
    # time_scale 1 (the time scale keeps the equilibrium: docs/vehicle-envelope.md).
    r_eq = float(np.mean(_law_errors(mission)[: len(mission.vehicles)]))
    with sitl_swarm(6, tmp_path / "sitl", first=30) as swarm:
        # instances 30-35 (ports 6060-6110), so it can run beside the others
        mission = with_links(mission, swarm.links_from_one())
        s, folder = _fly_in_process(mission, tmp_path / "runs")
    o = s["overall"]
    radii = [v["final_radius_m"] for v in s["vehicles"].values()]
    d = sorted(o["final_pairwise_distances_m"])
    edge, diag = r_eq * math.sqrt(2.0), 2.0 * r_eq
    figures = {
        "equilibrium_radius_m": r_eq, "radii_m": radii, "edges_m": d[:12], "diagonals_m": d[12:],
        "min_separation_m": o["min_separation_m"], "time_to_form_s": o["time_to_form_s"],
        "separation_configured_m": mission.law.safety.separation,
    }  # fmt: skip
    fig = _twin_figures(mission, folder, tmp_path / "emu", ensemble=3)
    figures["emulator_vs_sitl"] = fig
    write_figures(tmp_path, "sitl_octahedron", figures)
    assert s["outcome"] == "completed"
    np.testing.assert_allclose(radii, r_eq, rtol=0.01)
    np.testing.assert_allclose(d[:12], edge, rtol=0.02)
    np.testing.assert_allclose(d[12:], diag, rtol=0.02)
    assert o["min_separation_m"] >= mission.law.safety.separation
    _assert_twin_agrees(fig)


def test_scenario3_safety_filter_holds_on_the_vehicle(tmp_path: Path) -> None:
    """Scenario 3 at a safe height, filter on: clearance >= the margin and
    separation >= the configured value at every control step."""
    binary_or_skip()
    with sitl_swarm(4, tmp_path / "sitl", first=20) as swarm:
        # instances 20-23 (ports 5960-5990), so it can run beside the others
        mission = with_links(load("sitl_scenario3.yaml"), swarm.links_from_one())
        s, folder = _fly_in_process(mission, tmp_path / "runs")
    o = s["overall"]
    fig = _twin_figures(mission, folder, tmp_path / "emu")
    write_figures(tmp_path, "sitl_scenario3", {
        "min_clearance_m": o["min_clearance_m"], "clearance_margin_m": mission.law.safety.clearance,
        "min_separation_m": o["min_separation_m"],
        "separation_configured_m": mission.law.safety.separation, "emulator_vs_sitl": fig,
    })  # fmt: skip
    assert s["outcome"] == "completed"
    assert o["min_clearance_m"] >= mission.law.safety.clearance
    assert o["min_separation_m"] >= mission.law.safety.separation


def test_killed_vehicle_leaves_and_the_rest_reform(tmp_path: Path) -> None:
    """SIGKILL one SITL instance in flight: it leaves, the other three re-form
    (equal radii within 1 %), keeping the separation from the column where
    it was (Eq. K1: the station cannot tell a dead vehicle from a lost one)."""
    binary_or_skip()
    with sitl_swarm(4, tmp_path / "sitl", first=10) as swarm:
        # instances 10-13 (ports 5860-5890), so it can run beside the others
        mission = with_links(load("sitl_arducopter.yaml"), swarm.links_from_one())

        async def kill() -> None:
            swarm.kill(3)

        s = asyncio.run(fly_acting(mission, tmp_path / "runs", 60.0, kill))
    v = s["vehicles"]
    left = v["4"]["left_at_s"]
    radii = [v[k]["final_radius_m"] for k in ("1", "2", "3")]
    final = s["overall"]["vehicles_final"]
    kept = s["keep_out"]
    figures = {"left_at_s": left, "radii_m": radii, "final": final, "keep_out": kept}
    write_figures(tmp_path, "sitl_vehicle_killed", figures)
    assert s["overall"]["vehicles_final"] == [1, 2, 3]
    # Its column was kept: never closer than the separation (6 m), the filter's
    # guarantee on the vehicles' reports.
    assert kept["columns"] == 1
    assert kept["closest_m"] >= mission.law.safety.separation, kept
    np.testing.assert_allclose(radii, np.mean(radii), rtol=0.01)


def test_paused_vehicle_rejoins_the_moving_formation(tmp_path: Path) -> None:
    """SIGSTOP one SITL instance for 3 s at 20 s of formation flight (its link
    quiet, shorter than FS_GCS_TIMEOUT), then SIGCONT: it leaves after the
    stale timeout, is taken over in the air when heard again, flies to its
    rejoin point beside the leader (3 m/s on the square until about 70 s)
    with the leader's velocity as the feed-forward and rejoins while the
    formation still moves; four at the end, equal radii within 1 %,
    separation kept."""
    binary_or_skip()
    with sitl_swarm(4, tmp_path / "sitl", first=30) as swarm:
        # instances 30-33 (ports 6060-6090), so it can run beside the others
        mission = with_links(load("sitl_arducopter.yaml"), swarm.links_from_one())

        async def pause() -> None:
            swarm.pause(3, True)
            await asyncio.sleep(3.0)
            swarm.pause(3, False)

        s = asyncio.run(fly_acting(mission, tmp_path / "runs", 20.0, pause))
    v = s["vehicles"]
    radii = [v[k]["final_radius_m"] for k in ("1", "2", "3", "4")]
    left, joins = v["4"]["left_at_s"], v["4"]["joined_at_s"]
    write_figures(tmp_path, "sitl_vehicle_paused", {
        "left_at_s": left, "joined_at_s": joins, "radii_m": radii,
        "min_separation_m": s["overall"]["min_separation_m"],
        "final": s["overall"]["vehicles_final"],
    })  # fmt: skip
    # left_at_s ends with the mission's end (everyone leaves then); before it,
    # one leave (the pause) and a join after it.
    end = mission.settings.duration
    lost = [t for t in left if t < end]
    assert len(lost) == 1 and lost[0] < joins[-1] < end, (left, joins)
    # Back while the formation moves: the leader reaches the square's last
    # corner at about 70 s. Measured 17.75 s after the leave (21.1 -> 38.85 s);
    # the code that asked for rest at the slot itself rejoined at 70.5 s, 49.4 s
    # after it. Bound 30 s.
    assert joins[-1] - lost[0] < 30.0, (left, joins)
    assert s["overall"]["vehicles_final"] == [1, 2, 3, 4]
    np.testing.assert_allclose(radii, np.mean(radii), rtol=0.01)
    assert s["overall"]["min_separation_m"] >= mission.law.safety.separation


def test_killed_station_leaves_every_vehicle_landing(tmp_path: Path) -> None:
    """SIGKILL the station in flight: every vehicle is in LAND or RTL within
    FS_GCS_TIMEOUT + 1 s (the failsafe the station set on each vehicle)."""
    binary_or_skip()
    mission_path = MISSIONS / "sitl_arducopter.yaml"
    timeout_s = load("sitl_arducopter.yaml").settings.failsafe.timeout
    with sitl_swarm(4, tmp_path / "sitl"):
        exe = Path(sys.executable).with_name("gcs-swarm")
        # Not a terminal: the status line comes as a log line every 5 s,
        # "t=  20.04s | ...", in mission time from the formation start.
        proc = subprocess.Popen(
            [str(exe), "run", str(mission_path), "--log-dir", str(tmp_path / "runs")],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
            stdin=subprocess.DEVNULL,
        )  # fmt: skip
        monitors: list[Monitor] = []
        try:
            monitors.extend(Monitor(i) for i in range(4))  # closed below if one fails
            assert proc.stdout is not None
            deadline = time.monotonic() + 300
            for line in proc.stdout:
                if line.startswith("t=") and float(line[2:].split("s", 1)[0]) >= 20.0:
                    break
                assert time.monotonic() < deadline, "no formation after 300 s"
            else:
                pytest.fail(f"station ended before 20 s of formation: exit {proc.wait()}")
            killed_at = time.monotonic()
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
            time.sleep(timeout_s + 4.0)
            after = [m.first_mode_after(killed_at, {LAND, RTL}) for m in monitors]
        finally:
            for m in monitors:
                m.close()
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
            if proc.stdout is not None:
                proc.stdout.close()
    delays = [None if a is None else a - killed_at for a in after]
    write_figures(
        tmp_path,
        "sitl_station_killed",
        {"fs_gcs_timeout_s": timeout_s, "mode_change_after_kill_s": delays},
    )
    assert all(d is not None and d <= timeout_s + 1.0 for d in delays), delays


def _handshakes(tlog: Path) -> dict[int, tuple[float, float]]:
    """Each vehicle's handshake as the station's own frames in its tlog show
    it: from its first SET_MESSAGE_INTERVAL (the handshake's first command)
    to its first DO_SET_MODE (the first command after it) [s, tlog time]."""
    from pymavlink import mavutil

    first: dict[tuple[int, int], float] = {}
    log = mavutil.mavlink_connection(str(tlog))
    while (msg := log.recv_match(type="COMMAND_LONG")) is not None:
        if msg.get_srcSystem() == 255 and msg.command in (511, 176):
            first.setdefault((msg.target_system, msg.command), msg._timestamp)
    log.close()
    return {s: (t, first[(s, 176)]) for (s, c), t in first.items() if c == 511}


def test_start_up_in_waves_two_at_a_time(tmp_path: Path) -> None:
    """``sitl_arducopter.yaml`` with ``mission.startup.handshakes_per_network:
    2`` (and 30 s of formation) on four fresh instances: the station's own
    frames (its tlog) show at most two vehicles in their handshake at any
    moment and two at some moment, and the run completes."""
    binary_or_skip()
    text = (MISSIONS / "sitl_arducopter.yaml").read_text()
    text = text.replace("  duration: 150 ", "  duration: 30 ", 1)
    text = text.replace(
        "    guid_timeout: 0.5\n", "    guid_timeout: 0.5\n    handshakes_per_network: 2\n", 1
    )
    assert "handshakes_per_network: 2" in text and "duration: 30 " in text
    path = tmp_path / "sitl_waves.yaml"
    path.write_text(text)
    with sitl_swarm(4, tmp_path / "sitl"):
        rc, out, folder = gcs_swarm_run(path, tmp_path / "runs", timeout_s=600)
    assert rc == 0, out[-4000:]
    assert folder is not None
    s = summary_of(folder)
    spans = _handshakes(folder / "flight.tlog")
    t0 = min(a for a, _ in spans.values())
    edges = sorted([(a, 1) for a, _ in spans.values()] + [(b, -1) for _, b in spans.values()])
    inside = most = 0
    for _, step in edges:  # an end before a start at the same instant
        inside += step
        most = max(most, inside)
    figures = {
        "handshakes_s": {str(k): (a - t0, b - t0) for k, (a, b) in sorted(spans.items())},
        "most_at_once": most, "outcome": s["outcome"], "startup": s["startup"],
        "time_to_form_s": s["overall"]["time_to_form_s"], "folder": str(folder),
    }  # fmt: skip
    write_figures(tmp_path, "sitl_waves", figures)
    assert sorted(spans) == [1, 2, 3, 4]
    assert most == 2
    assert s["outcome"] == "completed", out[-4000:]


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-s", "-v"]))


def test_two_networks_with_the_same_ids_fly_one_tetrahedron_on_two_shards(tmp_path: Path) -> None:
    """``config/missions/sitl_arducopter_networks.yaml`` as its comment says
    to fly it, ``gcs-swarm run FILE --shards 2``, on instances 0-1 (blue,
    system ids 1-2) and 2-3 (red, system ids 1-2 again), homes 5 m apart:
    it completes, every radius's mean over the last 20 s is within 1 % of
    the law's equilibrium (as the mixed tetrahedron's), the separation never
    falls below the configured 6 m, the red shard flew in blue:1's frame,
    and the run folder holds both networks' logs and the controller's notes."""
    from gcs_swarm.report.artefacts import rebuild_report
    from tests.sitl.sitl_flights import held_radii
    from tests.sitl.test_sitl_px4 import _equilibrium_radius

    binary_or_skip()
    name = "sitl_arducopter_networks.yaml"
    mission = load(name)
    r_eq = _equilibrium_radius(mission)
    with sitl_swarm(2, tmp_path / "blue"), sitl_swarm(2, tmp_path / "red", first=2):
        rc, out, folder = gcs_swarm_run(MISSIONS / name, tmp_path / "runs", timeout_s=900,
                                        extra=("--shards", "2"))  # fmt: skip
    assert rc == 0, out[-4000:]
    assert folder is not None
    s = summary_of(folder)
    o = s["overall"]
    window = held_radii(s, r_eq)
    figures = {
        "equilibrium_radius_m": r_eq, **window,
        "time_to_form_s": o["time_to_form_s"], "min_separation_m": o["min_separation_m"],
        "separation_configured_m": mission.law.safety.separation,
        "setpoint_rate_hz_min": o["setpoints"]["rate_hz_min"],
        "largest_gap_s": o["setpoints"]["largest_gap_s"],
        "telemetry_loss_percent": o["telemetry"]["loss_percent"], "folder": str(folder),
    }  # fmt: skip
    write_figures(tmp_path, "sitl_two_networks_two_shards", figures)
    assert s["outcome"] == "completed"
    assert sorted(s["vehicles"]) == ["blue:1", "blue:2", "red:1", "red:2"]
    means = window["radii_last_20s_mean_m"]
    np.testing.assert_allclose(means, r_eq, rtol=0.01)
    assert o["min_separation_m"] >= mission.law.safety.separation
    names = {p.name for p in folder.iterdir()}
    assert {"controller.tlog", "flight-blue.tlog", "flight-red.tlog", "summary.json"} <= names
    # One frame for both shards: the logs, replayed with each vehicle's own
    # EKF origin against blue:1's, give the radii the controller flew (a red
    # shard in red:1's frame would be 10 m off). 1 mm: the notes' float32.
    rebuilt, _, _ = rebuild_report(folder)
    for label, v in s["vehicles"].items():
        assert rebuilt["vehicles"][label]["final_radius_m"] == pytest.approx(
            v["final_radius_m"], abs=1e-3), label  # fmt: skip


@pytest.mark.parametrize("shards", [None, 2, 1], ids=["one process", "two shards", "one shard"])
def test_two_networks_stepped_each_on_its_own_reports_fly_one_tetrahedron(
    tmp_path: Path, shards: int | None
) -> None:
    """The same four instances and mission with ``mission.step: network``, one
    station process, or ``--shards 2`` (the controller steps each shard's
    batch as it comes), or ``--shards 1`` (one shard of both networks,
    whose batches carry the rows that changed since the controller's last
    answer: ``shard_wire.changes``): each network is stepped when its two
    instances' reports are in (their phases are their own), the other
    network's at their latest. It completes, every radius's mean over the
    last 20 s is within 1 % of the law's equilibrium, the separation never
    falls below the configured 6 m, and there were more control steps than
    periods (steps of one network)."""
    from tests.sitl.sitl_flights import held_radii
    from tests.sitl.test_sitl_px4 import _equilibrium_radius

    binary_or_skip()
    text = (MISSIONS / "sitl_arducopter_networks.yaml").read_text()
    assert "  stale_timeout: 1.0" in text
    text = text.replace("  stale_timeout: 1.0", "  step: network\n  stale_timeout: 1.0", 1)
    path = tmp_path / "sitl_arducopter_networks_step.yaml"
    path.write_text(text)
    mission = load_mission(path)
    assert mission.settings.step == "network"
    r_eq = _equilibrium_radius(mission)
    with sitl_swarm(2, tmp_path / "blue"), sitl_swarm(2, tmp_path / "red", first=2):
        extra = () if shards is None else ("--shards", str(shards))
        rc, out, folder = gcs_swarm_run(path, tmp_path / "runs", timeout_s=900, extra=extra)
    assert rc == 0, out[-4000:]
    assert folder is not None
    s = summary_of(folder)
    o = s["overall"]
    window = held_radii(s, r_eq)
    periods = mission.settings.duration * mission.settings.rate
    figures = {
        "equilibrium_radius_m": r_eq, **window,
        "time_to_form_s": o["time_to_form_s"], "min_separation_m": o["min_separation_m"],
        "separation_configured_m": mission.law.safety.separation,
        "control_steps": s["control_steps"], "periods": periods,
        "setpoint_rate_hz_min": o["setpoints"]["rate_hz_min"],
        "largest_gap_s": o["setpoints"]["largest_gap_s"], "folder": str(folder),
    }  # fmt: skip
    name = (
        "sitl_two_networks_step_per_network" + {None: "", 2: "_two_shards", 1: "_one_shard"}[shards]
    )
    write_figures(tmp_path, name, figures)
    assert s["outcome"] == "completed"
    np.testing.assert_allclose(window["radii_last_20s_mean_m"], r_eq, rtol=0.01)
    assert o["min_separation_m"] >= mission.law.safety.separation
    assert s["control_steps"] > 1.2 * periods
