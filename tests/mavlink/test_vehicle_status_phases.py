"""The status streams asked at each vehicle's own phase of their interval
(``VehicleProtocol.status_phase``, ``StationConfig.status_phases``): the
command queue's ``not_before`` and the start-up that uses it, on a hand
clock. The whole chain against the real emulator: tests/station/test_status_phases_emulator.py."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest

from gcs_swarm.control.params import LawConfig
from gcs_swarm.mavlink import MessageSpec, Phase
from gcs_swarm.mavlink.builders import MAV_CMD_SET_MESSAGE_INTERVAL
from gcs_swarm.mavlink.commands import CommandQueue
from gcs_swarm.mavlink.inbound import CommandAck, ParamValue
from gcs_swarm.mission.model import KEY_STRIDE
from gcs_swarm.runtime.config import StationConfig, VehiclePlan
from tests.mavlink.vehicle_harness import STABILIZE, SYS, hb, make


def _spec(name: str) -> MessageSpec:
    return MessageSpec("COMMAND_LONG", {"command": 1, "label": name})


def test_a_command_not_before_a_time_waits_for_it_and_the_ones_behind_it_too() -> None:
    out: list[MessageSpec] = []
    q = CommandQueue(out, timeout_s=1.0, attempts=3)
    done: list[tuple[str, int, float]] = []
    q.push(10.0, "a", lambda: _spec("a"), lambda r, t: done.append(("a", r, t)), command=1)
    q.push(10.0, "b", lambda: _spec("b"), lambda r, t: done.append(("b", r, t)), command=1,
           not_before=10.3)  # fmt: skip
    q.push(10.0, "c", lambda: _spec("c"), lambda r, t: done.append(("c", r, t)), command=1)
    assert [m["label"] for m in out] == ["a"]
    q.on_ack(1, 0, 10.05)  # "a" answered: "b" may not go yet, nor "c" behind it
    assert [m["label"] for m in out] == ["a"] and q.busy
    assert q.next_deadline() == 10.3
    q.handle_timer(10.29)
    assert [m["label"] for m in out] == ["a"]
    q.handle_timer(10.3)
    assert [m["label"] for m in out] == ["a", "b"]
    assert q.next_deadline() == pytest.approx(11.3)  # now b's answer timeout
    q.on_ack(1, 0, 10.32)
    assert [m["label"] for m in out] == ["a", "b", "c"]
    q.on_ack(1, 0, 10.34)
    assert [d[0] for d in done] == ["a", "b", "c"] and not q.busy
    assert q.next_deadline() is None


def test_a_waiting_command_is_sent_at_once_when_its_time_has_come_on_push() -> None:
    out: list[MessageSpec] = []
    q = CommandQueue(out, timeout_s=1.0, attempts=3)
    q.push(5.0, "x", lambda: _spec("x"), lambda r, t: None, command=1, not_before=5.0)
    assert [m["label"] for m in out] == ["x"]


def _configure_until_streams(phase: float, t0: float) -> tuple[Any, list[float], list[float]]:
    """A vehicle of ``status_phase`` ``phase`` from its first HEARTBEAT at ``t0``,
    each request answered when it goes out, the timer called when it asks:
    returns the vehicle and the times each SET_MESSAGE_INTERVAL went out."""
    vp = make()
    vp.status_phase = phase
    vp.handle_message(hb(STABILIZE), t0)
    assert vp.phase is Phase.CONFIGURING
    sent: list[tuple[float, float]] = []  # (time, message id)
    now = t0
    for _ in range(200):
        out = vp.take_outbound()
        for m in out:
            if m.name == "COMMAND_LONG" and m["command"] == MAV_CMD_SET_MESSAGE_INTERVAL:
                sent.append((now, m["param1"]))
                vp.handle_message(CommandAck(SYS, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0), now)
            elif m.name in ("PARAM_SET", "PARAM_REQUEST_READ"):
                value = m["param_value"] if m.name == "PARAM_SET" else 0.0
                vp.handle_message(ParamValue(SYS, 1, str(m["param_id"]), value), now)
        if vp.phase is not Phase.CONFIGURING:
            break
        if not out:
            due = vp.next_deadline()
            assert due is not None and due > now
            now = due
            vp.handle_timer(now)
    return vp, [t for t, _ in sent], [i for _, i in sent]


@pytest.mark.parametrize("phase", [0.0, 0.25, 0.5, 0.9])
def test_the_status_streams_are_asked_a_phase_of_their_interval_after_the_start(
    phase: float,
) -> None:
    t0 = 100.0
    vp, times, ids = _configure_until_streams(phase, t0)
    # LOCAL_POSITION_NED at once; EKF_STATUS_REPORT, GPS_RAW_INT and
    # EXTENDED_SYS_STATE (ArduCopter's) at phase x 0.5 s (2 Hz), one after another.
    assert ids == [32, 193, 24, 245]
    assert times[0] == t0
    assert times[1:] == [pytest.approx(t0 + phase * 0.5)] * 3
    # The start-up goes on once the parameters behind them are set.
    assert vp.phase is Phase.SETTING_GUIDED, vp.failure


def test_a_status_phase_outside_zero_to_one_is_refused() -> None:
    vp = make()
    with pytest.raises(ValueError, match="status_phase"):
        type(vp)(SYS, vp.config, goto_m=(0.0, 0.0, 0.0), status_phase=1.0)
    with pytest.raises(ValueError, match="status_phase"):
        type(vp)(SYS, vp.config, goto_m=(0.0, 0.0, 0.0), status_phase=-0.1)


def test_each_networks_vehicles_spread_over_the_interval_in_mission_order() -> None:
    def plan(key: int) -> VehiclePlan:
        return VehiclePlan(sysid=key, link="udpout:127.0.0.1:1", start_m=(0.0, 0.0, 0.0), q=1.0)

    # Network 0 has four vehicles, network 1 (keys + KEY_STRIDE) two, interleaved.
    keys = [1, KEY_STRIDE + 1, 2, 3, KEY_STRIDE + 2, 4]
    cfg = StationConfig(vehicles=tuple(plan(k) for k in keys), law=LawConfig())
    phases = cfg.status_phases()
    assert phases == {1: 0.0, 2: 0.25, 3: 0.5, 4: 0.75, KEY_STRIDE + 1: 0.0, KEY_STRIDE + 2: 0.5}
    assert all(0.0 <= p < 1.0 and math.isfinite(p) for p in phases.values())
    # In lockstep all at once: the run stays repeatable (the docstring).
    locked = dataclasses.replace(cfg, lockstep=True).status_phases()
    assert locked == dict.fromkeys(keys, 0.0)
