"""The swarm's rules without I/O (issue 16): one link's policy
(``LinkState``) and the station's core (``SwarmCore``), driven by ``now``;
``gcs_swarm.runtime`` wraps them in sockets, one timer and a TaskGroup."""

from __future__ import annotations

from gcs_swarm.swarm.link_state import MESSAGE_QUEUE_SIZE, REBIND_S, LinkState, LinkStats

__all__ = ["MESSAGE_QUEUE_SIZE", "REBIND_S", "LinkState", "LinkStats"]
