"""The emulator's I/O-free layer stays I/O-free (STYLE.md habits 1 and 11).

Everything but the asyncio shell (``server``, ``link``, ``cli``) and the
signing set-up (``signing``: the wall clock starts its timestamps) is driven
by ``now``: the autopilots, the core, impairments, lockstep, the telemetry
schedule, the dynamics and its fast variant. (Python still runs
``sim_vehicle/__init__``, which re-exports the asyncio ``Emulator``; the
check is on what each module needs.) Checked on the source, through
every ``sim_vehicle`` and ``mavwire`` module each one imports, so an I/O
import cannot come in by the back door."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
IO = {"asyncio", "socket", "selectors", "threading", "time", "subprocess"}
SANS_IO = (
    "autopilot", "px4", "targets", "commands", "guards", "safety", "reports", "telemetry",
    "params", "config", "fleet", "dynamics", "dynamics_rows", "codec", "small", "core",
    "impairments", "lane", "lockstep", "schedule", "stats", "vehicles",
)  # fmt: skip
SHELL = {"server", "link", "cli", "signing", "__init__"}


def _imports(module: str) -> set[str]:
    """Dotted names ``module`` (``pkg.mod``) imports at module level or below."""
    path = ROOT / (module.replace(".", "/") + ".py")
    if not path.exists():
        path = ROOT / module.replace(".", "/") / "__init__.py"
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            if node.module in ("sim_vehicle", "mavwire"):  # from sim_vehicle import core
                out.update(f"{node.module}.{a.name}" for a in node.names)
    # ``sim_vehicle/__init__`` re-exports the shell for users; it is not what a
    # module needs (``from sim_vehicle import core`` needs ``core``).
    out.discard("sim_vehicle")
    return out


def _closure(module: str) -> dict[str, str]:
    """Every module reached from ``module`` through sim_vehicle / mavwire -> who imports it."""
    seen: dict[str, str] = {}
    todo = [module]
    while todo:
        mod = todo.pop()
        for name in _imports(mod):
            top = name.split(".")[0]
            if name not in seen:
                seen[name] = mod
                ok = (ROOT / (name.replace(".", "/") + ".py")).exists()
                if top in ("sim_vehicle", "mavwire") and (
                    ok or (ROOT / name.replace(".", "/")).is_dir()
                ):
                    todo.append(name)
    return seen


def test_every_module_is_placed() -> None:
    found = {p.stem for p in (ROOT / "sim_vehicle").glob("*.py")}
    assert found == set(SANS_IO) | SHELL, found ^ (set(SANS_IO) | SHELL)


@pytest.mark.parametrize("name", SANS_IO)
def test_sans_io_module_reaches_no_io(name: str) -> None:
    reached = _closure(f"sim_vehicle.{name}")
    bad = {m: by for m, by in reached.items() if m.split(".")[0] in IO}
    assert bad == {}, f"sim_vehicle.{name} reaches {bad} (module -> imported by)"
    assert "sim_vehicle.server" not in reached and "sim_vehicle.link" not in reached


def test_the_check_sees_an_io_import() -> None:
    """The shell does reach asyncio and socket, so the scan is not vacuous."""
    reached = _closure("sim_vehicle.server")
    assert {"asyncio", "socket", "time"} <= {m.split(".")[0] for m in reached}
