"""The ``gcs-swarm`` command line: every subcommand through ``main()`` as a
user types it, and bad input as one line with no traceback."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.cli import main

ROOT = Path(__file__).resolve().parents[2]
TETRA = ROOT / "config" / "missions" / "example1_tetrahedron.yaml"


def test_simulate_prints_the_summary_and_writes_the_report(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["simulate", str(TETRA), "--log-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "tetrahedron" in out
    # The paper's N = 4 radius (issue 3), printed to 5 decimals.
    assert "min 2.33359  max 2.33359" in out
    assert "6 x 3.81074" in out
    (folder,) = tmp_path.iterdir()  # one run folder, named by date and mission
    assert folder.name.endswith("example-1-tetrahedron-n-4")
    summary = json.loads((folder / "summary.json").read_text())
    radii = [v["final_radius_m"] for v in summary["vehicles"].values()]
    assert radii == pytest.approx([2.33359] * 4, abs=1e-5)
    assert (folder / "report.png").stat().st_size > 10_000
    assert (folder / "mission.yaml").read_text() == TETRA.read_text()


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_simulate_writes_trajectories(tmp_path: Path, suffix: str) -> None:
    out = tmp_path / f"traj{suffix}"
    assert main(["simulate", str(TETRA), "--duration", "2", "--out", str(out), "--no-log"]) == 0
    assert out.exists()
    if suffix == ".npz":
        with np.load(out) as data:
            assert data["pos_m"].shape[1:] == (4, 3)
            assert data["times_s"][-1] == pytest.approx(2.0)
    else:
        lines = out.read_text().splitlines()
        assert lines[0].startswith("t_s,id,x_m")
        assert len(lines) == 1 + 4 * 201  # 201 samples (t = 0 .. 2 s at 0.01 s) x 4


def test_check_ok_and_schema(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(TETRA)]) == 0
    assert capsys.readouterr().out.startswith("OK: ")
    assert main(["schema"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "vehicles" in doc["properties"]


def test_bad_mission_is_one_line_per_problem_and_no_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "mission: {name: x}\n"
        "gains: {alpha: -1}\n"
        "vehicles:\n"
        "  - {sysid: 1, start: [0, 0, 0]}\n"
        "  - {sysid: 1, start: [1, 0, 0]}\n"
    )
    for cmd in ("simulate", "run"):
        assert main([cmd, str(bad)]) == 2
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert len(lines) >= 2  # both problems reported, not just the first
        assert all(line.startswith(f"gcs-swarm: {bad}:") for line in lines)
        assert "Traceback" not in err
        assert any("alpha" in line for line in lines)
        assert any("sysid" in line for line in lines)


def test_missing_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", str(tmp_path / "nope.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope.yaml" in err


def test_bad_step_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", str(TETRA), "--dt", "0", "--no-log"]) == 2
    assert "--dt" in capsys.readouterr().err


# ---------------------------------------------------------------- issue 15, item 13
@pytest.mark.parametrize(
    ("args", "word"),
    [
        (["--duration", "-5"], "--duration"),
        (["--duration", "nan"], "--duration"),
        (["--duration", "1e9"], "--duration"),
        (["--dt", "nan"], "--dt"),
        (["--every", "0"], "--every"),
        (["--out", "t.txt"], "--out t.txt: trajectory files are .csv or .npz"),
    ],
)
def test_bad_simulate_arguments_are_one_line_before_anything_runs(
    args: list[str], word: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["simulate", str(TETRA), "--log-dir", str(tmp_path), *args]) == 2
    out, err = capsys.readouterr()
    assert out == ""  # nothing was simulated (it prints "simulated ... s" first)
    assert err.count("\n") == 1 and err.startswith("gcs-swarm: ") and word in err
    assert list(tmp_path.iterdir()) == []  # and no run folder


def test_simulate_duration_beyond_the_mission_checks_the_leader_too(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    m = tmp_path / "m.yaml"
    m.write_text(TETRA.read_text().replace("force: [0, 0, 0]", 'force: ["sqrt(100 - t)", 0, 0]'))
    assert main(["check", str(m)]) == 0
    capsys.readouterr()
    assert main(["simulate", str(m), "--duration", "200", "--no-log"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert f"{m}:" in err and "leader.force[0]" in err and "(with --duration 200)" in err


def test_check_takes_several_files_and_exits_2_if_any_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("mission: {duration: 1:30}\nvehicles:\n  - {sysid: 1, start: [0, 0, 1]}\n")
    assert main(["check", str(TETRA), str(bad), str(TETRA)]) == 2
    out, err = capsys.readouterr()
    assert out.count("OK: ") == 2
    assert err == (
        f'{bad}:1: mission.duration: expected a number > 0 and <= 14400, got "1:30"'
        " (YAML 1.2 reads 1:30 as a string, not a base-60 number)\n"
    )
    assert main(["check", str(TETRA), str(TETRA)]) == 0


def test_a_closed_output_pipe_is_no_traceback() -> None:
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-m", "gcs_swarm", "schema"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None
    proc.stdout.close()  # the reader is gone before a byte is written (| head, at once)
    _, err = proc.communicate(timeout=120)
    assert b"Traceback" not in err and b"BrokenPipe" not in err, err
    assert proc.returncode == 141
