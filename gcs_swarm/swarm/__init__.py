"""The swarm's rules without I/O (issue 16): one link's policy
(``LinkState``), the station's core (``SwarmCore``: membership, events,
origin, steps, ending), and a link shard's and its controller's halves of a
step (``ShardSide``, ``ControllerCore``, their wire: issue 19), driven by
``now``; ``gcs_swarm.runtime`` wraps them in sockets, one timer and a
TaskGroup. No module here imports asyncio, socket, zenoh or the runtime (a
test says so)."""

from __future__ import annotations

from gcs_swarm.swarm.controller import ControllerCore
from gcs_swarm.swarm.core import SwarmCore
from gcs_swarm.swarm.link_state import MESSAGE_QUEUE_SIZE, REBIND_S, LinkState, LinkStats
from gcs_swarm.swarm.shard import ShardSide
from gcs_swarm.swarm.shard_wire import SetpointReply, StateBatch
from gcs_swarm.swarm.status import StatusLine
from gcs_swarm.swarm.step import SetpointBatch

__all__ = [
    "MESSAGE_QUEUE_SIZE",
    "REBIND_S",
    "ControllerCore",
    "LinkState",
    "LinkStats",
    "SetpointBatch",
    "SetpointReply",
    "ShardSide",
    "StateBatch",
    "StatusLine",
    "SwarmCore",
]
