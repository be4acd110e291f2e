"""The station against real PX4 v1.14 SITL, SIH quadrotors (issue 17, item 6).

Skipped, with the reason, unless ``GCS_SWARM_PX4`` names a PX4 SITL binary
(``docs/sitl.md``, PX4 section). PX4 binds its UDP ports on every address,
so each test re-runs itself inside ``unshare -n`` (a private network
namespace with only loopback: ``px4_harness``) and starts its own fresh
instances there (default parameters), stopped by PID. SIH runs at 1x real
time: the file takes about 15 minutes.

The figures are written as JSON (``GCS_SWARM_SITL_REPORT``, else the test's
tmp folder) and copied into docs/sitl.md by hand.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from gcs_swarm.control.params import ConstantForce, Limits
from gcs_swarm.mission import Mission
from gcs_swarm.offline import simulate_mission
from gcs_swarm.runtime import run_mission
from tests.sitl.px4_harness import (
    Px4Monitor,
    binary_or_skip,
    in_private_namespace_or_rerun,
    px4_swarm,
)
from tests.sitl.sitl_flights import (
    MISSIONS,
    ROOT,
    compare,
    fly_acting,
    formation_series,
    held_radii,
    load,
    summary_of,
    time_to_enter,
    time_to_rms_band,
    wander,
    write_figures,
)

pytestmark = [pytest.mark.px4_sitl, pytest.mark.slow]

LAND = 4 << 16 | 6 << 24
"""PX4 AUTO.LAND's custom_mode (COM_OBL_RC_ACT 4, set by the station for end: land)."""
MISSION = "sitl_px4.yaml"


def _short(mission: Mission, duration_s: float) -> Mission:
    return dataclasses.replace(
        mission, settings=dataclasses.replace(mission.settings, duration=duration_s)
    )


def _fly(mission: Mission, log_dir: Path) -> tuple[dict[str, Any], Path, float | None]:
    """Fly ``mission`` in process; (summary.json, run folder, wall seconds
    from the call to "formation started")."""
    holder: list[Any] = []
    started: list[float] = []
    t0 = time.monotonic()

    class _Formation(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().startswith("formation started"):
                started.append(time.monotonic() - t0)

    handler = _Formation()
    log = logging.getLogger("gcs_swarm")
    log.addHandler(handler)
    level = log.level
    log.setLevel(logging.INFO)
    try:
        asyncio.run(run_mission(mission, log_dir=log_dir, picture=False, on_folder=holder.append))
    finally:
        log.removeHandler(handler)
        log.setLevel(level)
    return summary_of(holder[0].path), holder[0].path, started[0] if started else None


def _emulator_twin(mission: Mission, spacing_m: float = 5.0) -> Mission:
    """The mission on the emulator's PX4 personality, laid out as the SITL
    swarm (homes ``spacing_m`` apart due east), in lockstep."""
    vehicles = tuple(
        dataclasses.replace(v, link="sim", autopilot="px4", origin=(spacing_m * k, 0.0, 0.0))
        for k, v in enumerate(mission.vehicles)
    )
    emu = dataclasses.replace(mission.emulator, mode="lockstep", dynamics="ardupilot-like",
                              ground=0.0, origin_spread=spacing_m, spawn="ground")  # fmt: skip
    return dataclasses.replace(mission, vehicles=vehicles, emulator=emu)


def _equilibrium_radius(mission: Mission) -> float:
    """The law's equilibrium: the same gains on the ideal point mass, no
    limits, no safety filter, time_scale 1."""
    law = mission.law
    ideal = dataclasses.replace(
        mission,
        law=dataclasses.replace(
            law, gains=dataclasses.replace(law.gains, time_scale=1.0), limits=Limits(),
            safety=dataclasses.replace(law.safety, enabled=False),
        ),
        settings=dataclasses.replace(mission.settings, duration=300.0),
    )  # fmt: skip
    return float(np.mean(simulate_mission(ideal).result.figures().final_radii_m))


def test_px4_startup_first_try_three_times(tmp_path: Path, request: pytest.FixtureRequest) -> None:
    """Fresh PX4 SITL x 4, three times: the start-up completes first try each time."""
    binary = binary_or_skip()
    if not in_private_namespace_or_rerun(request.node.nodeid, tmp_path):
        return
    mission = _short(load(MISSION), 10.0)
    runs = []
    for k in range(3):
        with px4_swarm(binary, 4, tmp_path / f"px4{k}"):
            s, folder, formed = _fly(mission, tmp_path / f"runs{k}")
        assert s["outcome"] == "completed", (k, s["outcome"])
        runs.append({"run": k + 1, "outcome": s["outcome"], "formation_started_after_s": formed,
                     "wall_time_s": s["wall_time_s"], "folder": str(folder)})  # fmt: skip
    write_figures(tmp_path, "px4_startup", {"runs": runs})


def test_px4_formation_and_emulator_twin(tmp_path: Path, request: pytest.FixtureRequest) -> None:
    """Four PX4 SITL vehicles fly the tetrahedron: radii against the law's
    equilibrium, separation never below the configured value; the emulator's
    PX4 personality flies the same mission beside it."""
    binary = binary_or_skip()
    if not in_private_namespace_or_rerun(request.node.nodeid, tmp_path):
        return
    mission = load(MISSION)
    r_eq = _equilibrium_radius(mission)
    with px4_swarm(binary, 4, tmp_path / "px4"):
        s, folder, _ = _fly(mission, tmp_path / "runs")
    o = s["overall"]
    radii = [v["final_radius_m"] for v in s["vehicles"].values()]
    # A PX4 in OFFBOARD wanders (0.11-0.30 m std over 20 s measured):
    # the figure is each vehicle's mean radius over the last 20 s (the last sample too).
    window = held_radii(s, r_eq)
    held = window["radii_last_20s_mean_m"]
    twin_mission = _emulator_twin(mission)
    e, e_folder, _ = _fly(twin_mission, tmp_path / "emu")
    twin = compare(s, e)
    # Time to form: a PX4 SIH's position wanders (periods of 13-48 s; a relative
    # std of up to 2.5 % on a distance over the last 20 s), so the summary's "stays
    # within 1 % of the last sample" is never met on SITL. Compared instead: the
    # first time the radii and distances enter a band of twice that wander
    # (at least 1 %) around their held means, the same band on both (docs/sitl.md).
    t_s, series = formation_series(folder, mission)
    band = max(0.01, 2.0 * wander(t_s, series))
    twin["band_relative"] = band
    t_e, series_e = formation_series(e_folder, twin_mission)
    twin["sitl"]["time_to_enter_band_s"] = time_to_enter(t_s, series, band)
    twin["emulator"]["time_to_enter_band_s"] = time_to_enter(t_e, series_e, band)
    # Compared: the formation's RMS error entering the band. Every column entering
    # it is decided by the one vehicle that wanders most (2.82-3.48 s on three
    # SITL runs, a spread beyond the 10 % compared; docs/sitl.md), reported only.
    twin["sitl"]["time_to_rms_band_s"] = time_to_rms_band(t_s, series, band)
    twin["emulator"]["time_to_rms_band_s"] = time_to_rms_band(t_e, series_e, band)
    figures = {
        "equilibrium_radius_m": r_eq, "radii_m": radii,
        "radius_error_percent": [None if r is None else 100 * (r - r_eq) / r_eq for r in radii],
        **window,
        "min_separation_m": o["min_separation_m"],
        "separation_configured_m": mission.law.safety.separation,
        "time_to_form_s": o["time_to_form_s"],
        "setpoint_rate_hz_mean": o["setpoints"]["rate_hz_mean"],
        "telemetry_loss_percent": o["telemetry"]["loss_percent"], "emulator_vs_sitl": twin,
        "folder": str(folder),
    }  # fmt: skip
    write_figures(tmp_path, "px4_formation", figures)
    assert s["outcome"] == "completed"
    assert None not in radii, "a vehicle left the formation (stale telemetry: machine load?)"
    assert o["min_separation_m"] >= mission.law.safety.separation
    # The figures: radii within 1 % of the law's equilibrium; the emulator's
    # PX4 personality within 10 % on the time to form and 1 % on the final radii.
    assert None not in held
    np.testing.assert_allclose(held, r_eq, rtol=0.01)
    t_sitl = twin["sitl"]["time_to_rms_band_s"]
    t_emu = twin["emulator"]["time_to_rms_band_s"]
    assert t_sitl is not None and t_emu is not None
    assert abs(t_emu - t_sitl) <= 0.10 * t_sitl, (t_emu, t_sitl)
    emu_held = [v["final_radius_window_m"]["mean"] for v in e["vehicles"].values()]
    np.testing.assert_allclose(emu_held, held, rtol=0.01)


def _moving(mission: Mission, force_n: float) -> Mission:
    """``mission`` with its leader pushed east by ``force_n`` [N] (Eq. 13:
    it settles at force / (lambda (D + k)) m/s)."""
    leader = dataclasses.replace(mission.law.leader, force=ConstantForce((force_n, 0.0, 0.0)))
    return dataclasses.replace(mission, law=dataclasses.replace(mission.law, leader=leader))


def test_px4_paused_vehicle_rejoins_the_moving_formation(
    tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """The tetrahedron with its leader moving east at 0.75 m/s; one PX4
    SITL SIGSTOPped for 3 s at 25 s of formation flight (its link quiet,
    SIH frozen with it), then SIGCONT: it leaves after the stale timeout,
    is taken over in the air when heard again (OFFBOARD after the
    pre-stream), flies pos-vel setpoints to its rejoin point with the
    leader's velocity as the feed-forward and rejoins while the formation
    moves (what the emulator's PX4 does after a silence:
    tests/swarm/test_swarm_flights.py); four at the end, separation kept.
    Its offboard-loss failsafe (COM_OF_LOSS_T 1 s, COM_OBL_RC_ACT 4: land)
    is recorded, not asserted: PX4 decides it, and the station takes the
    vehicle over from AUTO.LAND as from any mode. Measured (2026-12-04,
    three runs): left at 26.48-26.94 s, in the formation again 9.7, 11.0
    and 20.0 s later; no AUTO.LAND until the mission's end (the station put
    it in Hold 1.65 s after it was heard again, then OFFBOARD 2.0 s later)."""
    binary = binary_or_skip()
    if not in_private_namespace_or_rerun(request.node.nodeid, tmp_path):
        return
    mission = _moving(_short(load(MISSION), 75.0), 1.2)  # 1.2 N / 1.6 N s/m = 0.75 m/s
    with px4_swarm(binary, 4, tmp_path / "px4") as swarm:
        monitor = Px4Monitor(3)

        resumed: list[float] = []

        async def pause() -> None:
            swarm.pause(3, True)
            await asyncio.sleep(3.0)
            swarm.pause(3, False)
            resumed.append(time.monotonic())

        try:
            s = asyncio.run(fly_acting(mission, tmp_path / "runs", 25.0, pause))
            land = monitor.first_mode_after(resumed[0], {LAND})
        finally:
            monitor.close()
    v = s["vehicles"]
    left, joins = v["4"]["left_at_s"], v["4"]["joined_at_s"]
    end = mission.settings.duration
    lost = [t for t in left if t < end]
    figures = {
        "left_at_s": left, "joined_at_s": joins,
        "rejoined_after_s": joins[-1] - lost[0] if lost and joins else None,
        "land_failsafe_after_resume_s": None if land is None else land - resumed[0],
        "radii_m": [v[k]["final_radius_m"] for k in ("1", "2", "3", "4")],
        "min_separation_m": s["overall"]["min_separation_m"],
        "separation_configured_m": mission.law.safety.separation,
        "final": s["overall"]["vehicles_final"], "outcome": s["outcome"],
    }  # fmt: skip
    write_figures(tmp_path, "px4_vehicle_paused", figures)
    assert len(lost) == 1 and lost[0] < joins[-1] < end, (left, joins)
    # Back while the formation moves (the leader moves until the end; the code
    # that asked for rest at the slot would not rejoin before it). Measured 9.7,
    # 11.0 and 20.0 s after the leave, the pos-vel chase 6.0, 5.3 and 14.5 s of
    # it; three more runs 9.7, 14.1 and 14.6 s (PX4 overshoots the moving point
    # and trails back: docs/sitl.md); bound 35 s, 1.75 times the slowest run.
    assert joins[-1] - lost[0] < 35.0, (left, joins)
    assert s["overall"]["vehicles_final"] == [1, 2, 3, 4]
    assert s["overall"]["min_separation_m"] >= mission.law.safety.separation


def test_px4_station_killed_every_vehicle_lands(
    tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """SIGKILL the station in flight: every PX4 is in AUTO.LAND (the
    COM_OBL_RC_ACT the station set) within COM_OF_LOSS_T + 0.5 s."""
    binary = binary_or_skip()
    if not in_private_namespace_or_rerun(request.node.nodeid, tmp_path):
        return
    loss_t = 1.0  # COM_OF_LOSS_T as the station sets it
    path = tmp_path / "mission.yaml"
    doc = yaml.safe_load((MISSIONS / MISSION).read_text())
    doc["mission"]["duration"] = 300
    path.write_text(yaml.safe_dump(doc))
    with px4_swarm(binary, 4, tmp_path / "px4"):
        monitors = [Px4Monitor(i) for i in range(4)]
        exe = Path(sys.executable).with_name("gcs-swarm")
        proc = subprocess.Popen(
            [str(exe), "run", str(path), "--log-dir", str(tmp_path / "runs")],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
            stdin=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            deadline = time.monotonic() + 300
            lines: list[str] = []
            for line in proc.stdout:
                lines.append(line)
                if line.startswith("t=") and float(line[2:].split("s", 1)[0]) >= 20.0:
                    break
                assert time.monotonic() < deadline, "no formation after 300 s"
            else:
                said = "".join(lines[-40:])
                pytest.fail(f"station ended before 20 s of formation: exit {proc.wait()}\n{said}")
            killed_at = time.monotonic()
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
            time.sleep(loss_t + 3.0)
            after = [m.first_mode_after(killed_at, {LAND}) for m in monitors]
            texts = [[t for at, t in m.texts if at >= killed_at][:3] for m in monitors]
        finally:
            for m in monitors:
                m.close()
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
            if proc.stdout is not None:
                proc.stdout.close()
    delays = [None if a is None else a - killed_at for a in after]
    gaps = [float(np.median(np.diff([a for a, _, _ in m.heartbeats]))) for m in monitors]
    figures = {"com_of_loss_t_s": loss_t, "land_after_kill_s": delays, "texts": texts,
               "heartbeat_interval_s": gaps}  # fmt: skip
    write_figures(tmp_path, "px4_station_killed", figures)
    assert all(d is not None and d <= loss_t + 0.5 for d in delays), (delays, texts)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-s", "-v", "-m", "px4_sitl"]))
