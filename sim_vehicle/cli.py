"""The ``sim-vehicle`` command line: run N emulated ArduCopters until Ctrl-C.

Owns argument parsing into an ``EmulatorConfig`` and the run-time console:
while it runs, type on stdin ``add SYSID [N,E,D]`` (add a vehicle, airborne
when D < 0), ``remove SYSID``, ``list`` (one line per vehicle) or ``quit``.
Ctrl-C (SIGINT) or SIGTERM stops it cleanly. Configuration errors print one
line and exit with status 2; a port that cannot be bound exits with 1.

Example: ``sim-vehicle --count 6 --base-port 5760 --origin-spread 5 --lockstep``
then connect each vehicle with ``udpout:127.0.0.1:5760``, ``...:5770``, ...;
with ``--tcp`` each is also served as SITL serves it, ``tcp:127.0.0.1:5760``,
``...:5770``, ... (``--tcp-base-port`` to move it; UDP stays).
``--sitl-times`` gives SITL's start-up: ``--boot 1 --ekf-delay 25``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import signal
import sys
from collections.abc import Sequence

from sim_vehicle.config import DEFAULT_ORIGIN, EmulatorConfig, Impairment, VehicleSpec
from sim_vehicle.server import Emulator
from sim_vehicle.telemetry import EARTH_RADIUS_M

__all__ = ["build_config", "main", "parse_args"]


def _triple(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers, got {text!r}")
    try:
        a, b, c = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers, got {text!r}") from None
    return a, b, c


def _keyval(text: str) -> tuple[str, float]:
    key, sep, val = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        return key.strip(), float(val)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number after '=', got {text!r}") from None


def _hostport(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Parse the command line."""
    p = argparse.ArgumentParser(
        prog="sim-vehicle",
        description="MAVLink point-mass vehicles that behave like ArduCopter 4.5 in GUIDED.",
        epilog="stdin while running: add SYSID [N,E,D] | remove SYSID | list | quit",
    )
    p.add_argument("--count", type=int, default=1, help="number of vehicles (default 1)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    p.add_argument("--base-port", type=int, default=None,
                   help="vehicle i on BASE+10*i (5760); PX4: BASE+i (18570)")  # fmt: skip
    p.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                   help="behave as ArduCopter 4.5 (default) or PX4 v1.14 (OFFBOARD)")  # fmt: skip
    p.add_argument("--shared-port", type=int, help="serve every sysid on this one UDP port")
    p.add_argument(
        "--tcp",
        action="store_true",
        help="also serve vehicle i on TCP BASE+10*i (as SITL: tcp:127.0.0.1:5760)",
    )
    p.add_argument("--tcp-base-port", type=int, metavar="BASE",
                   help="TCP base port (default: --base-port); implies --tcp")  # fmt: skip
    p.add_argument("--sysid-start", type=int, default=1, help="system id of vehicle 0 (1)")
    p.add_argument(
        "--start", type=_triple, action="append", default=[], metavar="N,E,D",
        help="start of vehicle i (local NED m from its origin; repeat per vehicle)",
    )  # fmt: skip
    p.add_argument("--airborne", action="store_true", help="start armed in GUIDED, hovering")
    p.add_argument("--origin", type=_triple, default=DEFAULT_ORIGIN, metavar="LAT,LON,ALT")
    p.add_argument("--origin-spread", type=float, default=0.0, metavar="METRES",
                   help="origin of vehicle i is i*METRES east of --origin")  # fmt: skip
    clock = p.add_mutually_exclusive_group()
    clock.add_argument("--speedup", type=float, default=1.0, help="real-time factor (1)")
    clock.add_argument("--lockstep", action="store_true", help="step on setpoints (see docs)")
    p.add_argument("--lockstep-timeout", type=float, default=0.5, metavar="S")
    p.add_argument("--rate", type=float, default=50.0, help="physics steps per second (50)")
    p.add_argument("--ideal", action="store_true", help="no acceleration lag (default 0.2 s)")
    p.add_argument("--tau", type=float, help="acceleration lag time constant, s")
    p.add_argument("--ekf-delay", type=float, help="s before EKF/GPS ready, arming passes (2)")
    p.add_argument(
        "--boot",
        type=float,
        metavar="S",
        help="s after first contact: 'ArduPilot Ready', STABILIZE (0: never, default)",
    )
    p.add_argument(
        "--sitl-times",
        action="store_true",
        help="SITL's start-up times: --boot 1 --ekf-delay 25 unless given",
    )
    p.add_argument("--no-shaping", action="store_true",
                   help="no jerk / lean-angle limits on the command (kept lag)")  # fmt: skip
    p.add_argument("--noise-pos", type=float, default=0.0, help="LOCAL_POSITION_NED noise, m")
    p.add_argument("--noise-vel", type=float, default=0.0, help="LOCAL_POSITION_NED noise, m/s")
    p.add_argument("--velocity-bias", type=_vec3, default=None, metavar="N,E,D",
                   help="m/s added to every reported velocity (default: the preset's, "
                        "-0.015,0.013,0 for ardupilot as SITL's EKF; 0,0,0 ideal)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--heartbeats", choices=("together", "spread"), default="together",
                   help="HEARTBEATs in one step, as a SITL swarm (default), or each at its "
                        "own phase, as a fleet booted one by one")  # fmt: skip
    p.add_argument("--overrun", choices=("catch_up", "skip"), default="catch_up",
                   help="held behind the wall clock: every missed step's messages, as SITL "
                        "(default), or the physics alone and one send, as an autopilot "
                        "whose loop overran")  # fmt: skip
    p.add_argument("--loss", type=float, default=0.0, help="datagram loss, both directions")
    p.add_argument("--delay", type=float, default=0.0, help="one-way delay, s")
    p.add_argument("--jitter", type=float, default=0.0, help="uniform extra delay, s")
    p.add_argument("--dup", type=float, default=0.0, help="duplication probability")
    p.add_argument("--stream", type=_keyval, action="append", default=[], metavar="MSGID=HZ",
                   help="stream from the start (default: HEARTBEAT only)")  # fmt: skip
    p.add_argument("--param", type=_keyval, action="append", default=[], metavar="NAME=VALUE")
    p.add_argument("--out", type=_hostport, help="also send to HOST:PORT from the start")
    p.add_argument("--signing-key-env", metavar="NAME",
                   help="MAVLink 2 signing: key (64 hex digits) in $NAME")  # fmt: skip
    return p.parse_args(argv)


def _shift_east(origin: tuple[float, float, float], east_m: float) -> tuple[float, float, float]:
    lat, lon, alt = origin
    dlon = math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat))))
    return lat, lon + dlon, alt


def build_config(args: argparse.Namespace) -> EmulatorConfig:
    """``EmulatorConfig`` from parsed arguments (ValueError on inconsistent values)."""
    if args.count < 0:
        raise ValueError(f"--count: expected >= 0, got {args.count}")
    if len(args.start) > args.count:
        raise ValueError(f"--start given {len(args.start)} times for {args.count} vehicles")
    vehicles = []
    for i in range(args.count):
        start = args.start[i] if i < len(args.start) else (0.0, 0.0, 0.0)
        if args.airborne and start[2] == 0.0:
            start = (start[0], start[1], -10.0)
        vehicles.append(
            VehicleSpec(
                sysid=args.sysid_start + i,
                origin=_shift_east(args.origin, i * args.origin_spread),
                start_ned_m=start,
                airborne=args.airborne,
                autopilot=args.autopilot,
            )
        )
    if args.base_port is None:
        args.base_port = 18570 if args.autopilot == "px4" else 5760
    imp = Impairment(loss=args.loss, delay_s=args.delay, jitter_s=args.jitter, duplicate=args.dup)
    sitl = getattr(args, "sitl_times", False)
    ekf = args.ekf_delay if args.ekf_delay is not None else (25.0 if sitl else 2.0)
    boot = args.boot if args.boot is not None else (1.0 if sitl else 0.0)
    tcp_base = args.tcp_base_port
    if tcp_base is None and args.tcp:
        tcp_base = args.base_port
    key: bytes | None = None
    if getattr(args, "signing_key_env", None):
        text = os.environ.get(args.signing_key_env, "")
        try:
            key = bytes.fromhex(text.strip())
        except ValueError:
            key = b""
        if len(key) != 32:  # never echo the value
            raise ValueError(f"--signing-key-env: ${args.signing_key_env} is not 64 hex digits")
    return EmulatorConfig(
        vehicles=tuple(vehicles),
        host=args.host,
        base_port=args.base_port,
        shared_port=args.shared_port,
        out=args.out,
        rate_hz=args.rate,
        clock="lockstep" if args.lockstep else "realtime",
        speedup=args.speedup,
        lockstep_timeout_s=args.lockstep_timeout,
        dynamics="ideal" if args.ideal else "ardupilot",
        accel_tau_s=args.tau,
        accel_shaping=False if args.no_shaping else None,
        boot_s=boot,
        ekf_ready_s=ekf,
        tcp_base_port=tcp_base,
        noise_pos_m=args.noise_pos,
        noise_vel_m_s=args.noise_vel,
        vel_bias_ned_m_s=args.velocity_bias,
        seed=args.seed,
        heartbeats=args.heartbeats,
        overrun=args.overrun,
        uplink=imp,
        downlink=imp,
        streams=dict((int(k), v) for k, v in args.stream),
        params=dict(args.param),
        signing_key=key,
    )


def _vec3(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected N,E,D (three numbers), got {text!r}")
    return values[0], values[1], values[2]


def _describe(emu: Emulator, sysid: int) -> str:
    st = emu.vehicle_state(sysid)
    host, port = st.endpoint
    n, e, d = st.pos_ned_m
    arm = "ARMED" if st.armed else "disarmed"
    tcp = f" tcp {st.tcp_endpoint[0]}:{st.tcp_endpoint[1]}" if st.tcp_endpoint else ""
    return (
        f"sysid {sysid:3d} udp {host}:{port}{tcp} {st.mode_name:8s} {arm:8s} "
        f"ned=({n:.2f}, {e:.2f}, {d:.2f}) t={st.sim_time_s:.2f}s"
    )


async def _console(emu: Emulator, stop: asyncio.Event) -> None:
    """Read commands from stdin until EOF; EOF leaves the emulator running."""
    loop = asyncio.get_running_loop()
    lines: asyncio.Queue[str | None] = asyncio.Queue()

    pending = bytearray()
    try:
        fd = sys.stdin.fileno()
    except (OSError, ValueError, AttributeError):
        return  # no stdin: signals only

    def readable() -> None:  # os.read, not readline: a buffered line would stay unseen
        chunk = os.read(fd, 4096)
        pending.extend(chunk)
        while b"\n" in pending:
            line, _, rest = bytes(pending).partition(b"\n")
            pending[:] = rest
            lines.put_nowait(line.decode("utf-8", "replace"))
        if not chunk:
            lines.put_nowait(None)
            loop.remove_reader(fd)

    try:
        loop.add_reader(fd, readable)
    except (OSError, ValueError, NotImplementedError, PermissionError):
        return  # no usable stdin (e.g. a file on some platforms): signals only
    try:
        while (line := await lines.get()) is not None:
            words = line.split()
            try:
                if not words:
                    continue
                if words[0] == "add" and len(words) in (2, 3):
                    start = _triple(words[2]) if len(words) == 3 else (0.0, 0.0, 0.0)
                    first = emu.config.vehicles[:1]  # an added vehicle is of the same kind
                    spec = VehicleSpec(
                        sysid=int(words[1]), start_ned_m=start, airborne=start[2] < 0,
                        autopilot=first[0].autopilot if first else "ardupilot",
                    )  # fmt: skip
                    await emu.add_vehicle(spec)
                    print(_describe(emu, spec.sysid), flush=True)
                elif words[0] == "remove" and len(words) == 2:
                    emu.remove_vehicle(int(words[1]))
                    print(f"removed sysid {words[1]}", flush=True)
                elif words[0] == "list":
                    for sysid in sorted(emu.endpoints):
                        print(_describe(emu, sysid), flush=True)
                elif words[0] in ("quit", "exit"):
                    stop.set()
                    return
                else:
                    print("commands: add SYSID [N,E,D] | remove SYSID | list | quit", flush=True)
            except (ValueError, KeyError, OSError, argparse.ArgumentTypeError) as exc:
                print(f"error: {exc}", flush=True)
    finally:
        with contextlib.suppress(ValueError, OSError):
            loop.remove_reader(fd)


async def _run(cfg: EmulatorConfig) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    async with Emulator(cfg) as emu:
        clock = "lockstep" if cfg.clock == "lockstep" else f"real time x{cfg.speedup:g}"
        print(f"sim-vehicle: {len(cfg.vehicles)} vehicles, {clock}, {cfg.rate_hz:g} Hz", flush=True)
        for sysid in sorted(emu.endpoints):
            print(_describe(emu, sysid), flush=True)
        console = asyncio.create_task(_console(emu, stop))
        try:
            await stop.wait()
        finally:
            console.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await console
    print("sim-vehicle: stopped", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``sim-vehicle``; returns the exit status."""
    args = parse_args(argv)
    try:
        cfg = build_config(args)
    except ValueError as exc:
        print(f"sim-vehicle: error: {exc}", file=sys.stderr)
        return 2
    try:
        asyncio.run(_run(cfg))
    except OSError as exc:
        print(f"sim-vehicle: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
