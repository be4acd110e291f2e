"""Summary figures on synthetic flight records with known answers."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.control.params import Box
from gcs_swarm.report import FlightRecorder, TelemetryCounter, summarize_record, write_json

R6 = 2.48418  # Example 1, N = 6: the octahedron radius (formation-law.md s10)
OCTA = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
DT = 0.02  # s, a 50 Hz control period


def _octahedron_run(decay_s: float = 2.0, steps: int = 1001) -> FlightRecorder:
    """Six vehicles on an octahedron around a leader moving at (1, 0.5, 0) m/s,
    radius R(t) = R6 (1 + 0.5 exp(-t / decay_s))."""
    rec = FlightRecorder(name="octahedron", rate_hz=50.0)
    ids = [1, 2, 3, 4, 5, 6]
    for sysid in ids:
        rec.member(0.0, sysid, True)
    for k in range(steps):
        t = k * DT
        leader = np.array([1.0, 0.5, 0.0]) * t
        r = R6 * (1.0 + 0.5 * math.exp(-t / decay_s))
        rec.step(t, ids, leader + r * OCTA, leader, "formation", 0,
                 accel_mps2=np.full((6, 3), 0.1) * (k == 10))  # fmt: skip
    return rec


def test_octahedron_distances_radius_and_time_to_form() -> None:
    s = summarize_record(_octahedron_run().record())
    o = s["overall"]
    # Leader stored at float32: a few 1e-6 m at |leader| ~ 22 m.
    assert o["final_radius_m"]["min"] == pytest.approx(R6 * (1 + 0.5 * math.exp(-10.0)), abs=1e-5)
    d = np.array(o["final_pairwise_distances_m"])
    rf = R6 * (1 + 0.5 * math.exp(-10.0))
    np.testing.assert_allclose(d[:12], rf * math.sqrt(2), rtol=1e-12)
    np.testing.assert_allclose(d[12:], 2 * rf, rtol=1e-12)
    assert [g["count"] for g in o["distance_groups"]] == [12, 3]
    # |R(t) - R(T)| <= 1 % R(T) (distances scale alike) once
    # exp(-t/2) <= 0.02 (1 + 0.5 e^-10) + e^-10, t = 7.8194 s; the figure is the
    # first 50 Hz sample after the last one outside the band.
    e10 = math.exp(-10.0)
    t_form = -2.0 * math.log(0.02 * (1 + 0.5 * e10) + e10)
    expected = math.ceil(t_form / DT) * DT
    assert o["time_to_form_s"] == pytest.approx(expected, abs=1e-9)
    for v in s["vehicles"].values():
        assert v["time_to_form_s"] == pytest.approx(expected, abs=1e-9)
        assert len(v["final_distances_m"]) == 5
    # Minimum separation: the closest neighbours at the end (R sqrt 2 shrinks).
    assert o["min_separation_m"] == pytest.approx(rf * math.sqrt(2), rel=1e-9)
    assert o["min_separation_at_s"] == pytest.approx(20.0)
    # Peak commanded acceleration: |(0.1, 0.1, 0.1)| at step 10, float32.
    assert o["peak_accel_mps2"] == pytest.approx(math.sqrt(3) * 0.1, rel=1e-6)
    assert o["peak_accel_at_s"] == pytest.approx(0.2)
    assert o["min_clearance_m"] is None and o["behaviour_switches"] == []
    assert [e["action"] for e in o["events"]] == ["join"] * 6


def test_final_radius_window_is_the_last_20_s_of_the_radius() -> None:
    """R(t) = R6 (1 + 0.5 exp(-t/2)) over 0..40 s: the window is t in [20, 40] s,
    its mean the integral of R over it / 20 (to the 50 Hz sampling's rectangle-rule
    error, e^-10 R6 / 4 ~ 3e-5 m: bound 1e-4 m), its max the first sample's R(20)."""
    s = summarize_record(_octahedron_run(steps=2001).record())
    e10, e20 = math.exp(-10.0), math.exp(-20.0)
    mean = R6 * (1.0 + 0.5 * 2.0 * (e10 - e20) / 20.0)
    for v in s["vehicles"].values():
        w = v["final_radius_window_m"]
        assert w["window_s"] == pytest.approx(20.0, abs=1e-9)
        assert w["mean"] == pytest.approx(mean, abs=1e-4)
        assert w["max"] == pytest.approx(R6 * (1 + 0.5 * e10), abs=1e-5)
        assert w["min"] == pytest.approx(R6 * (1 + 0.5 * e20), abs=1e-5)
        assert 0.0 < w["std"] < w["max"] - w["min"]
    assert s["overall"]["final_radius_window_m"]["mean"] == pytest.approx(mean, abs=1e-4)


def test_trajectory_entering_a_box_has_negative_clearance_at_the_right_time() -> None:
    # Vehicle 1 flies along x through a box (centre 0, half-extents 1) at 1 m/s:
    # clearance |x| - 1 outside, max(|x|, |y|, |z|) - 1 inside: -1 at x = 0.
    box = Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    rec = FlightRecorder(boxes=(box,))
    for k in range(501):
        t = k * DT
        p = np.array([[t - 5.0, 0.0, 0.0], [t - 5.0, 0.0, 3.0]])
        rec.step(t, [1, 2], p, (t - 5.0, 0.0, 1.5), "formation", 0)
    s = summarize_record(rec.record())
    o, v1, v2 = s["overall"], s["vehicles"]["1"], s["vehicles"]["2"]
    assert o["min_clearance_m"] == pytest.approx(-1.0, abs=1e-12)
    assert o["min_clearance_at_s"] == pytest.approx(5.0, abs=1e-9)
    assert o["min_clearance_vehicle"] == 1
    assert v1["min_clearance_m"] == pytest.approx(-1.0, abs=1e-12)
    assert v2["min_clearance_m"] == pytest.approx(2.0, abs=1e-12)  # 3 m up, box top at 1
    assert o["min_separation_pair"] == [1, 2] and o["min_separation_m"] == pytest.approx(3.0)


def test_setpoint_rate_and_largest_gap() -> None:
    rec = FlightRecorder()
    rec.member(0.0, 7, True)
    skipped = set(range(100, 110))  # 10 telemetry cycles unanswered: a 0.22 s gap
    for k in range(300):
        sent = () if k in skipped else (7,)
        rec.step(k * DT, [7], [[0.0, 0.0, 0.0]], (0, 0, 0), "formation", 0,
                 accel_mps2=[[0.0, 0.0, 1.0]], sent=sent)  # fmt: skip
    sp = summarize_record(rec.record())["vehicles"]["7"]["setpoints"]
    assert sp["sent"] == 290
    assert sp["largest_gap_s"] == pytest.approx(11 * DT, abs=1e-9)
    assert sp["largest_gap_at_s"] == pytest.approx(99 * DT, abs=1e-9)
    # 1 / mean interval: 289 intervals over 299 periods.
    assert sp["rate_hz"] == pytest.approx(289 / (299 * DT), rel=1e-9)


def test_gaps_do_not_span_a_leave_and_rejoin() -> None:
    rec = FlightRecorder()
    for k in range(200):
        t = k * DT
        ids = [1] if 50 <= k < 150 else [1, 2]
        rec.step(t, ids, np.zeros((len(ids), 3)) + np.arange(len(ids))[:, None], (0, 0, 0),
                 "formation", 0, accel_mps2=np.zeros((len(ids), 3)))  # fmt: skip
    sp = summarize_record(rec.record())["vehicles"]["2"]["setpoints"]
    assert sp["largest_gap_s"] == pytest.approx(DT)  # out of the formation is not a gap


def test_behaviour_switches_and_safety_interventions() -> None:
    rec = FlightRecorder(safety=True)
    for k in range(100):
        beh, ep = ("avoidance", 1) if 30 <= k < 60 else ("formation", 0 if k < 30 else 1)
        cor = [0.5 if k == 40 else 0.0, 0.0]
        rec.step(k * DT, [1, 2], [[0, 0, 0], [5, 0, 0]], (1, 0, 0), beh, ep, correction_mps2=cor)
    s = summarize_record(rec.record())
    o = s["overall"]
    assert o["behaviour_switches"] == [
        {"t_s": pytest.approx(0.6), "event": "start", "episode": 1},
        {"t_s": pytest.approx(1.2), "event": "end", "episode": 1},
    ]
    assert o["avoidance_episodes"] == 1
    assert o["safety"] == {"applied": True, "interventions": 1, "vehicle_steps": 200,
                           "max_correction_mps2": 0.5}  # fmt: skip
    assert s["vehicles"]["1"]["safety_interventions"] == 1
    assert s["vehicles"]["2"]["safety_interventions"] == 0


def test_telemetry_loss_from_sequence_numbers() -> None:
    tc = TelemetryCounter()
    seqs = [*range(250, 256), *range(0, 10)]  # wraps at 255
    for s in seqs:
        if s not in (253, 3, 4):  # three lost
            tc.add(1, 1, s, 32)
    tc.add(1, 1, 9, 32)  # a duplicate of the newest
    tc.add(1, 1, 2, 0)  # a duplicate of an older one (heard before)
    tc.add(1, 1, 4, 0)  # late (reordered): skipped when 5 came, so no longer lost
    tc.add(1, 1, 4, 0)  # and now a duplicate
    tc.add(1, 2, 0, 0)  # another component has its own sequence
    c = tc.counts[1]
    assert (c.received, c.lost, c.duplicates, c.late, c.local_position) == (18, 2, 3, 1, 14)
    assert c.loss_fraction == pytest.approx(2 / 20)


def test_reordered_frames_are_not_lost_and_far_gaps_are() -> None:
    """Frames recorded out of wire order (a station handing a datagram's
    frames on in two passes, or a network that reorders) are late, not lost;
    a real gap is still lost."""
    tc = TelemetryCounter()
    for s in (10, 14, 11, 12, 13, 15):
        tc.add(7, 1, s, 32)
    c = tc.counts[7]
    assert (c.received, c.lost, c.late, c.duplicates) == (6, 0, 3, 0)
    tc.add(7, 1, 15 + 100, 32)  # 99 skipped
    assert c.lost == 99


def test_json_has_no_nan_or_infinity(tmp_path: Path) -> None:
    rec = FlightRecorder()
    rec.step(0.0, [1], [[0.0, 0.0, 0.0]], (0, 0, 0), "formation", 0)  # alone: no separation
    path = tmp_path / "summary.json"
    write_json(summarize_record(rec.record()), path)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    data = json.loads(text)
    assert data["overall"]["min_separation_m"] is None
    assert data["format"] == "gcs-swarm-summary/1"


def test_empty_record() -> None:
    s = summarize_record(FlightRecorder(name="x").record())
    assert s["control_steps"] == 0 and s["vehicles"] == {}
