"""The scripts in examples/ run as a user runs them (``python examples/X.py``,
a subprocess from the repository root) against the bundled emulator in
lockstep, and print what they promise. The demo flies in full (the README's
"fly the demo from a 10-line script"); the others fly a 15 s Example 1 to
keep the suite short."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import gcs_swarm

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def _run(script: str, *args: str, timeout_s: float = 240.0, quiet: bool = False) -> str:
    """The script's stdout; with ``quiet`` its stderr must be empty too (no
    warning printed: a clean run says nothing an operator must read past)."""
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / script), *args], cwd=ROOT, capture_output=True,
        text=True, timeout=timeout_s, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    if quiet:
        assert out.stderr == "", out.stderr[-2000:]
    return out.stdout


@pytest.fixture(scope="module")
def short_octahedron(tmp_path_factory: pytest.TempPathFactory) -> Path:
    text = (ROOT / "config/missions/example1_octahedron.yaml").read_text()
    assert "duration: 150" in text
    path = tmp_path_factory.mktemp("missions") / "octahedron_15s.yaml"
    path.write_text(text.replace("duration: 150", "duration: 15", 1))
    return path


def test_the_demo_script_is_ten_lines_and_forms_the_octahedron() -> None:
    code = [
        line
        for line in (EXAMPLES / "fly_demo.py").read_text().splitlines()
        if line.strip() and not line.startswith(('"""', "(the", "import sys", "from pathlib"))
    ]
    assert len(code) <= 10, code
    # No warning either: ArduCopter's end-of-boot STABILIZE is routine (logged).
    out = _run("fly_demo.py", quiet=True)
    assert "outcome: completed" in out
    radii = [float(w.split()[0]) for w in out.split("radius ")[1:]]
    assert len(radii) == 6 and all(abs(r - 2.48418) < 1e-3 for r in radii), radii


def test_read_summary_prints_radii_distances_and_the_shape(short_octahedron: Path) -> None:
    out = _run("read_summary.py", str(short_octahedron))
    assert "outcome: completed" in out and "octahedron: distances" in out
    assert out.count("vehicle ") == 6


def test_a_mission_built_in_code_is_simulated_then_flown() -> None:
    out = _run("build_mission.py", "3")
    assert "outcome: completed" in out
    assert out.count("ended") == 3  # the three vehicles of the flight


def test_the_flight_is_one_task_of_the_users_own_event_loop(short_octahedron: Path) -> None:
    out = _run("own_event_loop.py", str(short_octahedron))
    assert "[status] " in out and "outcome: completed" in out


def test_the_public_api_is_exactly_this() -> None:
    assert gcs_swarm.__all__ == [
        "ExpressionError", "InfeasibleError", "LinkError", "Mission", "MissionError",
        "MissionSimResult", "ReportError", "RunSummary", "StartupError", "SwarmError",
        "UsageError", "VehicleError", "__version__", "fly", "load_mission", "parse_mission",
        "run", "simulate",
    ]  # fmt: skip
    for name in gcs_swarm.__all__:
        assert getattr(gcs_swarm, name) is not None, name
    assert issubclass(gcs_swarm.ReportError, gcs_swarm.SwarmError)
    with pytest.raises(AttributeError):
        gcs_swarm.Station  # noqa: B018  (not public: gcs_swarm.runtime.Station)


def test_importing_the_package_loads_neither_the_station_nor_the_simulator() -> None:
    heavy = ("gcs_swarm.runtime", "gcs_swarm.offline", "sim_vehicle")
    code = f"import sys, gcs_swarm; print(sorted(m for m in sys.modules if m.startswith({heavy})))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == "[]"


def test_a_bad_mission_path_is_a_mission_error_before_anything_flies(tmp_path: Path) -> None:
    with pytest.raises(gcs_swarm.MissionError, match="cannot read the file"):
        gcs_swarm.run(tmp_path / "nope.yaml")
    result = gcs_swarm.simulate(ROOT / "config/missions/example1_tetrahedron.yaml",
                                duration_s=5.0)  # fmt: skip
    assert result.result.figures().text()


def test_library_code_does_not_print() -> None:
    """Only the command line prints (``cli.py`` and ``commands.py``); the rest
    returns or logs what it has to say (issue 16)."""
    import ast

    package = ROOT / "gcs_swarm"
    calls: dict[str, int] = {}
    for path in sorted(package.rglob("*.py")):
        if path.name in ("cli.py", "commands.py"):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        n = sum(
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == "print"
            for node in ast.walk(tree)
        )
        if n:
            calls[str(path.relative_to(package))] = n
    assert calls == {}
