"""Link shards on the hand clock (tests/swarm/swarm_harness.py): each shard a
``Sky`` of its own vehicles, one ``ControllerCore``, the wire's bytes
between them, as a shard process (``runtime/shard.py``) and the controller
(``runtime/sharded.py``) exchange them over Zenoh, without Zenoh, sockets
or sleeps. ``recording`` gives a one-process station's steps to compare."""

from __future__ import annotations

from collections.abc import Callable, Collection

from swarm_harness import Sky

from gcs_swarm.control.loop import ControlLoop
from gcs_swarm.mavlink.states import Phase
from gcs_swarm.mission import Mission
from gcs_swarm.swarm.controller import ControllerCore
from gcs_swarm.swarm.shard import ShardSide
from gcs_swarm.swarm.shard_wire import decode_reply, decode_state, encode_reply, encode_state
from gcs_swarm.swarm.step import Write

Steps = list[tuple[float, tuple[int, ...], bytes]]
"""Each step of the law: its mission time, who flew, every vehicle's latest
command's bytes (``StepResult.accel_mps2``)."""


def _record(steps: Steps, control: ControlLoop) -> None:
    last = control.last
    if last is not None and control.steps > len(steps):
        steps.append((last.t_s, last.ids, last.accel_mps2.tobytes()))


def recording(sky: Sky) -> Steps:
    """Every step ``sky``'s own station takes from now on (``Steps``)."""
    steps: Steps = []
    plain = sky.control_step

    def step(now: float, write: Write) -> None:
        plain(now, write)
        _record(steps, sky.core.control)

    sky.control_step = step
    return steps


class Split:
    """``mission``'s vehicles as shards (``shards[i]``: shard i's keys, as
    ``run_sharded`` assigns whole networks), a ``Sky`` each on one clock,
    and their controller (real time: ``lockstep=False``), stepping per
    network when the mission says ``step: network``. ``stagger``: each
    network's reports reach its shard before the next network's emulator
    steps (``Sky``'s, here across the shards' skies)."""

    def __init__(
        self, mission: Mission, shards: list[Collection[int]], *, stagger: bool = False
    ) -> None:
        self.skies = [Sky(mission, keys=keys, stagger=stagger) for keys in shards]
        s = mission.settings
        self.sides = [ShardSide(sky.core, i, s.stale_timeout) for i, sky in enumerate(self.skies)]
        self.ctl = ControllerCore(mission.law, {v.key: v.q for v in mission.vehicles}, s.rate,
                                  shards=len(shards), duration_s=s.duration,
                                  stale_timeout_s=s.stale_timeout, lockstep=False,
                                  step_per_network=s.step == "network")  # fmt: skip
        self.steps: Steps = []
        """The controller's steps (``Steps``)."""
        for i, sky in enumerate(self.skies):
            sky.control_step = self._step(i)

    def _step(self, i: int) -> Callable[[float, Write], None]:
        def step(now: float, write: Write) -> None:
            batch = self.sides[i].take_state(now)
            if batch is None:
                return
            ctl = self.ctl
            ctl.receive_state(decode_state(encode_state(batch)), now)
            if not ctl.step_wanted:
                return
            for reply in ctl.control_step(now):
                j = reply.shard
                self.sides[j].apply(decode_reply(encode_reply(reply)), now, self.skies[j]._write)
            _record(self.steps, ctl.control)
            if ctl.finished:
                for sky in self.skies:
                    sky.core.finished = True

        return step

    @property
    def now(self) -> float:
        return self.skies[0].now

    def together(self, done: Callable[[], bool], limit_s: float = 30.0) -> None:
        """The shards' skies a physics step at a time on one clock."""
        skies = self.skies
        while not done():
            assert skies[0].now < limit_s, [sky.phases() for sky in skies]
            for sky in skies:
                sky.advance(sky.dt)
            assert all(sky.now == skies[0].now for sky in skies)

    def ready(self) -> None:
        """Every shard's vehicles READY, the controller in the tightest envelope."""
        skies = self.skies
        self.together(lambda: all(p is Phase.READY for sky in skies for p in sky.phases().values()))
        envelope = skies[0].core.apply_envelope()
        for sky in skies[1:]:
            envelope = envelope.tighter(sky.core.apply_envelope())
        self.ctl.set_envelope(envelope)

    def start(self) -> None:
        """The formation starts in the controller, then on every shard (the
        controller's start message: ``ShardedRun.start``)."""
        self.ctl.start(self.now, {i: len(sky.core.members) for i, sky in enumerate(self.skies)})
        for side, sky in zip(self.sides, self.skies, strict=True):
            sky.core.start(sky.now)  # Station.begin, the opening batch, then what it held
            self.ctl.receive_state(decode_state(encode_state(side.opening(sky.now))), sky.now)
            sky.transfer()
