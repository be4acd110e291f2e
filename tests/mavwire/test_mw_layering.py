"""``mavwire`` is plumbing under both ends: it imports neither the station
(``gcs_swarm``) nor the emulator (``sim_vehicle``), does no I/O, and its
``__all__`` is what it exports; the emulator still never imports the
station; and the plumbing is written once (neither end keeps its own copy)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import mavwire

_ROOT = Path(__file__).parents[2]
_IO_MODULES = {"asyncio", "socket", "selectors", "threading", "time", "subprocess", "logging"}
_ALLOWED = {
    "__future__",
    "bisect",
    "collections",
    "functools",
    "itertools",
    "typing",
    "numpy",
    "pymavlink",
    "mavwire",
}


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


@pytest.mark.parametrize("path", sorted((_ROOT / "mavwire").glob("*.py")), ids=lambda p: p.name)
def test_mavwire_imports_only_stdlib_numpy_and_pymavlink(path: Path) -> None:
    tops = {name.split(".")[0] for name in _imports(path)}
    assert not tops & {"gcs_swarm", "sim_vehicle"}, path.name
    assert not tops & _IO_MODULES, path.name
    assert tops <= _ALLOWED, f"{path.name} imports {tops - _ALLOWED}"
    assert "pymavlink.mavutil" not in _imports(path)  # the generated dialect only


def test_importing_mavwire_loads_neither_end() -> None:
    """Transitively too: a fresh interpreter that imports mavwire has loaded
    no module of gcs_swarm or sim_vehicle."""
    code = (
        "import sys, mavwire\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('gcs_swarm', 'sim_vehicle')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=_ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("path", sorted((_ROOT / "sim_vehicle").rglob("*.py")), ids=str)
def test_sim_vehicle_never_imports_gcs_swarm(path: Path) -> None:
    assert not any(m.split(".")[0] == "gcs_swarm" for m in _imports(path)), path


def test_exported_names() -> None:
    exported = mavwire.__all__
    assert exported == sorted(exported, key=lambda n: (not n.isupper(), n))
    public = {n for n in vars(mavwire) if not n.startswith("_")}
    submodules = {n for n in public if type(getattr(mavwire, n)).__name__ == "module"}
    assert submodules == {"crc", "datagrams", "framing", "protocols", "signing"}
    assert public - submodules - {"annotations"} == set(exported)
    for name in exported:  # each name is its submodule's, listed there too
        owner = next(m for m in submodules if name in getattr(mavwire, m).__all__)
        assert getattr(getattr(mavwire, owner), name) is getattr(mavwire, name)


@pytest.mark.parametrize(
    "needle",
    ["def check_signature", "mcrf4xx", "x25crc", "MAX_DATAGRAM =", "MAX_DATAGRAM_BYTES =",
     "allow_unsigned_callback", "0x8408"],
)  # fmt: skip
def test_the_plumbing_is_written_once(needle: str) -> None:
    """Neither end keeps its own signing set-up, CRC selection or datagram limit."""
    found = [
        str(path.relative_to(_ROOT))
        for pkg in ("gcs_swarm", "sim_vehicle")
        for path in sorted((_ROOT / pkg).rglob("*.py"))
        if needle in path.read_text()
    ]
    assert found == []
