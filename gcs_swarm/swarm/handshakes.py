"""How many vehicles of one network do their start-up handshake at once.

A vehicle's CONFIGURING phase (vehicle_startup.py: its stream rates asked,
its parameters read and set, its EKF origin asked) is 6 to 27 awaited
commands (docs/mavlink-protocol.md), one in flight at a time, and the
vehicle it readies then streams its telemetry at the control rate and is
answered at that rate. A network of 250 heard together starts all of that
at once: on a radio it is a burst of several seconds of the link's
capacity, and on one machine that also hosts the vehicles the load comes
all at once. Measured on two cores (benchmarks/README.md, "Start-up in
waves"): 1,000 bundled-emulator vehicles on four networks behind four
link shards started in 8 of 16 runs (in the others PARAM_SETs went
unanswered ten times: the emulator's socket buffers overflowed), in 11 of
11 with 16 of a network at once, 3 of 3 with 8, 1 of 4 with 25.

With ``mission.startup.handshakes_per_network`` set, ``HandshakeGate``
lets at most that many vehicles of a network configure at once; the
others, heard (their HEARTBEAT is in), wait in CONNECTING in the order they
were heard and start as places free. A place frees when its vehicle leaves
CONFIGURING, whichever way (on to GUIDED, failed, lost). A vehicle never
heard takes no place.

Only the first start is gated: a vehicle readied again (lost and heard
again, a rejoin) goes at once, as without the bound. The core creates its
vehicles with ``enabled=False`` and calls ``update`` after each call on a
protocol (``SwarmCore._service``); ``VehicleProtocol.enable`` starts the
ones it returns. No I/O.
"""

from __future__ import annotations

from collections import deque

from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mavlink.vehicle import VehicleProtocol

__all__ = ["HandshakeGate", "held"]


def held(vp: VehicleProtocol) -> bool:
    """Heard (its HEARTBEAT is in) but not let into its handshake: a vehicle
    created ``enabled=False`` that the gate has not started yet."""
    return not vp.enabled and vp.phase is Phase.CONNECTING and vp.heartbeat is not None


class HandshakeGate:
    """At most ``window`` vehicles of each network in CONFIGURING (module
    docstring); ``network_of`` maps each vehicle's key to its network."""

    def __init__(self, window: int, network_of: dict[int, int]) -> None:
        if window < 1:
            raise ValueError(f"handshakes_per_network must be at least 1, not {window}")
        self.window = window
        self.network_of = network_of
        self._in: dict[int, set[int]] = {net: set() for net in network_of.values()}
        self._queue: dict[int, deque[int]] = {net: deque() for net in network_of.values()}
        self._queued: set[int] = set()
        self.most = 0
        """The most vehicles of one network configuring at once, so far."""

    def waiting(self, key: int) -> bool:
        """Heard, and waiting for a place in its network's handshakes."""
        return key in self._queued

    def update(self, vp: VehicleProtocol) -> list[int]:
        """Note ``vp``'s phase; returns the vehicles of its network to start
        now, in the order heard (each already given its place: the caller
        calls ``enable`` on each)."""
        key = vp.sysid
        net = self.network_of[key]
        inside = self._in[net]
        if vp.phase is Phase.CONFIGURING:
            inside.add(key)
        else:
            inside.discard(key)
            if held(vp) and key not in self._queued:
                self._queued.add(key)
                self._queue[net].append(key)
        start: list[int] = []
        queue = self._queue[net]
        while queue and len(inside) < self.window:
            nxt = queue.popleft()
            self._queued.discard(nxt)
            inside.add(nxt)
            start.append(nxt)
        self.most = max(self.most, len(inside))
        return start
