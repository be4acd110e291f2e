"""The ``gcs-swarm`` command line: parse arguments, run one subcommand, and
print any ``SwarmError`` as one line with a non-zero exit.

Subcommands (their work lives in the library modules):

- ``run MISSION``: fly the mission over MAVLink (``gcs_swarm.runtime``);
  ``--shards N`` splits the station in N link shards (``runtime.sharded``);
- ``shard --connect ENDPOINT``: one link shard of a sharded run
  (``runtime.shard``); ``quic/`` and ``tls/`` endpoints (``run --listen``,
  ``shard --connect``) take ``--tls-ca/--tls-cert/--tls-key`` (mutual TLS,
  ``runtime.zbus``);
- ``simulate MISSION``: the deterministic in-process reference
  (``gcs_swarm.offline``);
- ``check MISSION...``: validate without flying (``gcs_swarm.mission``);
- ``schema``: print the JSON Schema of mission files;
- ``report RUN_FOLDER_OR_TLOG``: rebuild a run's summary and picture from
  its ``.tlog`` and the mission file (``gcs_swarm.report``);
- ``view RUN_FOLDER_OR_TLOG``: replay a run in the operator view
  (``gcs_swarm.view``; ``run --view`` and ``simulate --view`` show it live
  and after a simulation).

Exit codes (``EXIT_*``, stated in the README): 0 done; 1 a vehicle or a link
failed (start-up or flight); 2 refused before anything flew (bad arguments,
a bad or unreadable file); 130 interrupted; 141 the output pipe was closed
(``gcs-swarm schema | head``), as for a process killed by SIGPIPE.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

# One BLAS thread, set before numpy loads (the commands here import it lazily):
# the station's products are blocks of at most 256 x 256, and OpenBLAS's
# worker threads on them contend with the control loop and take the core of
# the emulator or SITL beside it (docs/architecture.md, "Threads"; measured
# 2026-12-04: 1,000 vehicles on four networks, p99 6.1 ms with one thread,
# 39 ms with numpy's default). A value the user set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from gcs_swarm import __version__  # noqa: E402
from gcs_swarm.errors import (  # noqa: E402
    InfeasibleError,
    LinkError,
    MissionError,
    SwarmError,
    UsageError,
    VehicleError,
)

if TYPE_CHECKING:
    from gcs_swarm.mission import Mission

__all__ = [
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "EXIT_PIPE",
    "EXIT_REFUSED",
    "build_parser",
    "main",
]

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_REFUSED = 2
EXIT_INTERRUPTED = 130
EXIT_PIPE = 141

#: Trajectory files ``simulate --out`` writes (``SimResult.save``).
_OUT_SUFFIXES = (".csv", ".npz")


def _cmd_check(args: argparse.Namespace) -> int:
    from gcs_swarm.commands import check_command

    code = EXIT_OK
    for path in args.mission:
        if check_command(path) == 0:
            _check_envelope(path)
        else:
            code = EXIT_REFUSED
    return code


def _check_envelope(path: str) -> None:
    """``check``'s demand warning (docs/vehicle-envelope.md): when the mission
    states ``limits.envelope``, simulate it on the ideal point mass (RK4 step
    ``offline.DEMAND_DT_S``, coarse so check stays fast) and print one
    warning line at the gains if the peaks exceed it, with the time scale
    that fits. A warning, not an error: the exit code stays 0."""
    from gcs_swarm.mission import load_mission
    from gcs_swarm.mission.checks import key_line
    from gcs_swarm.offline import demand_report

    mission = load_mission(path)
    envelope = mission.law.limits.envelope
    if not envelope.bounded:
        return
    where = "gains.time_scale" if mission.law.gains.time_scale != 1.0 else "gains"
    line = key_line(mission.text, where)
    for text in demand_report(mission, envelope):
        print(f"{path}:{line}: {where}: warning: {text}", file=sys.stderr)


def _cmd_schema(args: argparse.Namespace) -> int:
    from gcs_swarm.mission import schema

    print(json.dumps(schema(), indent=2, sort_keys=False))
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from gcs_swarm.mission import load_mission
    from gcs_swarm.offline import simulate_mission

    _check_simulate_args(args)
    view = _address("--view", args.view)
    mission = load_mission(args.mission)
    if args.duration is not None:
        _check_leader_for(mission, args.duration)
    out = simulate_mission(mission, dt_s=args.dt, duration_s=args.duration)
    how = f"RK4, dt {args.dt} s"
    if out.envelope is not None:
        how = f"vehicle envelope, control period {1.0 / mission.settings.rate:g} s"
    print(f"{mission.settings.name}: simulated {out.result.times_s[-1]:.2f} s ({how})")
    print(out.text())
    if args.out is not None:
        try:
            path = out.result.save(args.out, every=args.every)
        except (OSError, ValueError) as err:
            raise SwarmError(f"{args.out}: cannot write trajectories: {err}") from None
        print(f"trajectories written to {path}")
    if not args.no_log:
        from gcs_swarm.report import create_run_folder, write_simulation_report

        folder = create_run_folder(mission, base_dir=args.log_dir)
        write_simulation_report(
            out, folder.path, name=mission.settings.name, networks=mission.networks
        )
        print(f"summary written to {folder.summary}")
        print(f"picture written to {folder.picture}")
    if view is not None:
        from gcs_swarm.commands import serve_replay
        from gcs_swarm.report.artefacts import from_sim_result

        sys.stdout.flush()
        return serve_replay(from_sim_result(out, name=mission.settings.name), mission, view)
    return 0


def _check_simulate_args(args: argparse.Namespace) -> None:
    """Every argument of ``simulate`` before anything is simulated."""
    from gcs_swarm.mission.bounds import DURATION_MAX_S

    if not (math.isfinite(args.dt) and args.dt > 0.0):
        raise UsageError(f"--dt: expected a positive step in seconds, got {args.dt}")
    d = args.duration
    if d is not None and not (math.isfinite(d) and 0.0 < d <= DURATION_MAX_S):
        raise UsageError(
            f"--duration: expected seconds > 0 and <= {DURATION_MAX_S:g} (mission.duration's"
            f" bound), got {d:g}"
        )
    if args.every < 1:
        raise UsageError(f"--every: expected a whole number >= 1, got {args.every}")
    if args.out is not None and args.out.suffix.lower() not in _OUT_SUFFIXES:
        raise UsageError(
            f"--out {args.out}: trajectory files are .csv or .npz, got {args.out.suffix!r}"
        )


def _check_leader_for(mission: Mission, duration_s: float) -> None:
    """``--duration`` longer than the mission: the leader's path over it must
    hold too (``mission.bounds``), refused like a mission error."""
    from gcs_swarm.mission.bounds import leader_path_problem
    from gcs_swarm.mission.checks import key_line

    found = leader_path_problem(mission.law.leader, mission.law.gains, duration_s)
    if found is not None:
        key, why = found
        line = f"{mission.source}:{key_line(mission.text, key)}: {key}: {why}"
        raise MissionError(f"{line} (with --duration {duration_s:g})")


def _address(option: str, text: str | None) -> tuple[str, int] | None:
    """``[HOST:]PORT`` of a view option, refused as a usage error."""
    if text is None:
        return None
    from gcs_swarm.view.server import parse_address

    try:
        return parse_address(text)
    except ValueError as err:
        raise UsageError(f"{option}: {err}") from None


def _cmd_view(args: argparse.Namespace) -> int:
    from gcs_swarm.commands import view_command

    address = _address("--listen", args.listen)
    assert address is not None
    return view_command(args.path, args.mission, address)


def _cmd_run(args: argparse.Namespace) -> int:
    from gcs_swarm.commands import run_command
    from gcs_swarm.runtime.sched import short_slice

    short_slice()  # the setpoint stream's process wakes sooner on a busy machine

    view = _address("--view", args.view)
    if args.shards is not None:
        from gcs_swarm.commands import sharded_run_command

        if args.shards < 1:
            raise UsageError(f"--shards: expected a whole number >= 1, got {args.shards}")
        from gcs_swarm.runtime.zbus import check_endpoint, check_tls

        listen = None
        if args.listen is not None:
            listen = check_endpoint(args.listen, option="--listen")
        tls = check_tls(listen, "--listen", args.tls_ca, args.tls_cert, args.tls_key)
        return sharded_run_command(args.mission, args.shards, listen=listen, tls=tls,
                                   status=not args.no_status, log_dir=args.log_dir,
                                   record=not args.no_log, view=view)  # fmt: skip
    if args.listen is not None:
        raise UsageError("--listen: only with --shards N")
    for name in ("ca", "cert", "key"):
        if getattr(args, f"tls_{name}") is not None:
            raise UsageError(f"--tls-{name} {getattr(args, f'tls_{name}')}: only with"
                             " --shards N --listen quic/HOST:PORT (or tls/)")  # fmt: skip
    return run_command(
        args.mission,
        status=not args.no_status,
        log_dir=args.log_dir,
        record=not args.no_log,
        view=view,
    )


def _cmd_shard(args: argparse.Namespace) -> int:
    from gcs_swarm.commands import shard_command
    from gcs_swarm.runtime.sched import short_slice
    from gcs_swarm.runtime.zbus import check_endpoint, check_tls

    short_slice()

    endpoint = check_endpoint(args.connect, option="--connect")
    tls = check_tls(endpoint, "--connect", args.tls_ca, args.tls_cert, args.tls_key)
    return shard_command(endpoint, tls=tls)


def _cmd_report(args: argparse.Namespace) -> int:
    from gcs_swarm.commands import report_command

    return report_command(args.path, args.mission, force=args.force)


def _tls_options(p: argparse.ArgumentParser, side: str) -> None:
    """``--tls-ca/--tls-cert/--tls-key``: a ``quic/`` or ``tls/`` endpoint's
    files (``runtime.zbus.check_tls``), ``side`` the endpoint's option."""
    p.add_argument("--tls-ca", metavar="FILE", default=None,
                   help=f"with a quic/ or tls/ {side}: the CA (PEM) that signed the other"
                   " side's certificate (mutual TLS: docs/architecture.md)")  # fmt: skip
    p.add_argument("--tls-cert", metavar="FILE", default=None,
                   help=f"with a quic/ or tls/ {side}: this side's certificate (PEM)")  # fmt: skip
    p.add_argument("--tls-key", metavar="FILE", default=None,
                   help=f"with a quic/ or tls/ {side}: this side's private key (PEM)")  # fmt: skip


def _log_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--log-dir", default=None, help="put the run folder here (default: the mission's log.dir)"
    )
    p.add_argument("--no-log", action="store_true", help="write no run folder")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``gcs-swarm``."""
    parser = argparse.ArgumentParser(
        prog="gcs-swarm",
        description="Fly a drone swarm in formation over MAVLink.",
    )
    parser.add_argument("--version", action="version", version=f"gcs-swarm {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="fly a mission over MAVLink (bundled emulator for `sim` links)")
    p.add_argument("mission", help="mission YAML file")
    p.add_argument("--no-status", action="store_true", help="no live status line")
    p.add_argument(
        "--view",
        metavar="[HOST:]PORT",
        default=None,
        help="serve the operator view in a browser there (host 127.0.0.1 unless named;"
        " port 0: any free one); the address with its token is printed at start",
    )
    p.add_argument(
        "--shards",
        type=int,
        default=None,
        metavar="N",
        help="split the station: N link shard processes on this machine own whole networks,"
        " this process runs the law (docs/architecture.md, 'Scaled out: shards')",
    )
    p.add_argument(
        "--listen",
        metavar="ENDPOINT",
        default=None,
        help="with --shards N: listen there (e.g. quic/0.0.0.0:7447 with --tls-*, or"
        " tcp/127.0.0.1:7447) and wait for N shards started elsewhere with"
        " `gcs-swarm shard --connect`, instead of starting them here",
    )
    _tls_options(p, "--listen")
    _log_options(p)
    p.set_defaults(handler=_cmd_run)

    p = sub.add_parser("shard", help="serve as a link shard of a `run --shards` controller")
    p.add_argument(
        "--connect",
        required=True,
        metavar="ENDPOINT",
        help="the controller's Zenoh endpoint, e.g. quic/HOST:7447 (with --tls-*) or"
        " tcp/127.0.0.1:7447",
    )
    _tls_options(p, "--connect")
    p.set_defaults(handler=_cmd_shard)

    p = sub.add_parser("simulate", help="run a mission in the in-process reference simulator")
    p.add_argument("mission", help="mission YAML file")
    p.add_argument("--dt", type=float, default=0.01, help="RK4 step [s] (default 0.01)")
    p.add_argument("--duration", type=float, default=None, help="override the duration [s]")
    p.add_argument("--out", type=Path, default=None, help="write trajectories (.csv or .npz)")
    p.add_argument("--every", type=int, default=1, help="write every n-th sample (default 1, >= 1)")
    p.add_argument(
        "--view",
        metavar="[HOST:]PORT",
        default=None,
        help="then replay the simulation in the operator view there (port 0: any free one)",
    )
    _log_options(p)
    p.set_defaults(handler=_cmd_simulate)

    p = sub.add_parser("check", help="validate mission files without flying")
    p.add_argument("mission", nargs="+", help="mission YAML file(s)")
    p.set_defaults(handler=_cmd_check)

    p = sub.add_parser("schema", help="print the JSON Schema of mission files")
    p.set_defaults(handler=_cmd_schema)

    p = sub.add_parser("report", help="rebuild a run's summary and picture from its .tlog")
    p.add_argument("path", help="a run folder, or a .tlog file")
    p.add_argument(
        "--mission", default=None, help="the mission file flown (default: the folder's copy)"
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="overwrite an existing summary and picture (default: write summary-<n>.json,"
        " report-<n>.png beside them)",
    )
    p.set_defaults(handler=_cmd_report)

    p = sub.add_parser("view", help="replay a run in the operator view (a browser page)")
    p.add_argument("path", help="a run folder, or a .tlog file")
    p.add_argument(
        "--mission", default=None, help="the mission file flown (default: the folder's copy)"
    )
    p.add_argument(
        "--listen",
        metavar="[HOST:]PORT",
        default="0",
        help="serve the page there (default 127.0.0.1, any free port)",
    )
    p.set_defaults(handler=_cmd_view)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code
    (module docstring)."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.handler(args))
    except MissionError as err:
        for line in err.problems:
            print(f"gcs-swarm: {line}", file=sys.stderr)
        return EXIT_REFUSED
    except (VehicleError, LinkError, InfeasibleError) as err:
        print(f"gcs-swarm: {err}", file=sys.stderr)
        return EXIT_FAILED
    except SwarmError as err:
        print(f"gcs-swarm: {err}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt:
        print("gcs-swarm: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader went away (``| head``): nothing more can be written, and
        # Python's own flush at exit must not fail again on the same pipe.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_PIPE
