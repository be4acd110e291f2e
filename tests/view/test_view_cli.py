"""``gcs-swarm run MISSION --view [HOST:]PORT`` from the command line: the
address with its token is printed at start and the page is served while
the mission flies; a bad address is refused before anything flies."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from gcs_swarm.cli import EXIT_REFUSED, main

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "config" / "missions" / "example1_octahedron.yaml"


@pytest.mark.parametrize(
    ("demo", "extra"),
    [(DEMO, []), (ROOT / "config" / "missions" / "example1_networks.yaml", ["--shards", "2"])],
    ids=["one-station", "two-shards"],
)
def test_run_with_view_prints_the_address_and_serves_the_page(
    demo: Path, extra: list[str], tmp_path: Path
) -> None:
    mission = tmp_path / "short.yaml"
    text = demo.read_text()
    assert "duration: 150" in text
    mission.write_text(text.replace("duration: 150", "duration: 20", 1))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcs_swarm", "run", str(mission), "--view", "127.0.0.1:0",
         "--no-log", "--no-status", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert line.startswith("operator view: http://127.0.0.1:"), line
        url = line.split()[2]
        assert "?token=" in url
        with urllib.request.urlopen(url, timeout=5) as page:
            assert page.status == 200 and b"<canvas" in page.read()
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(url.split("?")[0], timeout=5)
        assert err.value.code == 403
        err.value.close()
        out, _ = proc.communicate(timeout=25)
        assert proc.returncode == 0, out
    finally:
        proc.kill()
        proc.wait()
        for pipe in (proc.stdout, proc.stderr):
            if pipe is not None:
                pipe.close()


@pytest.mark.parametrize("bad", ["x", "host:", "127.0.0.1:99999", "-1"])
def test_a_bad_view_address_is_refused(bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(DEMO), "--view", bad, "--no-log"]) == EXIT_REFUSED
    err = capsys.readouterr().err
    assert err.startswith("gcs-swarm: --view: expected [HOST:]PORT"), err


def test_simulate_with_view_replays_the_simulation_until_interrupted(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "gcs_swarm", "simulate", str(DEMO), "--duration", "2",
         "--no-log", "--view", "127.0.0.1:0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert line.startswith("replay view: http://127.0.0.1:"), line
        with urllib.request.urlopen(line.split()[2], timeout=5) as page:
            assert page.status == 200
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0
        assert "simulated 2.00 s" in out
    finally:
        proc.kill()
        proc.wait()
        for pipe in (proc.stdout, proc.stderr):
            if pipe is not None:
                pipe.close()
