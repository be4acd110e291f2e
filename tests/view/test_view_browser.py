"""The operator view in a real headless browser (Debian's ``chromium`` with
``chromium-driver``, driven by Selenium) during a lockstep run of the demo:
the 3-D view and the table show the six vehicles, their positions change,
and the page's confirmed Land click lands them. A screenshot of the page
goes into the test's temporary folder. Skipped, with the reason, where the
browser is not installed (README set-up, ``.ci/run``)."""

from __future__ import annotations

import asyncio
import dataclasses
import os
import shutil
import time
from pathlib import Path
from typing import Any

import pytest

from gcs_swarm.control import ConstantForce
from gcs_swarm.report.artefacts import report_from_tlog
from gcs_swarm.view import RecordFrames, ViewServer, replay_view, scene_of
from tests.station.station_harness import mission_from
from tests.view.test_view_server import _fly_with_view

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
DRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"

pytestmark = pytest.mark.skipif(
    not (Path(CHROMIUM).is_file() and Path(DRIVER).is_file()),
    reason="no headless browser: apt-get install -y chromium chromium-driver (README, set-up)",
)


def _browser() -> Any:
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1500,900", "--no-first-run"):  # fmt: skip
        opts.add_argument(arg)
    return webdriver.Chrome(options=opts, service=webdriver.ChromeService(executable_path=DRIVER))


def _wait(driver: Any, script: str, limit_s: float = 15.0) -> Any:
    """Poll ``script`` (JavaScript returning a value) until it is truthy."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"not true after {limit_s} s: {script}")


def _keep(shot: Path) -> None:
    """Also into ``$GCS_SWARM_VIEW_SHOTS`` when set (the README's pictures)."""
    where = os.environ.get("GCS_SWARM_VIEW_SHOTS")
    if where:
        shutil.copy(shot, Path(where) / shot.name)


_DRAWN = "return window.gcsView && window.gcsView.drawn.length === 6 && window.gcsView.drawn"
_ROWS = "return document.querySelectorAll('#vehicles tbody tr').length"


def test_the_page_shows_six_vehicles_moving_and_lands_them(tmp_path: Path) -> None:
    # An hour of flight, ended by the click: an idle machine runs the lockstep
    # demo's 150 s in a few seconds, before a browser has clicked anything.
    # The leader is pushed east (about 1 m/s) and the page does not follow it:
    # Example 1 settles in about 50 s of flight, which a fast machine flies
    # before the browser has drawn a frame, and a settled formation around
    # a leader at rest (or one the camera follows) does not move on the
    # canvas (seen: 0.0 px for all six, 2026-12-04).
    mission = mission_from("example1_octahedron.yaml", duration=3600.0)
    leader = dataclasses.replace(mission.law.leader, force=ConstantForce((10.0, 0.0, 0.0)))
    mission = dataclasses.replace(mission, law=dataclasses.replace(mission.law, leader=leader))
    driver = _browser()
    seen: dict[str, Any] = {}

    def look(server: ViewServer) -> None:
        driver.get(server.url)
        _wait(driver, _DRAWN)
        follow = driver.find_element("id", "follow")
        if follow.is_selected():
            follow.click()  # the camera stays put: the formation crosses the canvas
        # What the canvas shows and the frame time it shows, read together; then
        # a canvas drawn from a frame at least 1 s of flight later (frames come
        # faster than the page draws them: waiting on the frame alone compared
        # one drawing with itself, 0.0 px, in CI on 2026-12-04).
        first, t0 = _wait(driver, f"return ({_DRAWN[7:]}) && [window.gcsView.drawn, "
                                  "window.gcsView.drawnT]")  # fmt: skip
        _wait(driver, f"return window.gcsView.drawnT > {t0} + 1.0")
        later = _wait(driver, _DRAWN)
        seen["moved"] = {
            a["sysid"]: abs(a["x"] - b["x"]) + abs(a["y"] - b["y"])
            for a, b in zip(sorted(first, key=lambda d: d["sysid"]),
                            sorted(later, key=lambda d: d["sysid"]), strict=True)
        }  # fmt: skip
        seen["rows"] = driver.execute_script(_ROWS)
        seen["ids"] = driver.execute_script(
            "return [...document.querySelectorAll('#vehicles tbody tr')]"
            ".map(r => r.cells[0].textContent)"
        )
        seen["positions"] = driver.execute_script(
            "return [...document.querySelectorAll('#vehicles tbody tr')]"
            ".map(r => r.cells[8].textContent)"
        )
        _wait(driver, "return window.gcsView.draws > 2")
        driver.save_screenshot(str(tmp_path / "live-view.png"))
        driver.find_element("id", "end-land").click()
        seen["confirm"] = driver.find_element("id", "confirm-text").text
        driver.find_element("id", "confirm-yes").click()
        seen["answer"] = _wait(driver, "return window.gcsView.answers.length && "
                               "window.gcsView.answers[0]")  # fmt: skip

    async def during(server: ViewServer) -> None:
        await asyncio.to_thread(look, server)

    try:
        summary, states = asyncio.run(_fly_with_view(mission, during, timeout_s=28.0))
    finally:
        driver.quit()
    assert seen["rows"] == 6 and seen["ids"] == ["1", "2", "3", "4", "5", "6"]
    assert all(p != "-" for p in seen["positions"])
    assert sorted(seen["moved"]) == [1, 2, 3, 4, 5, 6]
    assert min(seen["moved"].values()) > 0.5  # pixels: every label moved on the canvas
    assert "Land every vehicle" in seen["confirm"]
    assert seen["answer"]["ok"] and seen["answer"]["action"] == "land"
    assert {st.mode_name for st in states.values()} == {"LAND"}
    assert summary.outcome == "completed"
    shot = tmp_path / "live-view.png"
    assert shot.stat().st_size > 10_000
    _keep(shot)


def test_the_replay_page_plays_a_logged_run(tmp_path: Path, run_folder: Path) -> None:
    mission = mission_from("example1_octahedron.yaml")
    _, record = report_from_tlog(run_folder / "flight.tlog", mission)
    frames = RecordFrames(record, scene_of(mission.law, name="Example 1 (replay)"))
    driver = _browser()
    seen: dict[str, Any] = {}

    def look(server: ViewServer) -> None:
        driver.get(server.url)
        _wait(driver, _DRAWN)
        assert driver.find_element("id", "replay").is_displayed()
        assert not driver.find_elements("css selector", "#buttons button")  # no end buttons
        _wait(driver, "return Number(document.getElementById('slider').value) > 1.0")
        seen["rows"] = driver.execute_script(_ROWS)
        driver.find_element("id", "play").click()  # pause
        _wait(driver, "return !window.gcsView.frame.replay.playing")
        seen["events"] = driver.execute_script(
            "return document.querySelectorAll('#events .ev-join').length"
        )
        driver.save_screenshot(str(tmp_path / "replay-view.png"))

    async def main() -> None:
        async with asyncio.timeout(25.0), replay_view(frames) as server:
            await asyncio.to_thread(look, server)

    try:
        asyncio.run(main())
    finally:
        driver.quit()
    assert seen["rows"] == 6 and seen["events"] == 6
    _keep(tmp_path / "replay-view.png")
