"""Replay in the operator view: the replay clock on a hand-advanced clock,
the frames of a run's flight record rebuilt from its ``.tlog``, and
``gcs-swarm view RUN_FOLDER`` serving them over a real socket."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
from websockets.asyncio.client import connect

from gcs_swarm.report.artefacts import report_from_tlog
from gcs_swarm.view import RecordFrames, ReplayClock, scene_of
from tests.station.station_harness import mission_from

ROOT = Path(__file__).resolve().parents[2]


def test_the_replay_clock_plays_pauses_speeds_and_seeks() -> None:
    c = ReplayClock(0.0, 10.0)
    assert c.at(100.0) == 0.0 and not c.playing
    assert c.command({"type": "play"}, 100.0)["ok"]
    assert c.at(101.5) == 1.5
    assert c.command({"type": "speed", "value": 2.0}, 101.5)["ok"]
    assert c.at(102.5) == 3.5
    assert not c.command({"type": "speed", "value": 3.0}, 102.5)["ok"]  # not offered
    assert c.command({"type": "pause"}, 103.0)["ok"] and c.t_s == 4.5
    assert c.at(110.0) == 4.5
    c.restarted = False
    assert c.command({"type": "seek", "t": 99.0}, 110.0)["ok"] and c.t_s == 10.0 and c.restarted
    c.command({"type": "play"}, 110.0)  # at the end: from the start again
    assert c.t_s == 0.0 and c.playing
    assert c.at(200.0) == 10.0 and not c.playing  # stops at the end
    assert not c.command({"type": "end", "action": "land"}, 200.0)["ok"]  # commands nothing


def test_frames_of_a_logged_run(run_folder: Path) -> None:
    mission = mission_from("example1_octahedron.yaml")
    _, record = report_from_tlog(run_folder / "flight.tlog", mission)
    frames = RecordFrames(record, scene_of(mission.law), autopilots={1: "sim"})
    clock = ReplayClock(frames.t0_s, frames.t1_s)
    first = frames.frame(0.0, clock)
    assert first["replay"]["restart"]
    joins = [e["sysid"] for e in first["events"] if e["kind"] == "join"]
    assert sorted(joins) == [1, 2, 3, 4, 5, 6]  # at t = 0: the start shows them
    v = first["vehicles"]
    assert v["sysid"] == [1, 2, 3, 4, 5, 6] and v["autopilot"][:2] == ["sim", None]
    k = int(np.searchsorted(record.times_s, 2.0, side="right")) - 1
    mid = frames.frame(2.0, clock)
    assert not mid["replay"]["restart"] and mid["t"] == round(float(record.times_s[k]), 3)
    np.testing.assert_allclose(np.array(mid["vehicles"]["pos"]), record.pos_m[k], atol=5e-4)
    np.testing.assert_allclose(mid["leader"], record.leader_pos_m[k], atol=5e-4)
    assert mid["vehicles"]["in_formation"] == [True] * 6
    assert all(x == 0.0 for x in mid["vehicles"]["loss"])  # no frame lost on 127.0.0.1
    assert mid["events"] == [] and frames.frame(3.0, clock)["events"] == []  # each once
    assert frames.frame(1.0, clock)["events"] == []  # a jump back shows nothing again
    json.dumps(mid, allow_nan=False)


def test_gcs_swarm_view_serves_the_replay_until_interrupted(run_folder: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcs_swarm", "view", str(run_folder), "--listen", "127.0.0.1:0"],
        stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert line.startswith("replay view: http://127.0.0.1:"), line
        url = line.split()[2].replace("http://", "ws://").replace("/?", "/ws?")

        async def watch() -> list[dict]:  # type: ignore[type-arg]
            got = []
            async with asyncio.timeout(15.0), connect(url) as ws:
                hello = json.loads(await ws.recv())
                assert hello["mode"] == "replay" and hello["duration"] >= 3.9
                await ws.send(json.dumps({"type": "speed", "value": 10.0}))
                async for text in ws:
                    msg = json.loads(text)
                    if msg["type"] == "frame":
                        got.append(msg)
                        if not msg["replay"]["playing"]:
                            return got
            return got

        frames = asyncio.run(watch())
        assert frames[-1]["replay"]["t"] == frames[-1]["replay"]["duration"]  # played to the end
        assert len({f["t"] for f in frames}) > 3
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
    finally:
        proc.kill()
        proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()
