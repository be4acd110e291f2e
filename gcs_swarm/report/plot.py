"""The report picture of a run (PNG, matplotlib, Agg: no display needed).

``build_figure`` returns a ``matplotlib.figure.Figure`` (so tests can check
its axes, labels and legends); ``save_picture`` writes it. matplotlib is
imported inside these functions only, so that importing the station does
not pay for it.

Layout: on the left a 3-D view (mission frame, x east, y north, z up, equal
scale) of every vehicle's path and the virtual leader's, obstacles as boxes
and their fields as wireframe ellipsoids rho = r0 (formation-law.md s5:
semi-axes r0 sqrt(3) v_i); on the right, against mission time, the radius
to the leader, the minimum separation, the minimum box clearance and the
commanded |a|, with avoidance episodes shaded and join/leave events marked.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs_swarm.report.figures import Series, series
from gcs_swarm.report.record import F64, FlightRecord

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["PANEL_TITLES", "build_figure", "save_picture"]

PANEL_TITLES = (
    "3-D paths (mission frame)",
    "Radius to the virtual leader",
    "Minimum separation between vehicles",
    "Minimum obstacle clearance (negative: inside a box)",
    "Commanded acceleration",
)
_MAX_POINTS = 3000
_AVOID_COLOUR = "tab:orange"
_JOIN_COLOUR = "tab:green"
_LEAVE_COLOUR = "tab:purple"


def _colours(n: int) -> list[Any]:
    import matplotlib as mpl

    cmap = mpl.colormaps["tab10" if n <= 10 else "turbo"]
    return [cmap(i if n <= 10 else i / max(n - 1, 1)) for i in range(n)]


def _fmt(x: Any, unit: str, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}f} {unit}"


def build_figure(rec: FlightRecord, summary: dict[str, Any] | None = None) -> Figure:
    """The report picture of ``rec``; ``summary`` (``summarize_record``) adds
    the key figures to the title."""
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d import Axes3D  # type: ignore[import-untyped]  # noqa: F401

    fig = Figure(figsize=(18, 10), dpi=100, layout="constrained")
    grid = fig.add_gridspec(4, 2, width_ratios=(1.2, 1.0), wspace=0.06)
    ax3d = fig.add_subplot(grid[:, 0], projection="3d")
    axes = [fig.add_subplot(grid[0, 1])]
    axes += [fig.add_subplot(grid[i, 1], sharex=axes[0]) for i in (1, 2, 3)]
    colours = _colours(len(rec.ids))
    ser = series(rec)
    stride = max(1, rec.steps // _MAX_POINTS)
    names = {int(k): str(k) for k in rec.ids}
    if summary is not None and len(summary.get("vehicles", {})) == len(names):
        # The summary's names: network:sysid on a mission with networks (report.networks).
        names = dict(zip(names, summary["vehicles"], strict=True))
    _draw_3d(ax3d, rec, colours, stride, names)
    _draw_time(axes, rec, ser, colours, stride, names)

    when = f"{rec.times_s[-1]:.1f} s of mission time" if rec.steps else "no control step"
    head = f"{rec.name or 'gcs-swarm run'}: {when}, {len(rec.ids)} vehicles ({rec.source})"
    lines = [head]
    if summary is not None and "overall" in summary:
        o = summary["overall"]
        lines.append(
            "formed (1 %) after " + _fmt(o.get("time_to_form_s"), "s", 1)
            + "   |   min separation " + _fmt(o.get("min_separation_m"), "m")
            + "   |   min clearance " + _fmt(o.get("min_clearance_m"), "m")
            + "   |   peak |a| " + _fmt(o.get("peak_accel_mps2"), "m/s²", 2)
            + f"   |   avoidance episodes {o.get('avoidance_episodes', 0)}"
        )  # fmt: skip
    fig.suptitle("\n".join(lines), fontsize=13)
    return fig


def save_picture(fig: Figure, path: str | os.PathLike[str]) -> None:
    """Write ``fig`` as a PNG (Agg canvas; no display)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    fig.savefig(os.fspath(path), dpi=100)


# ---------------------------------------------------------------------- 3-D
def _box_faces(centre: F64, half: F64) -> list[list[F64]]:
    c = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    v = centre + c * half
    idx = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return [[v[i] for i in face] for face in idx]


def _draw_3d(
    ax: Any, rec: FlightRecord, colours: list[Any], stride: int, names: dict[int, str]
) -> None:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # type: ignore[import-untyped]

    extent: list[F64] = []
    handles: list[Any] = []
    for j, sysid in enumerate(rec.ids):
        p = rec.pos_m[::stride, j]
        ok = ~np.isnan(p[:, 0])
        if not ok.any():
            continue
        (line,) = ax.plot(p[:, 0], p[:, 1], p[:, 2], color=colours[j], lw=1.4,
                          label=f"vehicle {names[int(sysid)]}")  # fmt: skip
        handles.append(line)
        first, last = p[ok][0], rec.pos_m[:, j][~np.isnan(rec.pos_m[:, j, 0])][-1]
        ax.scatter(*first, color=colours[j], marker="o", s=22)
        ax.scatter(*last, color=colours[j], marker="s", s=40, edgecolor="black")
        extent.append(p[ok])
    if rec.steps:
        lp = rec.leader_pos_m[::stride]
        (line,) = ax.plot(lp[:, 0], lp[:, 1], lp[:, 2], color="black", ls="--", lw=1.6,
                          label="virtual leader")  # fmt: skip
        handles.append(line)
        ax.scatter(*rec.leader_pos_m[-1], color="black", marker="*", s=90)
        extent.append(lp)
        fin = rec.pos_m[-1][~np.isnan(rec.pos_m[-1, :, 0])]
        if 2 <= fin.shape[0] <= 12:
            for a in range(fin.shape[0]):
                for b in range(a + 1, fin.shape[0]):
                    seg = fin[[a, b]]
                    ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="0.45", lw=0.7, alpha=0.7)
            handles.append(Line2D([], [], color="0.45", lw=0.7, label="final formation"))
    for box in rec.boxes:
        centre, half = np.array(box.centre, float), np.array(box.half_extents, float)
        faces = _box_faces(centre, half)
        ax.add_collection3d(Poly3DCollection(faces, facecolor="0.55", edgecolor="0.25",
                                             alpha=0.35, lw=0.8))  # fmt: skip
        # rho = r0 (formation-law.md s5): semi-axes r0 / A = r0 sqrt(3) v_i.
        semi = rec.r0 * math.sqrt(3.0) * half
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
        ex = centre[0] + semi[0] * np.cos(u) * np.sin(v)
        ey = centre[1] + semi[1] * np.sin(u) * np.sin(v)
        ez = centre[2] + semi[2] * np.cos(v)
        ax.plot_wireframe(ex, ey, ez, color="tab:red", lw=0.4, alpha=0.35)
        extent.append(np.array([centre - semi, centre + semi]))
    if rec.boxes:
        handles.append(Patch(facecolor="0.55", edgecolor="0.25", alpha=0.5, label="obstacle"))
        handles.append(Line2D([], [], color="tab:red", lw=0.8, alpha=0.6,
                              label=f"avoidance field (ρ = r0 = {rec.r0:g})"))  # fmt: skip
    handles.append(Line2D([], [], color="0.3", marker="o", ls="", label="start"))
    handles.append(Line2D([], [], color="0.3", marker="s", ls="", label="end"))
    if extent:
        pts = np.vstack(extent)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        mid, span = (lo + hi) / 2, np.maximum(hi - lo, 1.0) * 1.08
        for setter, m, s in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid, span, strict=True):
            setter(m - s / 2, m + s / 2)
        ax.set_box_aspect(tuple(span))  # equal scale on every axis
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.set_zlabel("z up [m]")
    ax.set_title(PANEL_TITLES[0])
    ax.legend(handles=handles, loc="upper left", fontsize=8, ncol=2 if len(handles) > 12 else 1)


# --------------------------------------------------------------------- time
def _marked(rec: FlightRecord) -> list[tuple[float, str, int]]:
    """Join/leave events worth a line: not the initial members joining at the
    start, nor everyone leaving at the ending."""
    if not rec.steps:
        return []
    t0, t1 = float(rec.times_s[0]), float(rec.times_s[-1])
    return [(ts, a, s) for ts, a, s in rec.events
            if not (a == "join" and ts <= t0) and not (a == "leave" and ts >= t1)]  # fmt: skip


def _mark_events(axes: list[Axes], rec: FlightRecord, names: dict[int, str]) -> list[Any]:
    """Shade avoidance episodes and draw join/leave lines on every panel;
    returns legend handles for them."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = []
    t = rec.times_s
    spans: list[tuple[float, float]] = []
    start: float | None = float(t[0]) if rec.steps and rec.behaviour[0] == "avoidance" else None
    for ts, what, _ in rec.switches():
        if what == "start":
            start = ts
        elif start is not None:
            spans.append((start, ts))
            start = None
    if start is not None:
        spans.append((start, float(t[-1])))
    for ax in axes:
        for a, b in spans:
            ax.axvspan(a, b, color=_AVOID_COLOUR, alpha=0.15, lw=0)
        for ts, action, _ in _marked(rec):
            join = action == "join"
            ax.axvline(ts, color=_JOIN_COLOUR if join else _LEAVE_COLOUR,
                       ls="-" if join else "--", lw=1.0, alpha=0.8)  # fmt: skip
    for ts, action, sysid in _marked(rec):
        axes[0].annotate(f"{'+' if action == 'join' else '−'}{names.get(sysid, sysid)}", (ts, 1.0),
                         xycoords=("data", "axes fraction"), xytext=(2, -10),
                         textcoords="offset points", fontsize=8,
                         color=_JOIN_COLOUR if action == "join" else _LEAVE_COLOUR)  # fmt: skip
    if spans:
        handles.append(Patch(color=_AVOID_COLOUR, alpha=0.3, label="avoidance episode"))
    actions = {a for _, a, _ in _marked(rec)}
    if "join" in actions:
        handles.append(Line2D([], [], color=_JOIN_COLOUR, label="vehicle joins"))
    if "leave" in actions:
        handles.append(Line2D([], [], color=_LEAVE_COLOUR, ls="--", label="vehicle leaves"))
    return handles


def _draw_time(
    axes: list[Axes],
    rec: FlightRecord,
    ser: Series,
    colours: list[Any],
    stride: int,
    names: dict[int, str],
) -> None:
    t = rec.times_s[::stride]
    ax_r, ax_s, ax_c, ax_a = axes
    marks = _mark_events(axes, rec, names)
    for j, sysid in enumerate(rec.ids):
        ax_r.plot(t, ser.radius_m[::stride, j], color=colours[j], lw=1.1,
                  label=f"vehicle {names[int(sysid)]}")  # fmt: skip
        ax_a.plot(t, ser.accel_mps2[::stride, j], color=colours[j], lw=0.9)
    ax_r.set_ylabel("radius [m]")
    ax_r.legend(handles=[*ax_r.get_legend_handles_labels()[0][:10], *marks], fontsize=8,
                loc="best", ncol=2)  # fmt: skip

    ax_s.plot(t, ser.min_separation_m[::stride], color="tab:blue", lw=1.3,
              label="closest pair")  # fmt: skip
    ax_s.set_ylabel("separation [m]")
    ax_s.legend(handles=[*ax_s.get_legend_handles_labels()[0], *marks], fontsize=8,
                loc="best")  # fmt: skip

    if ser.min_clearance_m is not None:
        ax_c.plot(t, ser.min_clearance_m[::stride], color="tab:red", lw=1.3,
                  label="closest vehicle to a box")  # fmt: skip
        ax_c.axhline(0.0, color="black", lw=0.8, label="box surface")
        ax_c.axhspan(min(0.0, float(np.nanmin(ser.min_clearance_m, initial=0.0))) - 1.0, 0.0,
                     color="tab:red", alpha=0.08, lw=0)  # fmt: skip
        finite = ser.min_clearance_m[np.isfinite(ser.min_clearance_m)]
        if finite.size:  # zoom on the approach: the far part says little
            low = float(finite.min())
            top = min(float(finite.max()), max(5.0, 5.0 * abs(low) + 2.0))
            ax_c.set_ylim(min(-0.2, 1.2 * low), top + 0.05 * (top - low))
        ax_c.legend(handles=[*ax_c.get_legend_handles_labels()[0], *marks], fontsize=8,
                    loc="best")  # fmt: skip
    else:
        ax_c.text(0.5, 0.5, "no obstacles in this mission", transform=ax_c.transAxes,
                  ha="center", va="center", color="0.4")  # fmt: skip
    ax_c.set_ylabel("clearance [m]")

    acc = ser.accel_mps2[np.isfinite(ser.accel_mps2)]
    if acc.size:
        peak, usual = float(acc.max()), float(np.percentile(acc, 99.0))
        if peak > 5.0 * max(usual, 0.1):  # a spike (formation-law.md s11): keep the rest legible
            ax_a.set_ylim(0.0, 2.0 * max(usual, 0.1))
            k = np.unravel_index(int(np.nanargmax(ser.accel_mps2)), ser.accel_mps2.shape)
            ax_a.annotate(f"peak {peak:.1f} m/s² ↑", (float(rec.times_s[k[0]]), 1.0),
                          xycoords=("data", "axes fraction"), xytext=(4, -12),
                          textcoords="offset points", fontsize=8, color="0.2")  # fmt: skip
    else:
        ax_a.text(0.5, 0.5, "no acceleration commanded", transform=ax_a.transAxes,
                  ha="center", va="center", color="0.4")  # fmt: skip
    ax_a.set_ylabel("|a| commanded [m/s²]")
    ax_a.legend(handles=[_per_vehicle(), *marks], fontsize=8, loc="best")
    ax_a.set_xlabel("mission time [s]")
    for ax, title in zip(axes, PANEL_TITLES[1:], strict=True):
        ax.set_title(title, fontsize=11, loc="left")
        ax.grid(True, alpha=0.3)
        if ax is not ax_a:
            ax.tick_params(labelbottom=False)


def _per_vehicle() -> Any:
    from matplotlib.lines import Line2D

    return Line2D([], [], color="0.3", lw=0.9, label="one line per vehicle (colours as above)")
