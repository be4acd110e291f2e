"""The MAVLink layer does no I/O (STYLE.md: time is an argument) and both
packages export exactly what their ``__all__`` says."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

import gcs_swarm.mavlink
import gcs_swarm.runtime
import gcs_swarm.swarm

_IO_MODULES = {
    "asyncio", "socket", "selectors", "threading", "time", "subprocess", "logging", "zenoh",
}  # fmt: skip


@pytest.mark.parametrize("path", sorted(Path(gcs_swarm.mavlink.__file__).parent.glob("*.py")))
def test_mavlink_modules_import_no_io(path: Path) -> None:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names} | {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module.split(".")[0])
            names.add(node.module)
            assert not node.module.startswith("gcs_swarm.runtime"), path.name
    assert not names & _IO_MODULES, f"{path.name} imports {names & _IO_MODULES}"
    assert "pymavlink.mavutil" not in names and "mavutil" not in {
        a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names
    }  # the generated dialect only (STYLE.md habit 5)


@pytest.mark.parametrize("package", [gcs_swarm.mavlink, gcs_swarm.runtime, gcs_swarm.swarm])
def test_exported_names(package: object) -> None:
    exported = package.__all__  # type: ignore[attr-defined]
    assert exported == sorted(exported, key=lambda n: (not n.isupper(), n))
    module = importlib.import_module(package.__name__)  # type: ignore[attr-defined]
    for name in exported:
        assert getattr(module, name) is not None
    public = {n for n in vars(module) if not n.startswith("_")}
    submodules = {n for n in public if type(getattr(module, n)).__name__ == "module"}
    assert public - submodules - {"annotations"} == set(exported)


def _gcs_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out: set[str] = set()
    for node in ast.walk(tree):  # lazy imports inside functions too
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return {m for m in out if m.startswith("gcs_swarm.")}


@pytest.mark.parametrize(
    ("package", "below"),
    [("report", "gcs_swarm.runtime"), ("control", "gcs_swarm.runtime"),
     ("control", "gcs_swarm.report"), ("mavlink", "gcs_swarm.report")],
)  # fmt: skip
def test_lower_layers_never_import_the_runtime(package: str, below: str) -> None:
    """Imports go one way (issue 16): the runtime uses report, mavlink and
    control; report reads logs and replays the law without the runtime."""
    root = Path(gcs_swarm.mavlink.__file__).parent.parent / package
    files = sorted(root.glob("*.py"))
    assert len(files) >= 5
    bad = {f.name: sorted(m for m in _gcs_imports(f) if m.startswith(below)) for f in files}
    assert {k: v for k, v in bad.items() if v} == {}


def _run_time_imports(tree: ast.Module) -> set[str]:
    """Modules imported when the module runs: ``if TYPE_CHECKING:`` blocks
    (names for the types only) left out."""
    out: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            return
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return out


@pytest.mark.parametrize("path", sorted(Path(gcs_swarm.swarm.__file__).parent.glob("*.py")))
def test_swarm_core_and_link_state_import_no_io_and_not_the_runtime(path: Path) -> None:
    """The swarm core and the link state are driven by ``now`` (issue 16):
    no sockets, tasks, threads or clocks, and the asyncio runtime above them
    only for its types."""
    names = _run_time_imports(ast.parse(path.read_text()))
    roots = {n.split(".")[0] for n in names}
    assert not roots & (_IO_MODULES - {"logging"}), f"{path.name} imports {roots & _IO_MODULES}"
    assert not [n for n in names if n.startswith("gcs_swarm.runtime")], path.name
    assert "pymavlink.mavutil" not in names


def test_the_swarm_package_is_seen_whole() -> None:
    files = {p.name for p in Path(gcs_swarm.swarm.__file__).parent.glob("*.py")}
    assert {
        "core.py",
        "link_state.py",
        "step.py",
        "shard.py",
        "controller.py",
        "shard_wire.py",
    } <= files
