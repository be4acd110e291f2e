"""The operator's view in a browser: the swarm in 3-D, every vehicle's state,
the end buttons, and replay (docs/operator-view.md).

- ``snapshot``: no I/O; one JSON-able frame of a running station;
- ``server``: the asyncio shell (``websockets``): the page and its files over
  HTTP, frames over a WebSocket, a per-run token, a slot per client;
- ``live``: the view ``gcs-swarm run --view`` enters over the station;
- ``sharded``: the same over a sharded run (``run --shards N --view``): the
  shards' halves of each frame merged with the controller's law;
- ``replay``: a finished run's flight record (or a simulation's) in the same
  page, with play, pause, speed and a time slider (``gcs-swarm view``);
- ``static/``: the page, its script (a small canvas 3-D renderer written here)
  and its style, served by the package: nothing is loaded from elsewhere.
"""

from gcs_swarm.view.live import END_LABELS, live_view
from gcs_swarm.view.replay import SPEEDS, RecordFrames, ReplayClock, replay_view
from gcs_swarm.view.server import ViewServer, parse_address
from gcs_swarm.view.snapshot import EVENT_KINDS, SnapshotBuilder, StationState, scene_of

__all__ = [
    "END_LABELS",
    "EVENT_KINDS",
    "SPEEDS",
    "RecordFrames",
    "ReplayClock",
    "SnapshotBuilder",
    "StationState",
    "ViewServer",
    "live_view",
    "parse_address",
    "replay_view",
    "scene_of",
]
