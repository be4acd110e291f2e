"""When each emulated vehicle sends its periodic HEARTBEAT
(``EmulatorConfig.heartbeats``).

A SITL swarm started by one script sends its HEARTBEATs together (4
instances within 6 ms, every second: docs/mavlink-protocol.md), and so do an
emulator's vehicles by default (``"together"``). A fleet's vehicles booted
one by one keep their own phases: ``"spread"`` gives each vehicle its own,
drawn from the emulator's seed and the vehicle's key
(``vehicles.heartbeat_phase_s``). At 1,500 vehicles in networks of 250,
"together" makes one step a second of each network 7-8 ms long in the
emulator and puts 250 HEARTBEATs in one period at the station
(benchmarks/README.md, twelfth session).

A core of 100 airborne vehicles on one port, stepped by hand at 50 Hz for
3.5 s, the datagrams of each step parsed. Spread: every vehicle still sends
one HEARTBEAT a second (50 steps apart), its first within the first second,
at most 8 of the 100 in one step (a uniform draw puts 2 in a step on
average; this seed's fullest step has 5; with every phase 0 all 100 go in
one step, which the test was checked to catch); the same steps in another
core of the same seed, other steps under another seed; ArduCopter and PX4,
real time and lockstep alike. Together: all 100 in the same steps, a second
apart, as before the option.
"""

from __future__ import annotations

import itertools
from collections import Counter
from typing import Literal

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle import EmulatorConfig, VehicleSpec
from sim_vehicle.core import EmulatorCore
from sim_vehicle.vehicles import heartbeat_phase_s
from tests.sim_vehicle.test_sv_deferred_lane import _Port

N = 100
STEPS = 175  # 3.5 s at 50 Hz


def _heartbeat_steps(
    seed: int,
    autopilot: Literal["ardupilot", "px4"],
    clock: Literal["realtime", "lockstep"],
    heartbeats: Literal["together", "spread"] = "spread",
) -> dict[int, list[int]]:
    """Each vehicle's steps that sent a HEARTBEAT."""
    specs = tuple(
        VehicleSpec(sysid=s, start_ned_m=(2.0 * s, 0.0, -5.0), airborne=True, autopilot=autopilot)
        for s in range(1, N + 1)
    )
    cfg = EmulatorConfig(vehicles=specs, clock=clock, seed=seed, heartbeats=heartbeats)
    core, port = EmulatorCore(cfg), _Port()
    core.ports.append(port)
    for spec in cfg.vehicles:
        core.add(spec, port, initial=True, enc=mav.MAVLink(None, spec.sysid, spec.compid))
    parser = mav.MAVLink(None)
    steps: dict[int, list[int]] = {s: [] for s in range(1, N + 1)}
    for k in range(STEPS):
        before = len(port.sent)
        core.step()
        for data in port.sent[before:]:
            for m in parser.parse_buffer(data) or []:
                if m.get_msgId() == mav.MAVLINK_MSG_ID_HEARTBEAT:
                    steps[m.get_srcSystem()].append(k)
    return steps


@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_each_vehicle_sends_its_heartbeat_at_its_own_phase(
    autopilot: Literal["ardupilot", "px4"], clock: Literal["realtime", "lockstep"]
) -> None:
    steps = _heartbeat_steps(0, autopilot, clock)
    for sysid, ks in steps.items():
        assert len(ks) >= 3, (sysid, ks)
        assert ks[0] <= 50, (sysid, ks)  # its first within the first second
        assert {b - a for a, b in itertools.pairwise(ks)} <= {49, 50, 51}, (sysid, ks)
    per_step = Counter(k for ks in steps.values() for k in ks)
    assert max(per_step.values()) <= 8, per_step.most_common(3)
    assert len({ks[0] for ks in steps.values()}) >= 30  # the first ones spread over the second
    # repeatable: the same seed, the same steps; another seed, other steps
    assert _heartbeat_steps(0, autopilot, clock) == steps
    assert _heartbeat_steps(1, autopilot, clock) != steps


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_together_every_vehicle_sends_its_heartbeat_in_the_same_steps(
    autopilot: Literal["ardupilot", "px4"],
) -> None:
    steps = _heartbeat_steps(0, autopilot, "realtime", "together")
    assert EmulatorConfig().heartbeats == "together"  # SITL's, the default
    first = steps[1]
    assert len(first) >= 3
    assert {b - a for a, b in itertools.pairwise(first)} <= {49, 50, 51}
    assert all(ks == first for ks in steps.values())


def test_the_phase_is_the_vehicles_own_draw_in_the_first_second() -> None:
    cfg = EmulatorConfig(vehicles=(), heartbeats="spread")
    phases = [heartbeat_phase_s(cfg, VehicleSpec(sysid=s)) for s in range(1, 251)]
    assert all(0.0 <= p < 1.0 for p in phases)
    assert len(set(phases)) == len(phases)
    assert phases == [heartbeat_phase_s(cfg, VehicleSpec(sysid=s)) for s in range(1, 251)]
    other = EmulatorConfig(vehicles=(), seed=7, heartbeats="spread")
    together = EmulatorConfig(vehicles=())
    assert {heartbeat_phase_s(together, VehicleSpec(sysid=s)) for s in range(1, 251)} == {0.0}
    assert phases != [heartbeat_phase_s(other, VehicleSpec(sysid=s)) for s in range(1, 251)]


def test_sim_vehicle_takes_the_choice_on_its_command_line() -> None:
    from sim_vehicle.cli import build_config, parse_args

    assert build_config(parse_args(["--count", "2"])).heartbeats == "together"
    cfg = build_config(parse_args(["--count", "2", "--heartbeats", "spread"]))
    assert cfg.heartbeats == "spread"
    with pytest.raises(SystemExit):
        parse_args(["--heartbeats", "staggered"])
