"""Measure how a vehicle answers GUIDED acceleration setpoints: ArduCopter SITL
or the bundled emulator, the same script and the same profile.

Usage (one vehicle, already started; SITL instance 0 or ``sim-vehicle``):

    python benchmarks/vehicle_response.py tcp:127.0.0.1:5760 --out sitl.csv
    python benchmarks/vehicle_response.py udpout:127.0.0.1:5760 --out emu.csv
    python benchmarks/vehicle_response.py --compare sitl.csv emu.csv

The vehicle is set to GUIDED (again whenever it leaves it before arming),
armed, taken off to 10 m, then flown through ``PROFILE``: steps of the
acceleration setpoint (SET_POSITION_TARGET_LOCAL_NED, type_mask 3135, NED)
at 50 Hz, each followed by a pause at zero. Every LOCAL_POSITION_NED is
written to the CSV with the command in force, so the achieved acceleration
(the derivative of the reported velocity) can be set against the command:
``an, ae, ad`` as this script had last sent it when it read the report,
and ``tn, te, td`` as the vehicle last echoed it (POSITION_TARGET_LOCAL_NED,
on the vehicle's clock; NaN on a vehicle that does not send it). Fit
against the echo: on ArduCopter SITL the script's own column ran
0.04-0.05 s early (docs/emulator.md).
``--compare`` prints, per segment, the RMS difference of the two vehicles'
velocities and the peak achieved acceleration of each.

A measuring tool, not part of the station: it uses pymavlink's ``mavutil``
for brevity (the station itself never does, STYLE.md habit 5).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time

import numpy as np

PROFILE: list[tuple[str, tuple[float, float, float], float, float]] = [
    # (label, acceleration NED m/s^2, seconds, Hz); each is followed by 2 s at zero.
    # Hz 0 is a step; otherwise a sine of that frequency whose amplitude is the
    # vector (small, slow commands, as a formation's: the phase with which the
    # vehicle follows them, docs/emulator.md).
    ("north +1 (sheet's step)", (1.0, 0.0, 0.0), 3.0, 0.0),
    ("north -1", (-1.0, 0.0, 0.0), 3.0, 0.0),
    ("east +4 (jerk)", (0.0, 4.0, 0.0), 1.5, 0.0),
    ("east -4", (0.0, -4.0, 0.0), 1.5, 0.0),
    ("north +8 (saturation)", (8.0, 0.0, 0.0), 1.2, 0.0),
    ("north -8", (-8.0, 0.0, 0.0), 1.2, 0.0),
    ("up 2 (az -2)", (0.0, 0.0, -2.0), 1.5, 0.0),
    ("down 2 (az +2)", (0.0, 0.0, 2.0), 1.5, 0.0),
    ("reverse east +3 -> -3", (0.0, 3.0, 0.0), 1.0, 0.0),
    ("reverse east -3", (0.0, -3.0, 0.0), 1.0, 0.0),
    ("north sine 0.3 at 0.1 Hz", (0.3, 0.0, 0.0), 10.0, 0.1),
    ("east sine 0.3 at 0.3 Hz", (0.0, 0.3, 0.0), 20.0 / 3.0, 0.3),
    ("north sine 0.3 at 1 Hz", (0.3, 0.0, 0.0), 3.0, 1.0),
    ("up sine 0.3 at 0.3 Hz", (0.0, 0.0, -0.3), 20.0 / 3.0, 0.3),
]


def _command(acc: tuple[float, float, float], hz: float, t_s: float) -> tuple[float, ...]:
    """A profile segment's command ``t_s`` s after it began: ``acc`` itself for a
    step (``hz`` 0), else ``acc`` times the sine of that frequency."""
    if hz == 0.0:
        return acc
    k = math.sin(2.0 * math.pi * hz * t_s)
    return (acc[0] * k, acc[1] * k, acc[2] * k)


PAUSE_S = 2.0
RATE_HZ = 50.0
MASK_ACCEL = 3135


def _connect(link: str):  # type: ignore[no-untyped-def]
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(link, source_system=255, source_component=190)
    if link.startswith("udpout"):
        m.mav.heartbeat_send(6, 8, 0, 0, 0)
    m.wait_heartbeat(timeout=30)
    return m


def _cmd(m, command: int, *p: float) -> None:  # type: ignore[no-untyped-def]
    ps = list(p) + [0.0] * (7 - len(p))
    m.mav.command_long_send(m.target_system, 1, command, 0, *ps)


def _ack(m, command: int, timeout: float = 3.0) -> int | None:  # type: ignore[no-untyped-def]
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.2)
        if msg is not None and msg.command == command:
            return int(msg.result)
    return None


def _prepare(m, log: list[str]) -> None:  # type: ignore[no-untyped-def]
    _cmd(m, 511, 32, 20_000)  # LOCAL_POSITION_NED at 50 Hz
    _ack(m, 511)
    _cmd(m, 511, 85, 20_000)  # POSITION_TARGET_LOCAL_NED: what the vehicle took, on its clock
    _ack(m, 511)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 180:
        hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=1.5)
        if hb is not None and hb.custom_mode != 4:
            _cmd(m, 176, 1, 4)
            _ack(m, 176)
            continue
        if hb is None:
            continue
        _cmd(m, 400, 1)
        if _ack(m, 400) == 0:
            log.append(f"armed after {time.monotonic() - t0:.1f} s")
            break
        time.sleep(1.0)
    else:
        raise SystemExit("could not arm within 180 s")
    _cmd(m, 22, 0, 0, 0, 0, 0, 0, 10.0)
    res = _ack(m, 22)
    if res != 0:
        raise SystemExit(f"take-off refused: {res}")
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60:
        p = m.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=1)
        if p is not None and -p.z > 9.6 and abs(p.vz) < 0.1:
            break
    time.sleep(2.0)


def measure(link: str, out: str) -> None:
    m = _connect(link)
    log: list[str] = []
    _prepare(m, log)
    rows: list[list[float | str]] = []
    boot0: int | None = None
    # the target the vehicle reported last (POSITION_TARGET_LOCAL_NED), in the row of each
    # LOCAL_POSITION_NED after it: the command as the vehicle had it, free of this
    # script's own timing (its ``cur`` is what it had sent when it read the report)
    echo: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    period = 1.0 / RATE_HZ
    next_send = time.monotonic()
    for label, acc, dur, hz in PROFILE:
        pause = (label + " / pause", (0.0, 0.0, 0.0), PAUSE_S, 0.0)
        for seg, a, d, f in ((label, acc, dur, hz), pause):
            start = time.monotonic()
            end = start + d
            cur = a
            while time.monotonic() < end:
                now = time.monotonic()
                if now >= next_send:
                    cur = _command(a, f, next_send - start)
                    m.mav.set_position_target_local_ned_send(
                        0, m.target_system, 1, 1, MASK_ACCEL, 0, 0, 0, 0, 0, 0, *cur, 0, 0
                    )
                    next_send += period
                p = m.recv_match(type=["LOCAL_POSITION_NED", "POSITION_TARGET_LOCAL_NED"])
                if p is None:
                    time.sleep(0.002)
                    continue
                if p.get_type() == "POSITION_TARGET_LOCAL_NED":
                    echo = (p.afx, p.afy, p.afz)
                    continue
                boot0 = p.time_boot_ms if boot0 is None else boot0
                t = (p.time_boot_ms - boot0) / 1000.0
                rows.append([t, seg, *cur, p.x, p.y, p.z, p.vx, p.vy, p.vz, *echo])
    m.mav.set_position_target_local_ned_send(
        0, m.target_system, 1, 1, MASK_ACCEL, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    _cmd(m, 176, 1, 9)  # LAND
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            ["t_s", "segment", "an", "ae", "ad", "x", "y", "z", "vx", "vy", "vz", "tn", "te", "td"]
        )
        w.writerows(rows)
    print("\n".join(log))
    print(f"{len(rows)} reports written to {out}")


def _load(path: str) -> tuple[list[str], np.ndarray]:
    with open(path) as f:
        r = list(csv.DictReader(f))
    segs = [row["segment"] for row in r]
    cols = ["t_s", "an", "ae", "ad", "vx", "vy", "vz"]
    return segs, np.array([[float(row[c]) for c in cols] for row in r])


def compare(a_path: str, b_path: str) -> None:
    sa, a = _load(a_path)
    sb, b = _load(b_path)
    print(f"{'segment':34} {'RMS dv m/s':>10} {'peak|acc| A':>11} {'peak|acc| B':>11}")
    for label, *_ in PROFILE:
        for seg in (label, label + " / pause"):
            ia = [i for i, s in enumerate(sa) if s == seg]
            ib = [i for i, s in enumerate(sb) if s == seg]
            if len(ia) < 5 or len(ib) < 5:
                continue
            ta, tb = a[ia, 0] - a[ia[0], 0], b[ib, 0] - b[ib[0], 0]
            dv = []
            for k in (4, 5, 6):
                va, vb = a[ia, k] - a[ia[0], k], b[ib, k] - b[ib[0], k]
                dv.append(np.interp(ta, tb, vb) - va)
            rms = math.sqrt(float(np.mean(np.sum(np.square(dv), axis=0))))

            def peak(arr: np.ndarray, idx: list[int]) -> float:
                t = arr[idx, 0]
                v = arr[idx][:, 4:7]
                acc = np.gradient(v, t, axis=0)
                return float(np.max(np.linalg.norm(acc, axis=1)))

            print(f"{seg:34} {rms:10.3f} {peak(a, ia):11.2f} {peak(b, ib):11.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("link", nargs="?")
    ap.add_argument("--out", default="response.csv")
    ap.add_argument("--compare", nargs=2, metavar=("A_CSV", "B_CSV"))
    args = ap.parse_args(argv)
    if args.compare:
        compare(*args.compare)
    elif args.link:
        measure(args.link, args.out)
    else:
        ap.error("give a link or --compare")
    return 0


if __name__ == "__main__":
    sys.exit(main())
