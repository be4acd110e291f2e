"""The report picture has the expected panels (axes, titles, labels with
units, legends; not pixels); run folders; the simulation report; the
package's exported names; matplotlib stays out of the station's import."""

from __future__ import annotations

import subprocess
import sys
from datetime import datetime
from pathlib import Path

import pytest
from synthetic import mission, write_run

import gcs_swarm.report
from gcs_swarm.report import create_run_folder, run_folder_name, write_simulation_report
from gcs_swarm.report.plot import PANEL_TITLES, build_figure, save_picture


def test_figure_panels_labels_and_legends(tmp_path: Path) -> None:
    from gcs_swarm.report import summarize_record

    rec = write_run(tmp_path / "flight.tlog", mission())
    fig = build_figure(rec, summarize_record(rec))
    path = tmp_path / "report.png"
    save_picture(fig, path)  # drawn: the 3-D collections are projected
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    axes = fig.get_axes()
    assert [ax.get_title(loc="left") or ax.get_title() for ax in axes] == list(PANEL_TITLES)
    ax3d, ax_r, ax_s, ax_c, ax_a = axes
    assert ax3d.name == "3d"
    assert (ax3d.get_xlabel(), ax3d.get_ylabel(), ax3d.get_zlabel()) == (
        "x east [m]", "y north [m]", "z up [m]"
    )  # fmt: skip
    assert [ax.get_ylabel() for ax in (ax_r, ax_s, ax_c, ax_a)] == [
        "radius [m]", "separation [m]", "clearance [m]", "|a| commanded [m/s²]"
    ]  # fmt: skip
    assert ax_a.get_xlabel() == "mission time [s]"
    # 3-D legend: every vehicle, the leader, the obstacle and its field.
    labels3d = [t.get_text() for t in ax3d.get_legend().get_texts()]
    for want in ("vehicle 1", "vehicle 4", "virtual leader", "obstacle"):
        assert want in labels3d
    assert any(t.startswith("avoidance field") for t in labels3d)
    # One box drawn (6 faces) and one wireframe ellipsoid.
    assert sum(len(c.get_paths()) for c in ax3d.collections if c.__class__.__name__ ==
               "Poly3DCollection") == 6  # fmt: skip
    assert any(c.__class__.__name__ == "Line3DCollection" for c in ax3d.collections)
    # Time panels: the episode, the leave and the join are marked and in the legends.
    for ax in (ax_r, ax_s, ax_c, ax_a):
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert {"avoidance episode", "vehicle joins", "vehicle leaves"} <= set(labels), labels
    assert "box surface" in [t.get_text() for t in ax_c.get_legend().get_texts()]
    assert len(ax_r.get_lines()) >= 4  # one radius line per vehicle
    assert fig.get_suptitle().startswith("Scenario 3")
    assert "min clearance" in fig.get_suptitle()


def test_simulation_report(tmp_path: Path) -> None:
    from gcs_swarm.offline import simulate_mission

    m = mission()
    out = simulate_mission(m, dt_s=0.05, duration_s=30.0)
    s = write_simulation_report(out, tmp_path / "sim", name=m.settings.name)
    assert (tmp_path / "sim" / "summary.json").is_file()
    assert (tmp_path / "sim" / "report.png").is_file()
    o = s["overall"]
    assert s["source"] == "simulation" and o["avoidance_episodes"] == out.result.episode[-1]
    assert o["min_clearance_m"] == pytest.approx(out.result.figures().min_clearance_m)
    assert o["telemetry"] is None and o["setpoints"]["sent"] == 0
    assert o["safety"]["applied"] is False and "interventions" in o["safety"]


def test_run_folder_layout(tmp_path: Path) -> None:
    when = datetime(2025, 3, 1, 14, 25, 1)
    assert run_folder_name("Scenario 3, moving tetrahedron!", when) == (
        "20250301-142501-scenario-3-moving-tetrahedron"
    )
    assert run_folder_name("***", when) == "20250301-142501-mission"
    m = mission()
    a = create_run_folder(m, base_dir=tmp_path / "runs", when=when)
    b = create_run_folder(m, base_dir=tmp_path / "runs", when=when)
    assert a.path.name == "20250301-142501-scenario-3-moving-tetrahedron-meets-a-box"
    assert b.path.name == a.path.name + "-2"
    assert a.mission.read_bytes() == Path(m.source).read_bytes()
    assert (a.tlog.name, a.summary.name, a.picture.name) == (
        "flight.tlog", "summary.json", "report.png"
    )  # fmt: skip


def test_exported_names() -> None:
    exported = gcs_swarm.report.__all__
    assert exported == sorted(exported, key=lambda n: (not n.isupper(), n))
    public = {n for n in vars(gcs_swarm.report) if not n.startswith("_")}
    modules = {n for n in public if type(getattr(gcs_swarm.report, n)).__name__ == "module"}
    assert public - modules - {"annotations"} == set(exported)


def test_matplotlib_is_imported_only_for_the_picture() -> None:
    code = ("import sys, gcs_swarm.report, gcs_swarm.runtime.tlog, gcs_swarm.runtime; "
            "print('matplotlib' in sys.modules)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert out.stdout.strip() == "False"
