"""The operator view of a sharded run: ``gcs-swarm run MISSION --shards N --view``.

The vehicles live in the shards and the law in the controller
(docs/architecture.md, "Scaled out: shards"), so a frame is built in two
halves:

- each shard builds the frame of its own vehicles with the one-station
  ``SnapshotBuilder`` (``shard_frames``: phase, mode, arming, telemetry
  rate and loss, last heard, mission-frame position, its joins, leaves and
  notes) and sends it to the controller at ``runtime.sharded.SHARD_VIEW_HZ``
  while the run has the view;
- the controller merges the shards' latest frames in key order and adds
  what only the law knows (``ShardedFrames``): the mission time, the
  leader, the behaviour and its switches, each vehicle's commanded
  acceleration and safety correction and whether it is in the formation,
  the geometry columns recomputed against the leader, its own notes.

The page, the token and the end buttons are the one-station view's
(``view.live``): a button fills the run's ``EndRequest`` and the controller
ends every vehicle through its shard with that end action. A frame is at
most one shard period (0.1 s) older than the law's step it shows.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import AsyncIterator, Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from gcs_swarm.control.obstacles import Ellipsoids
from gcs_swarm.view.live import live_server
from gcs_swarm.view.server import ViewServer
from gcs_swarm.view.snapshot import (
    SnapshotBuilder,
    float_column,
    frame_head,
    geometry_columns,
    law_columns,
    new_lines,
    obstacles_of,
    scene_of,
)

if TYPE_CHECKING:
    from gcs_swarm.mission import Mission
    from gcs_swarm.runtime.ending import EndRequest
    from gcs_swarm.runtime.sharded import ShardedRun, ShardedView
    from gcs_swarm.runtime.station import Station

__all__ = ["ShardedFrames", "shard_frames", "sharded_view"]

_SHARD_COLUMNS = ("sysid", "label", "autopilot", "phase", "mode", "armed", "rate_hz", "loss",
                  "heard_s", "pos")  # fmt: skip
"""The vehicle columns a shard knows (the rest are the law's)."""


def shard_frames(station: Station) -> Callable[[float], dict[str, Any]]:
    """A shard's half (``runtime.shard.FrameSource``): its vehicles' frame at
    wall time ``now`` [s], with its links' setpoint drops."""
    builder = SnapshotBuilder({}, Ellipsoids.from_boxes(()))  # geometry: the controller's
    recorder = station.recorder

    def frame(now: float) -> dict[str, Any]:
        counts = None if recorder is None else recorder.telemetry.counts
        out = builder.frame(station, now, telemetry=counts)
        out["setpoints_dropped"] = sum(lk.stats.setpoints_dropped for lk in station.links.values())
        return out

    return frame


class ShardedFrames:
    """The controller's half (module docstring): ``frame(run)`` merges the
    shards' latest frames with the law's step. ``scene`` is ``scene_of``'s."""

    def __init__(self, scene: Mapping[str, Any]) -> None:
        self.scene = dict(scene)
        self._obstacles = obstacles_of(scene)
        self._behaviour: str | None = None
        self._last_line: str | None = None
        self.seq = 0

    def frame(self, run: ShardedRun, *, ended_by: str | None = None) -> dict[str, Any]:
        core = run.core
        control = core.control
        last = control.last
        cols: dict[str, list[Any]] = {c: [] for c in _SHARD_COLUMNS}
        for i in sorted(run.views):
            part = run.views[i]["vehicles"]
            for c in _SHARD_COLUMNS:
                cols[c].extend(part[c])
        order = sorted(range(len(cols["sysid"])), key=cols["sysid"].__getitem__)
        cols = {c: [v[k] for k in order] for c, v in cols.items()}
        ids: list[int] = cols["sysid"]
        n = len(ids)
        pos = np.array([[math.nan] * 3 if p is None else p for p in cols.pop("pos")],
                       dtype=np.float64).reshape(n, 3)  # fmt: skip
        leader = None if last is None else last.law.leader_pos_m
        accel, correction = law_columns(last, ids)
        behaviour = None if last is None else str(last.law.behaviour)
        t = float(control.t_s)
        events = list(run.view_events)
        run.view_events.clear()
        if behaviour is not None and self._behaviour is not None and behaviour != self._behaviour:
            events.append({"t": t, "kind": "switch", "sysid": None, "text": behaviour})
        if behaviour is not None:
            self._behaviour = behaviour
        lines, self._last_line = new_lines(core.log, self._last_line)
        events += [{"t": t, "kind": "note", "sysid": None, "text": line} for line in lines]
        flying = set(core.flying)
        dropped = sum(int(f.get("setpoints_dropped", 0)) for f in run.views.values())
        self.seq += 1
        stage = "ending" if core.finished else "flying" if core.started else "starting"
        return {
            **frame_head(self.seq, t, stage, last),
            "vehicles": {
                **cols,
                **geometry_columns(pos, leader, self._obstacles),
                "accel": float_column(accel, 3),
                "correction": float_column(correction, 3),
                "in_formation": [s in flying for s in ids],
            },
            "scene": self.scene,
            "events": events,
            "setpoints_dropped": dropped,
            "ended_by": ended_by,
        }


def sharded_view(
    mission: Mission,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    rate_hz: float = 10.0,
    token: str | None = None,
    on_url: Callable[[str], None] | None = None,
    on_server: Callable[[ViewServer], None] | None = None,
) -> ShardedView:
    """The view of ``mission``'s sharded run on ``host:port`` (0: any free
    port), frames at ``rate_hz``; ``on_url`` gets the page's address with
    its token as soon as it listens, ``on_server`` the server."""

    @contextlib.asynccontextmanager
    async def lifetime(run: ShardedRun, request: EndRequest) -> AsyncIterator[ViewServer]:
        builder = ShardedFrames(scene_of(mission.law, name=mission.settings.name))

        def frames() -> dict[str, Any]:
            return builder.frame(run, ended_by=request.action)

        async with live_server(mission, frames, request, lambda: run.core.finished,
                               host=host, port=port, rate_hz=rate_hz, token=token,
                               on_url=on_url, on_server=on_server) as server:  # fmt: skip
            yield server

    return lifetime
