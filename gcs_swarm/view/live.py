"""The live operator view of a flight: ``run_mission(view=live_view(...))``.

``live_view`` returns the lifetime ``run_mission`` enters once the station is
up (``runtime.run.View``): a ``ViewServer`` on the station's event loop whose
frames are ``SnapshotBuilder`` frames of the station (with the flight
recorder's inbound counts for the loss column, and the links' setpoint
drops), and whose only command is an end button: ``{"type": "end",
"action": "hold" | "land" | "rtl"}`` fills the run's ``EndRequest``, so the
mission ends the way it does when its duration is over (``Station.end`` with
that end action, for every vehicle). Nothing else in the page commands a
vehicle. docs/operator-view.md.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, Any

from gcs_swarm.runtime.ending import END_ACTIONS, EndRequest
from gcs_swarm.view.server import ViewServer
from gcs_swarm.view.snapshot import SnapshotBuilder, scene_of

if TYPE_CHECKING:
    from gcs_swarm.mission import Mission
    from gcs_swarm.report.record import FlightRecorder
    from gcs_swarm.runtime.run import View
    from gcs_swarm.runtime.station import Station

__all__ = ["END_LABELS", "live_view"]

END_LABELS = {"hold": "Hold", "land": "Land", "rtl": "Return"}
"""The page's button for each end action."""


def end_command(msg: dict[str, Any], request: EndRequest, *, ending: bool) -> dict[str, Any]:
    """The page's only command, an end button: ``request`` filled with its
    action unless the mission is ``ending`` already or was asked before;
    the answer the page shows."""
    action = msg.get("action")
    if msg.get("type") != "end" or action not in END_ACTIONS:
        return {"ok": False, "text": "the view takes only an end action: "
                + ", ".join(END_ACTIONS)}  # fmt: skip
    assert isinstance(action, str)
    if ending or not request.request(action):
        return {"ok": False, "action": action, "text": "the mission is already ending"}
    text = f"{END_LABELS[action]}: ending the mission for every vehicle"
    return {"ok": True, "action": action, "text": text}


def live_hello(mission: Mission) -> dict[str, Any]:
    """What a live page is told first: its mode, the mission, the buttons."""
    return {"mode": "live", "name": mission.settings.name,
            "actions": [[a, END_LABELS[a]] for a in END_ACTIONS]}  # fmt: skip


def live_view(
    mission: Mission,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    rate_hz: float = 10.0,
    token: str | None = None,
    on_url: Callable[[str], None] | None = None,
    on_server: Callable[[ViewServer], None] | None = None,
    write_limit: int = 2**15,
    send_buffer: int | None = 2**16,
) -> View:
    """The view of ``mission``'s run on ``host:port`` (0: any free port),
    frames at ``rate_hz`` (built just after the station's steps:
    ``Station.on_step`` -> ``ViewServer.step_done``); ``on_url``
    gets the page's address with its token as soon as it listens, ``on_server``
    the server (tests read its counts);
    ``write_limit``, ``send_buffer`` [bytes]: ``ViewServer``'s."""

    @contextlib.asynccontextmanager
    async def lifetime(
        station: Station, request: EndRequest, recorder: FlightRecorder | None
    ) -> AsyncIterator[ViewServer]:
        law = mission.law
        builder = SnapshotBuilder(scene_of(law, name=mission.settings.name),
                                  station.control.controller.obstacles)  # fmt: skip

        def frames() -> dict[str, Any]:
            counts = None if recorder is None else recorder.telemetry.counts
            frame = builder.frame(station, station.now(), telemetry=counts)
            links = station.links.values()
            frame["setpoints_dropped"] = sum(link.stats.setpoints_dropped for link in links)
            frame["ended_by"] = request.action
            return frame

        async with live_server(mission, frames, request, lambda: station.ending,
                               host=host, port=port, rate_hz=rate_hz, token=token,
                               on_url=on_url, on_server=on_server, write_limit=write_limit,
                               send_buffer=send_buffer) as server:  # fmt: skip
            station.on_step = server.step_done
            yield server

    return lifetime


@contextlib.asynccontextmanager
async def live_server(
    mission: Mission,
    frames: Callable[[], dict[str, Any]],
    request: EndRequest,
    ending: Callable[[], bool],
    *,
    on_url: Callable[[str], None] | None = None,
    on_server: Callable[[ViewServer], None] | None = None,
    **server: Any,
) -> AsyncIterator[ViewServer]:
    """A live page of ``mission`` serving ``frames``, its end buttons filling
    ``request`` unless ``ending()`` (``end_command``); ``on_url`` and
    ``on_server`` told once it listens; ``server``: ``ViewServer``'s options.
    The one-station view (``live_view``) and the sharded one
    (``view.sharded``) differ only in their frames."""

    def command(msg: dict[str, Any]) -> dict[str, Any]:
        return end_command(msg, request, ending=ending())

    async with ViewServer(frames, on_command=command, hello=live_hello(mission),
                          **server) as view:  # fmt: skip
        if on_url is not None:
            on_url(view.url)
        if on_server is not None:
            on_server(view)
        yield view
