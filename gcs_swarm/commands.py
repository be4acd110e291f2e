"""What the ``gcs-swarm`` commands that fly or rebuild a run print, and
their exit codes: the command line's layer (``gcs_swarm.cli`` parses the
arguments and maps errors to one line). The library below (``runtime``,
``report``) prints nothing; these functions are where its results meet a
terminal.

``run_command`` wraps ``gcs_swarm.runtime.run_mission``: the status line
(rewritten in place on a terminal, every 5th line into a log file), Ctrl-C
or SIGTERM ends the run cleanly (zero acceleration, then the end action), a
second Ctrl-C quits at once. ``report_command`` wraps
``gcs_swarm.report.rebuild_report``; ``view_command`` and ``serve_replay``
replay a run or a simulation in the operator view (``gcs_swarm.view``).
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from collections.abc import Coroutine
from typing import TYPE_CHECKING, Any

from gcs_swarm.errors import MissionError
from gcs_swarm.mission import Mission, describe, load_mission

if TYPE_CHECKING:
    from gcs_swarm.report.artefacts import RunFolder
    from gcs_swarm.report.record import FlightRecord
    from gcs_swarm.runtime.summary import RunSummary
    from gcs_swarm.runtime.zbus import TlsFiles

__all__ = [
    "check_command",
    "report_command",
    "run_command",
    "serve_replay",
    "shard_command",
    "sharded_run_command",
    "view_command",
]


def check_command(path: str) -> int:
    """``gcs-swarm check FILE``: validate without flying.

    Prints ``OK: FILE: <summary>`` on stdout and returns 0, or every problem on
    stderr (one line each) and returns 2 (the command line's "refused").
    Never raises for a bad file. (It loads neither the station nor the
    report, so that ``check`` answers at once.)
    """
    try:
        mission = load_mission(path)
    except MissionError as err:
        for line in str(err).splitlines():
            print(line, file=sys.stderr)
        return 2
    print(f"OK: {path}: {describe(mission)}")
    return 0


class _StatusLines:
    """The live status line of ``run``: rewritten in place on a terminal; to
    a log file (stderr not a terminal) one line in five, every 5 s."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self._count = 0

    def show(self, line: str) -> None:
        self._count += 1
        if self.tty:
            print("\r" + line[:200].ljust(120), end="", file=sys.stderr, flush=True)
        elif self._count % 5 == 1:
            print(line, file=sys.stderr, flush=True)

    def done(self) -> None:
        """The status line is over: a terminal gets its line break."""
        if self.tty:
            print(file=sys.stderr)


def run_command(
    path: str,
    *,
    status: bool = True,
    log_dir: str | None = None,
    record: bool = True,
    view: tuple[str, int] | None = None,
) -> int:
    """``gcs-swarm run PATH``: exit 0 when the mission completed (every vehicle
    that flew ended), 1 when it failed or was degraded (``EXIT_CODES``), 130
    when it was interrupted. ``SwarmError`` (bad file, start-up failure) propagates
    for the command line to print as one line. With ``record`` the run
    folder goes under ``log_dir`` (default the mission's ``log.dir``). With
    ``view`` (host, port) the operator view is served there and its address,
    with the run's token, printed at start (docs/operator-view.md)."""
    mission = load_mission(path)
    base = (log_dir if log_dir is not None else mission.log.dir) if record else None
    return asyncio.run(_main(mission, status=status, log_dir=base, view=view))


async def _main(
    mission: Mission, *, status: bool, log_dir: str | None, view: tuple[str, int] | None = None
) -> int:
    from gcs_swarm.runtime.run import EXIT_CODES, View, run_mission

    lines = _StatusLines()

    folders: list[RunFolder] = []

    def report(summary: RunSummary) -> None:
        lines.done()
        print(summary.format())
        _print_written(folders, mission)

    def announce(folder: RunFolder) -> None:
        folders.append(folder)
        print(f"run folder: {folder.path}", file=sys.stderr)

    live: View | None = None
    if view is not None:
        from gcs_swarm.view import live_view

        def url(text: str) -> None:
            print(f"operator view: {text}", file=sys.stderr, flush=True)

        live = live_view(mission, host=view[0], port=view[1], on_url=url)

    summary = await _until_interrupted(
        run_mission(
            mission,
            on_status=lines.show if status else None,
            on_summary=report,
            log_dir=log_dir,
            on_folder=announce,
            view=live,
        ),
        "ending: zero acceleration and the end action for every vehicle "
        "(Ctrl-C again to quit at once)",
    )
    return 130 if summary is None else EXIT_CODES.get(summary.outcome, 1)


def _print_written(folders: list[RunFolder], mission: Mission) -> None:
    """``written: PATH`` for each file the run left in its folder."""
    for folder in folders:
        paths = [*folder.tlogs(mission.networks), folder.controller_tlog, folder.summary,
                 folder.picture, folder.vehicle_params]  # fmt: skip
        for path in paths:
            if path.is_file():
                print(f"written: {path}", flush=True)


async def _until_interrupted(run: Coroutine[Any, Any, RunSummary], say: str) -> RunSummary | None:
    """Await ``run`` with SIGINT and SIGTERM cancelling it (its own ending then
    ends the vehicles; ``say`` is printed at the first signal); None when it
    was interrupted. The handlers are removed however it ends."""
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None
    hits = 0

    def interrupt() -> None:
        nonlocal hits
        hits += 1
        if hits == 1:
            print(f"\n{say}", file=sys.stderr)
        task.cancel()

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, interrupt)
    try:
        return await run
    except asyncio.CancelledError:
        return None
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)


def sharded_run_command(
    path: str,
    shards: int,
    *,
    listen: str | None = None,
    tls: TlsFiles | None = None,
    status: bool = True,
    log_dir: str | None = None,
    record: bool = True,
    view: tuple[str, int] | None = None,
) -> int:
    """``gcs-swarm run PATH --shards N [--listen ENDPOINT]``: the mission
    flown by N link shards (``gcs_swarm.runtime.sharded``): started on this
    machine, or with ``listen`` (and ``tls`` for ``quic/`` and ``tls/``)
    awaited there from ``gcs-swarm shard --connect ENDPOINT`` elsewhere; its
    summary printed; the run folder, the
    status line, the operator view (``view``: host, port) and the exit
    codes as ``run_command``'s. Ctrl-C or SIGTERM ends every vehicle (the
    end action) through its shard."""
    from gcs_swarm.runtime.run import EXIT_CODES
    from gcs_swarm.runtime.sharded import ShardedView, check_shards, run_sharded

    mission = load_mission(path)
    check_shards(mission, shards)
    base = (log_dir if log_dir is not None else mission.log.dir) if record else None

    async def main() -> int:
        if listen is not None:
            how = "" if tls is None else " --tls-ca CA --tls-cert CERT --tls-key KEY"
            print(f"waiting for {shards} shards: gcs-swarm shard --connect {listen}{how}",
                  file=sys.stderr, flush=True)  # fmt: skip
        lines = _StatusLines()
        folders: list[RunFolder] = []

        def report(summary: RunSummary) -> None:
            lines.done()
            print(summary.format(), flush=True)
            _print_written(folders, mission)

        def announce(folder: RunFolder) -> None:
            folders.append(folder)
            print(f"run folder: {folder.path}", file=sys.stderr, flush=True)

        shown: ShardedView | None = None
        if view is not None:
            from gcs_swarm.view.sharded import sharded_view

            def url(text: str) -> None:
                print(f"operator view: {text}", file=sys.stderr, flush=True)

            shown = sharded_view(mission, host=view[0], port=view[1], on_url=url)

        flight = run_sharded(
            mission, shards, endpoint=listen, tls=tls, spawn=listen is None, log_dir=base,
            on_folder=announce, on_status=lines.show if status else None, on_summary=report,
            view=shown,
        )  # fmt: skip
        summary = await _until_interrupted(
            flight,
            "ending: the end action for every vehicle, through its shard",
        )
        return 130 if summary is None else EXIT_CODES.get(summary.outcome, 1)

    return asyncio.run(main())


def shard_command(endpoint: str, tls: TlsFiles | None = None) -> int:
    """``gcs-swarm shard --connect ENDPOINT`` (``gcs_swarm.runtime.shard``)."""
    from gcs_swarm.runtime.shard import shard_command as serve
    from gcs_swarm.view.sharded import shard_frames

    return serve(endpoint, frames=shard_frames, tls=tls)


def report_command(
    path: str | os.PathLike[str], mission_path: str | None = None, *, force: bool = False
) -> int:
    """``gcs-swarm report RUN_FOLDER_OR_TLOG [--mission FILE] [--force]``:
    ``rebuild_report``, then print the figures and the paths written."""
    from gcs_swarm.report.artefacts import rebuild_report, summary_text

    summary, summary_path, picture_path = rebuild_report(path, mission_path, force=force)
    print(summary_text(summary))
    print(f"summary written to {summary_path}")
    print(f"picture written to {picture_path}")
    return 0


def view_command(
    path: str | os.PathLike[str], mission_path: str | None, address: tuple[str, int]
) -> int:
    """``gcs-swarm view RUN_FOLDER_OR_TLOG [--mission FILE] [--listen [HOST:]PORT]``:
    the run's flight record rebuilt from its ``.tlog`` and mission (as
    ``report`` does), replayed in the operator view until Ctrl-C."""
    from gcs_swarm.report.artefacts import flown_run, report_from_tlog

    tlog, mission = flown_run(path, mission_path)
    _, record = report_from_tlog(tlog, mission)
    return serve_replay(record, mission, address)


def serve_replay(record: FlightRecord, mission: Mission, address: tuple[str, int]) -> int:
    """Replay ``record`` (of ``mission``) in the operator view at ``address``
    (host, port), printing its address with the token, until Ctrl-C (0)."""
    from gcs_swarm.view import RecordFrames, replay_view, scene_of

    frames = RecordFrames(
        record,
        scene_of(mission.law, name=mission.settings.name),
        autopilots={v.key: v.autopilot for v in mission.vehicles},
        labels={v.key: mission.label(v.key) for v in mission.vehicles},
    )

    def url(text: str) -> None:
        print(f"replay view: {text} (Ctrl-C to stop)", file=sys.stderr, flush=True)

    async def serve() -> None:
        loop = asyncio.get_running_loop()
        stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            async with replay_view(frames, host=address[0], port=address[1], on_url=url):
                await stop.wait()
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)

    asyncio.run(serve())
    return 0
