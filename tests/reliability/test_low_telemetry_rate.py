"""A stream rate lowered on the way is noticed (issue 15 item 11).

Through MAVProxy (which asks 4 Hz every 15 s) the control loop fell from
20 Hz to 4 Hz with no word. Now each flying vehicle's LOCAL_POSITION_NED
rate is measured over 2 s windows of its own clock; a low window asks for
the mission rate again (MAV_CMD_SET_MESSAGE_INTERVAL), and a rate that
stays low is one warning, in the status line and in the summary.

Unit: the protocol alone, a hand-advanced clock. Closed loop: the emulator
serves at most 5 Hz (``SIM_LPN_MAX_HZ``, a router's cap) against a 50 Hz
mission, lockstep.
"""

from __future__ import annotations

import asyncio

from gcs_swarm.mavlink import Phase, VehicleProtocol
from gcs_swarm.mavlink.builders import MAV_CMD_SET_MESSAGE_INTERVAL, MSG_ID_LOCAL_POSITION_NED
from gcs_swarm.mavlink.vehicle import RATE_WINDOW_MS
from tests.mavlink.test_vehicle_protocol import _flying
from tests.mavlink.vehicle_harness import commands, make, pos
from tests.station.station_harness import fly, lockstep_config, mission_from


def _feed(vp: VehicleProtocol, t0_ms: int, hz: float, seconds: float) -> int:
    step = round(1000 / hz)
    t = t0_ms
    while t < t0_ms + seconds * 1000:
        t += step
        vp.handle_message(pos(t, (-100.0, 5.0, -22.0)), t * 1e-3)
    return t


def test_a_low_rate_is_asked_again_each_window_and_warned_once() -> None:
    vp = make(control_rate_hz=20.0, stale_timeout_s=5.0, heartbeat_timeout_s=60.0)
    _flying(vp, 0.0)
    assert vp.phase is Phase.FLYING
    t = _feed(vp, 1000, 20.0, 4.0)  # as asked: nothing
    assert vp.telemetry_rate_hz is not None and abs(vp.telemetry_rate_hz - 20.0) < 0.6
    assert not commands(vp.take_outbound(), MAV_CMD_SET_MESSAGE_INTERVAL)
    t = _feed(vp, t, 4.0, 4 * RATE_WINDOW_MS / 1000)  # a router's 4 Hz for four windows
    asks = commands(vp.take_outbound(), MAV_CMD_SET_MESSAGE_INTERVAL)
    # Every low window asks (at least three of the four: the first may straddle).
    assert len(asks) >= 3 and vp.rate_requests == len(asks)
    assert all(a["param1"] == MSG_ID_LOCAL_POSITION_NED and a["param2"] == 50_000 for a in asks)
    warnings = [e.text for e in vp.take_events() if e.kind == "warning"]
    assert len(warnings) == 1 and "below the mission rate 20 Hz" in warnings[0]
    assert vp.rate_low and abs(vp.telemetry_rate_min_hz - 4.0) < 0.3
    _feed(vp, t, 20.0, 4.0)  # back to the mission rate
    assert not vp.rate_low
    assert any("back at" in e.text for e in vp.take_events())


def test_a_router_capping_the_stream_is_reported_in_the_summary() -> None:
    mission = mission_from("example1_octahedron.yaml", n=2, duration=8.0)
    cfg = lockstep_config(mission, params={"SIM_LPN_MAX_HZ": 5.0})
    flown = asyncio.run(fly(mission, cfg, timeout_s=90.0))
    s = flown.ok
    assert s.outcome == "completed"
    rate = mission.settings.rate
    for v in s.vehicles:
        # 5 Hz served against the mission's rate: seen (to 0.5 Hz: one report
        # in a 2 s window), asked again each window, warned once.
        assert v.telemetry_rate_min_hz is not None and abs(v.telemetry_rate_min_hz - 5.0) < 0.5
        assert v.rate_requests >= 3
    log = "\n".join(s.log)
    assert log.count(f"below the mission rate {rate:g} Hz") == len(s.vehicles)
    assert "telemetry as low as 5.0 Hz" in s.format()
