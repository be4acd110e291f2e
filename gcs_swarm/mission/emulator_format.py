"""The ``emulator:`` section of the mission format: the bundled emulator that
flies the vehicles on ``link: sim`` (mode, dynamics, noise, homes, endpoints,
seeded impairments; docs/emulator.md). Declared with ``declarations`` and
``scalars``; assembled into the whole file by ``format``.
"""

from __future__ import annotations

from typing import Any

import yaml

from gcs_swarm.mission.addresses import check_host
from gcs_swarm.mission.bounds import POSITION_LIMIT_M, SPEED_LIMIT_MPS
from gcs_swarm.mission.context import Context
from gcs_swarm.mission.declarations import INVALID, Key, Obj
from gcs_swarm.mission.model import Emulator, Impairments
from gcs_swarm.mission.scalars import (
    Bool,
    Enum,
    Int,
    NonNeg,
    Num,
    Pos,
    Str,
    Vec3,
)

__all__ = ["EMULATOR"]

_EMU = Emulator()
_IMP = Impairments()


def _build_emulator(v: dict[str, Any], ctx: Context, node: yaml.Node, path: str) -> Any:
    ok = True
    if v["mode"] == "lockstep" and v["speedup"] != 1.0:
        ctx.add(
            ctx.line_of("emulator.speedup"),
            "emulator.speedup",
            "speedup applies to mode realtime; lockstep runs as fast as the station answers",
        )
        ok = False
    if v["dynamics"] == "ideal" and v["lag"] not in (None, 0.0):
        ctx.add(
            ctx.line_of("emulator.lag"),
            "emulator.lag",
            "ideal dynamics have no lag; use dynamics ardupilot-like",
        )
        ok = False
    return Emulator(**v) if ok else INVALID


EMULATOR = Obj(
    name="emulator",
    cls=Emulator,
    build=_build_emulator,
    keys=(
        Key(
            "mode",
            Enum(choices=("lockstep", "realtime")),
            _EMU.mode,
            "lockstep: one step per answered telemetry; realtime: wall clock x speedup",
        ),
        Key(
            "speedup",
            Num(lo=0.0, hi=1000.0, lo_open=True),
            _EMU.speedup,
            "realtime only: simulated seconds per wall-clock second",
        ),
        Key(
            "dynamics",
            Enum(choices=("ideal", "ardupilot-like")),
            _EMU.dynamics,
            "ideal: exact double integrator; ardupilot-like: lagged",
        ),
        Key(
            "lag",
            Num(lo=0.0, hi=5.0, nullable=True),
            _EMU.lag,
            "first-order acceleration lag [s]; null: the preset's (0.1 for ardupilot-like)",
        ),
        Key("accel_max", Pos(nullable=True), None, "clamp on |acceleration| [m/s^2]; null: 5"),
        Key(
            "ekf_ready_delay", NonNeg(3600.0), _EMU.ekf_ready_delay, "arming refused this long [s]"
        ),
        Key("noise_pos", NonNeg(1000.0), _EMU.noise_pos, "std of position noise on telemetry [m]"),
        Key(
            "noise_vel",
            NonNeg(SPEED_LIMIT_MPS),
            _EMU.noise_vel,
            "std of velocity noise on telemetry [m/s]",
        ),
        Key(
            "velocity_bias_ned",
            Vec3("[north, east, down] m/s", limit=10.0),
            None,
            "constant added to every reported velocity; absent: ArduCopter SITL's figure "
            "for ardupilot-like, none for ideal",
        ),
        Key(
            "velocity_bias_flip",
            Num(lo=0.0, hi=1e6, nullable=True),
            None,
            "boot time [s] at which that bias starts to reverse (tau 14 s); 0: never; "
            "absent: ArduCopter SITL's 304 s for ardupilot-like, never for ideal",
        ),
        Key(
            "heartbeats",
            Enum(choices=("together", "spread")),
            _EMU.heartbeats,
            "together: every vehicle's HEARTBEAT in one step (a SITL swarm); "
            "spread: each at its own phase (a fleet booted one by one)",
        ),
        Key(
            "overrun",
            Enum(choices=("catch_up", "skip")),
            _EMU.overrun,
            "realtime held behind the wall clock: catch_up: every missed step's messages "
            "(as SITL); skip: physics alone, then each stream once (as an autopilot)",
        ),
        Key(
            "ground",
            Num(lo=-POSITION_LIMIT_M, hi=POSITION_LIMIT_M),
            _EMU.ground,
            "mission-frame z of the sim vehicles' homes [m]",
        ),
        Key(
            "origin_spread", NonNeg(1000.0), _EMU.origin_spread, "east spacing of default homes [m]"
        ),
        Key(
            "spawn",
            Enum(choices=("ground", "air")),
            _EMU.spawn,
            "ground: landed at home, full start-up; air: hovering at the start, armed, GUIDED",
        ),
        Key(
            "host",
            Str(what="an IP address or a host name", check=check_host),
            _EMU.host,
            "address the emulator's endpoints bind to",
        ),
        Key("base_port", Int(0, 65535), _EMU.base_port, "k-th sim vehicle on base_port + 10 k"),
        Key("shared", Bool(), _EMU.shared, "all sim vehicles on one endpoint (by system id)"),
        Key(
            "impairments",
            Obj(
                name="impairments",
                cls=Impairments,
                keys=(
                    Key(
                        "loss",
                        Num(lo=0.0, hi=1.0, hi_open=True),
                        _IMP.loss,
                        "probability a packet is lost",
                    ),
                    Key("delay", Num(lo=0.0, hi=10.0), _IMP.delay, "added one-way delay [s]"),
                    Key(
                        "jitter", Num(lo=0.0, hi=10.0), _IMP.jitter, "random extra delay, up to [s]"
                    ),
                    Key(
                        "duplicate",
                        Num(lo=0.0, hi=1.0),
                        _IMP.duplicate,
                        "probability a packet is sent twice",
                    ),
                    Key(
                        "seed",
                        Int(0, 2**63 - 1),
                        _IMP.seed,
                        "seed of the impairment random numbers",
                    ),
                ),
            ),
            Impairments,
            "seeded link impairments, both directions",
        ),
    ),
)
