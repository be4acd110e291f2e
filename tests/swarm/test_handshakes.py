"""``mission.startup.handshakes_per_network`` (``gcs_swarm.swarm.handshakes``):
at most W vehicles of a network configure at once, the others wait in the
order heard, a place frees whichever way its vehicle leaves CONFIGURING,
and a vehicle never heard takes none. The station's core against the
emulator's, on the hand clock (``swarm_harness.Sky``).

What the tests count is the core's own log: every phase change is a line
(``vehicle blue:2: configuring``), in the order it happened, so replaying
the lines gives how many of a network were configuring at every moment,
however briefly."""

from __future__ import annotations

import itertools

from swarm_harness import PHASE_LINE, Sky, handshakes_at_once, in_waves

from gcs_swarm.mavlink.states import Phase
from gcs_swarm.runtime.station import _not_ready


def test_at_most_the_window_of_a_network_configure_and_the_formation_flies() -> None:
    free = Sky(in_waves(None, duration=1.0))
    free.ready()
    free_most, _ = handshakes_at_once(free.core.log)
    assert free_most == {"blue": 3, "red": 3}  # unbounded: all three at once

    sky = Sky(in_waves(2, duration=1.0))
    sky.ready()
    most, began = handshakes_at_once(sky.core.log)
    assert most == {"blue": 2, "red": 2}
    assert sky.core.gate is not None and sky.core.gate.most == 2
    # The third of each network started only once a place was free: after one
    # of its network's first two left CONFIGURING.
    assert sorted(began) == sorted(f"{n}:{i}" for n in ("blue", "red") for i in (1, 2, 3))
    sky.start()
    sky.run_until(lambda: sky.core.finished, 3.0)
    assert sky.core.flying == set(sky.core.vehicles)
    sky.end()
    assert sky.core.outcome() == "completed"


def test_with_one_place_a_network_configures_one_vehicle_after_another() -> None:
    sky = Sky(in_waves(1, duration=1.0))
    sky.ready()
    for net in ("blue", "red"):
        phases = [
            (m[1], m[2])
            for line in sky.core.log
            if (m := PHASE_LINE.match(line)) is not None and m[1].startswith(net + ":")
        ]
        # Each vehicle's configuring is followed by its own next phase before
        # the next vehicle of the network begins.
        starts = [i for i, (_, p) in enumerate(phases) if p == Phase.CONFIGURING.value]
        assert len(starts) == 3
        for a, b in itertools.pairwise(starts):
            who = phases[a][0]
            assert any(lb == who and p != Phase.CONFIGURING.value for lb, p in phases[a + 1 : b])


def test_a_vehicle_never_heard_takes_no_place() -> None:
    mission = in_waves(1, duration=1.0)
    sky = Sky(mission)
    silent = next(k for k, vp in sky.core.vehicles.items() if vp.label == "blue:1")
    sky.set_silent(silent)
    sky.run_until(
        lambda: all(vp.phase is Phase.READY for k, vp in sky.core.vehicles.items() if k != silent),
        30.0,
    )
    gate = sky.core.gate
    assert gate is not None and not gate.waiting(silent)
    assert sky.core.vehicles[silent].phase is Phase.CONNECTING


def test_a_vehicle_lost_while_configuring_frees_its_place_and_waiting_ones_say_so() -> None:
    sky = Sky(in_waves(1, duration=1.0))
    vps = sky.core.vehicles
    blue = [k for k, vp in vps.items() if vp.label.startswith("blue:")]
    # A vehicle of blue stops answering while it configures: the one behind it
    # waits for its place until it leaves CONFIGURING (lost after 3 s unheard).
    sky.run_until(lambda: vps[blue[1]].phase is Phase.CONFIGURING, 5.0)
    sky.set_silent(blue[1])
    sky.advance(1.0)
    gate = sky.core.gate
    assert gate is not None
    assert vps[blue[0]].phase is Phase.READY and vps[blue[1]].phase is Phase.CONFIGURING
    held = vps[blue[2]]
    assert held.phase is Phase.CONNECTING and gate.waiting(held.sysid)
    assert _not_ready("not ready after 1 s", [held]) == (
        f"not ready after 1 s: vehicle {held.label} connecting "
        "(heard, waiting for a handshake place on its network)"
    )
    sky.run_until(lambda: vps[blue[1]].phase is not Phase.CONFIGURING, 10.0)
    assert vps[blue[1]].phase is Phase.LOST
    sky.run_until(lambda: held.phase is Phase.READY, 10.0)
    assert not gate.waiting(held.sysid)
