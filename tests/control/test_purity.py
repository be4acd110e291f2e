"""Meta-tests (STYLE habits 10-11): ``gcs_swarm.control`` stays pure (no I/O
imports) and its public API is exactly what ``__all__`` says."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import gcs_swarm.control as control

FORBIDDEN = {
    "asyncio", "socket", "pymavlink", "yaml", "logging", "threading", "selectors",
    "subprocess", "os", "io", "time", "zenoh",
}  # fmt: skip
CONTROL_DIR = Path(control.__file__).parent


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_control_imports_no_io() -> None:
    files = sorted(CONTROL_DIR.glob("*.py"))
    assert len(files) >= 10  # the scan really sees the package
    offenders = {f.name: sorted(_imports(f) & FORBIDDEN) for f in files}
    assert {k: v for k, v in offenders.items() if v} == {}


def test_control_imports_only_numpy_and_itself() -> None:
    """numpy everywhere; numba in ``kernels.py`` alone (the compiled pair loop)."""
    for f in sorted(CONTROL_DIR.glob("*.py")):
        allowed_third_party = {"numpy", "numba"} if f.name == "kernels.py" else {"numpy"}
        for name in _imports(f):
            if name in {"gcs_swarm", "__future__"} or name in allowed_third_party:
                continue
            assert name in sys.stdlib_module_names, f"{f.name} imports {name}"


def test_exported_names() -> None:
    exported = set(control.__all__)
    assert len(exported) == len(control.__all__)  # no duplicates
    public = {n for n in vars(control) if not n.startswith("_")}
    public -= {"annotations"}
    modules = {n for n in public if type(getattr(control, n)).__name__ == "module"}
    assert public - modules == exported
    for name in (
        "SwarmController",
        "ControlOutput",
        "LookaheadJob",
        "LookaheadResult",
        "LawConfig",
        "validate_expression",
    ):
        assert name in exported


def test_the_emulators_sans_io_pieces_import_no_io() -> None:
    """What the in-process harness (tests/swarm/swarm_harness.py) drives with
    a hand-advanced clock: the emulator's autopilot, fleet, commands,
    telemetry and codec, like the law, open no socket and start no task."""
    root = CONTROL_DIR.parent.parent / "sim_vehicle"
    names = ("autopilot", "fleet", "commands", "telemetry", "guards", "params", "codec",
             "dynamics")  # fmt: skip
    offenders = {n: sorted(_imports(root / f"{n}.py") & (FORBIDDEN - {"pymavlink"})) for n in names}
    assert {k: v for k, v in offenders.items() if v} == {}
