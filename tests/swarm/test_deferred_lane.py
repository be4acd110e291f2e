"""The emulator's deferred lane against every setpoint taken at once.

``EmulatorCore._deliver`` holds a streamed acceleration setpoint for a
vehicle already flying the stream (``Autopilot.stream_deferrable``): it
writes its a_ff into the fleet row and makes the autopilot's own call only
for the last one held, when anything else is asked of the autopilot
(``_fold``). Flown here twice against the station's core
(``swarm_harness.Sky``, hand clock), once with the lane and once with
``defer_stream`` off (every setpoint called at once, the emulator before
the lane), through a start, a vehicle's leave, lossy uplinks, another
tool's position target and GUIDED, a GUID_TIMEOUT lowered in flight (the
deadline the lane must not keep), hostile numbers, a radio silence longer
than GUID_TIMEOUT, a PX4 beside the ArduCopters and the end: every fleet
array after every physics step, every datagram towards the station and,
at the end, every autopilot's whole state must be the same bit for bit.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav
from swarm_harness import Radio, Sky, mission_from

from gcs_swarm.mission import Event, Mission
from sim_vehicle import Impairment
from tests.sim_vehicle.state_bits import canon


class _RecordingSky(Sky):
    """A sky that records each physics step's fleet arrays (a digest) and every
    datagram towards the station, and counts the setpoints the lane holds."""

    def __init__(self, mission: Mission, defer: bool, **kw: Any) -> None:
        super().__init__(mission, **kw)
        for emu in self.emus:
            emu.defer_stream = defer
        self.record: list[tuple[str, Any]] = []
        self.held = 0

    def to_station(self, sender: tuple[str, int], data: bytes, link: str = "") -> None:
        self.record.append(("up", (sender, data)))
        if link:
            super().to_station(sender, data, link)
        else:
            super().to_station(sender, data)

    def _to_vehicle(self, radio: Radio, data: bytes) -> None:
        super()._to_vehicle(radio, data)
        self.held += sum(v.hosted.lane_a is not None for v in self.vehicles.values())

    def advance(self, seconds: float) -> None:
        end = self.now + seconds - 1e-9
        while self.now < end:
            super().advance(self.dt)
            h = hashlib.sha256()
            for emu in self.emus:
                for name, a in sorted(vars(emu.fleet).items()):
                    if isinstance(a, np.ndarray):
                        h.update(name.encode() + a.tobytes())
            self.record.append(("step", (round(self.now, 6), h.hexdigest())))


_OPERATOR = mav.MAVLink(None, srcSystem=255, srcComponent=190)


def _operator(sky: Sky, sysid: int, msg: Any) -> None:
    """``msg`` reaches vehicle ``sysid`` from the station's address (another GCS tool)."""
    sky._to_vehicle(sky.vehicles[sysid].radio, msg.pack(_OPERATOR))


def _fly(defer: bool, raw: bool) -> tuple[_RecordingSky, list[Any]]:
    m = mission_from("example1_tetrahedron.yaml", duration=6.0)
    vehicles = tuple(
        dataclasses.replace(v, autopilot="px4", setpoint="velocity+acceleration")
        if v.sysid == 4
        else v
        for v in m.vehicles
    )
    mission = dataclasses.replace(
        m, vehicles=vehicles, events=(Event(t=1.0, action="leave", sysid=2),)
    )
    sky = _RecordingSky(mission, defer, uplink=Impairment(loss=0.1), seed=5, raw_setpoints=raw)
    sky.ready()
    sky.start()
    sky.run_until(lambda: sky.core.control.t_s >= 1.5, 4.0)
    # Another tool's position target, then GUIDED again: the stream restarts.
    hold = mav.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 3576, 1.0, 2.0, -10.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    _operator(sky, 1, hold)
    sky.advance(0.3)
    _operator(sky, 1, mav.MAVLink_set_mode_message(1, 1, 4))
    sky.advance(0.5)
    # GUID_TIMEOUT lowered in flight, with its deadline set by the old one: the
    # stream's next setpoint must lower the deadline (then a silence brakes it).
    _operator(sky, 3, mav.MAVLink_param_set_message(3, 1, b"GUID_TIMEOUT", 0.2, 9))
    sky.advance(0.5)
    # Hostile numbers (refused and counted), and a setpoint for another component.
    nan = mav.MAVLink_set_position_target_local_ned_message(
        0, 3, 1, mav.MAV_FRAME_LOCAL_NED, 3135, 0, 0, 0, 0, 0, 0, math.nan, 0.0, 0.0, 0, 0
    )
    other = mav.MAVLink_set_position_target_local_ned_message(
        0, 3, 7, mav.MAV_FRAME_LOCAL_NED, 3135, 0, 0, 0, 0, 0, 0, 3.0, 0.0, 0.0, 0, 0
    )
    for msg in (nan, other, nan):
        _operator(sky, 3, msg)
        sky.advance(0.04)
    sky.set_silent(3)  # past GUID_TIMEOUT: it brakes; past the stale timeout: it leaves
    sky.advance(1.5)
    sky.set_silent(3, False)
    sky.run_until(lambda: sky.core.finished, 6.0)
    sky.end()
    for emu in sky.emus:
        emu.fold()
    states = [canon(vars(v.ap), skip={"version"}) for emu in sky.emus for v in emu.rows]
    return sky, states


@pytest.mark.parametrize("raw", [True, False])
def test_the_deferred_lane_flies_as_every_setpoint_taken_at_once(raw: bool) -> None:
    deferred, deferred_states = _fly(True, raw)
    direct, direct_states = _fly(False, raw)
    assert direct.held == 0
    # The lane held setpoints, many of them: 3 ArduCopters streaming for seconds.
    assert deferred.held > 300, deferred.held
    steps = sum(kind == "step" for kind, _ in deferred.record)
    assert steps > 300 and len(deferred.record) > 2 * steps
    assert len(deferred.record) == len(direct.record)
    for k, (a, b) in enumerate(zip(deferred.record, direct.record, strict=True)):
        assert a == b, f"record {k} of {len(direct.record)}: {a[0]} differs"
    assert deferred_states == direct_states
    rejected = [v.ap.rejected for v in deferred.emus[0].rows]
    assert rejected == [v.ap.rejected for v in direct.emus[0].rows] and sum(rejected) >= 2
