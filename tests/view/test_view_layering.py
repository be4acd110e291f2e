"""The view's frame builder does no I/O, the package exports what its
``__all__`` says, and the page's files are the package's own."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import gcs_swarm.view
from gcs_swarm.runtime.ending import END_ACTIONS
from gcs_swarm.runtime.run import END_MODES
from tests.mavlink.test_layering import _run_time_imports

_VIEW = Path(gcs_swarm.view.__file__).parent
_IO = {"asyncio", "socket", "selectors", "threading", "time", "subprocess", "websockets", "http"}


def test_the_snapshot_builder_imports_no_io_and_not_the_runtime() -> None:
    names = _run_time_imports(ast.parse((_VIEW / "snapshot.py").read_text()))
    assert not {n.split(".")[0] for n in names} & _IO
    assert not [n for n in names if n.startswith("gcs_swarm.runtime")]


def test_exported_names() -> None:
    module = importlib.import_module("gcs_swarm.view")
    exported = module.__all__
    assert exported == sorted(exported, key=lambda n: (not n.isupper(), n))
    public = {n for n in vars(module) if not n.startswith("_")}
    submodules = {n for n in public if type(getattr(module, n)).__name__ == "module"}
    assert public - submodules - {"annotations"} == set(exported)


def test_the_end_buttons_are_the_missions_end_actions() -> None:
    assert set(END_ACTIONS) == set(END_MODES)
    assert set(gcs_swarm.view.END_LABELS) == set(END_ACTIONS)


def test_the_page_loads_nothing_from_elsewhere() -> None:
    files = sorted((_VIEW / "static").iterdir())
    assert [f.name for f in files] == ["index.html", "view.css", "view.js"]
    for f in files:
        text = f.read_text()
        assert "http://" not in text and "https://" not in text, f.name
        assert "//cdn" not in text and "import(" not in text, f.name
