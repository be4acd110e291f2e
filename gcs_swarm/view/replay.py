"""Replay of a finished run (or a simulation) in the operator view's page.

``RecordFrames`` (no I/O) turns a ``FlightRecord`` (``gcs_swarm.report``:
a run's ``.tlog`` rebuilt with the mission, or a simulation) into frames of
the live view's shape at any mission time; ``ReplayClock`` is play, pause,
speed and seek with the wall time as an argument (STYLE.md habit 1);
``replay_view`` serves them with ``ViewServer`` until cancelled. The page
shows the same 3-D view, table and events, with a time slider in place of
the end buttons: a replay commands nothing. docs/operator-view.md.

What a record does not hold is shown as unknown (None): the vehicles'
modes, arming and link figures at each step (the loss column is the whole
run's, from the record's inbound counts), and positions outside the
formation.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import AsyncIterator, Callable, Mapping
from typing import Any

import numpy as np

from gcs_swarm.report.record import FlightRecord
from gcs_swarm.view.server import ViewServer
from gcs_swarm.view.snapshot import float_column, geometry_columns, obstacles_of

__all__ = ["SPEEDS", "RecordFrames", "ReplayClock", "replay_view"]

SPEEDS = (0.25, 0.5, 1.0, 2.0, 5.0, 10.0)
"""Replay speeds the page offers [x mission time]."""


class ReplayClock:
    """Where the replay is in mission time [s]; ``now`` is the wall clock [s]."""

    def __init__(self, t0_s: float, t1_s: float) -> None:
        self.t0_s, self.t1_s = t0_s, t1_s
        self.t_s = t0_s
        self.playing = False
        self.speed = 1.0
        self._wall: float | None = None
        self.restarted = True
        """The replay jumped (a seek, a new start): the page clears its trails."""

    def at(self, now: float) -> float:
        """The replay's time at ``now``; it stops at the end."""
        if self.playing and self._wall is not None:
            self.t_s = min(self.t1_s, self.t_s + (now - self._wall) * self.speed)
            if self.t_s >= self.t1_s:
                self.playing = False
        self._wall = now
        return self.t_s

    def command(self, msg: Mapping[str, Any], now: float) -> dict[str, Any]:
        """``{"type": "play" | "pause" | "speed" (value) | "seek" (t)}`` from the page."""
        self.at(now)
        kind = msg.get("type")
        if kind == "play":
            if self.t_s >= self.t1_s:
                self.t_s, self.restarted = self.t0_s, True
            self.playing = True
        elif kind == "pause":
            self.playing = False
        elif kind == "speed" and msg.get("value") in SPEEDS:
            self.speed = float(msg["value"])
        elif kind == "seek" and isinstance(msg.get("t"), int | float):
            self.t_s = min(self.t1_s, max(self.t0_s, float(msg["t"])))
            self.restarted = True
        else:
            return {"ok": False, "text": "a replay takes play, pause, speed (one of "
                    + ", ".join(f"{s:g}" for s in SPEEDS) + ") or seek (t)"}  # fmt: skip
        return {"ok": True, "text": f"{kind}"}


class RecordFrames:
    """Frames of a ``FlightRecord`` at any time (module docstring)."""

    def __init__(
        self,
        record: FlightRecord,
        scene: Mapping[str, Any],
        *,
        autopilots: Mapping[int, str] | None = None,
        labels: Mapping[int, str] | None = None,
    ) -> None:
        """``autopilots`` and ``labels`` (``network:sysid`` on named networks;
        default the key itself) by vehicle key."""
        self.record = record
        self.scene = dict(scene)
        self._obstacles = obstacles_of(scene)
        ids = [int(s) for s in record.ids]
        self._ids = ids
        self._autopilot = [(autopilots or {}).get(s) for s in ids]
        named = labels or {}
        self._labels = [named.get(s, str(s)) for s in ids]
        loss = np.full(len(ids), np.nan)
        for k, s in enumerate(ids):
            c = (record.telemetry or {}).get(s)
            if c is not None:
                loss[k] = c.loss_fraction
        self._loss = float_column(loss, 4)
        times = record.times_s
        self.t0_s = float(times[0]) if times.size else 0.0
        self.t1_s = float(times[-1]) if times.size else 0.0
        self._happened = sorted(
            [(t, kind, s, f"vehicle {named.get(s, s)} {'joins' if kind == 'join' else 'leaves'}")
             for t, kind, s in record.events]
            + [(t, "switch", None, "avoidance" if what == "start" else "formation")
               for t, what, _ in record.switches()]
        )  # fmt: skip
        self._last_t: float | None = None
        self.seq = 0

    def frame(self, t_s: float, clock: ReplayClock | None = None) -> dict[str, Any]:
        """The record's last step at or before mission time ``t_s`` [s], with
        the events since the previous frame (after a jump: none, unless it
        is to the start)."""
        rec = self.record
        n = len(self._ids)
        if rec.steps == 0:
            k = -1
        else:
            k = max(0, int(np.searchsorted(rec.times_s, t_s, side="right")) - 1)
        t = float(rec.times_s[k]) if k >= 0 else self.t0_s
        pos = rec.pos_m[k] if k >= 0 else np.full((n, 3), np.nan)
        leader = rec.leader_pos_m[k] if k >= 0 else None
        inside = np.isfinite(pos).all(axis=1)
        accel = np.full(n, np.nan)
        correction = np.full(n, np.nan)
        if k >= 0:
            accel = np.where(rec.sent[k], np.linalg.norm(rec.accel_mps2[k], axis=1), np.nan)
            if rec.correction_mps2 is not None:
                correction = rec.correction_mps2[k]
        restart = clock is not None and clock.restarted
        if clock is not None:
            clock.restarted = False
        since = self._last_t
        if restart or (since is not None and t < since):
            since = -math.inf if t <= self.t0_s else None  # from the start: what happened at it
        events = []
        if since is not None:
            events = [{"t": te, "kind": kind, "sysid": s, "text": text}
                      for te, kind, s, text in self._happened if since < te <= t]  # fmt: skip
        self._last_t = t
        self.seq += 1
        unknown: list[Any] = [None] * n
        frame: dict[str, Any] = {
            "type": "frame",
            "seq": self.seq,
            "t": round(t, 3),
            "stage": "replay",
            "behaviour": str(rec.behaviour[k]) if k >= 0 else None,
            "episode": int(rec.episode[k]) if k >= 0 else None,
            "leader": None if leader is None else float_column(np.asarray(leader), 3),
            "vehicles": {
                "sysid": self._ids,
                "label": self._labels,
                "autopilot": self._autopilot,
                "phase": ["flying" if x else None for x in inside.tolist()],
                "mode": unknown,
                "armed": unknown,
                "rate_hz": unknown,
                "loss": self._loss,
                "heard_s": unknown,
                **geometry_columns(pos, leader, self._obstacles),
                "accel": float_column(accel, 3),
                "correction": float_column(correction, 3),
                "in_formation": inside.tolist(),
            },
            "scene": self.scene,
            "events": events,
        }
        if clock is not None:
            frame["replay"] = {"t": round(clock.t_s, 3), "duration": clock.t1_s,
                               "playing": clock.playing, "speed": clock.speed,
                               "restart": restart}  # fmt: skip
        return frame


def replay_view(
    frames: RecordFrames,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    rate_hz: float = 20.0,
    token: str | None = None,
    on_url: Callable[[str], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
    play: bool = True,
) -> contextlib.AbstractAsyncContextManager[ViewServer]:
    """A ``ViewServer`` replaying ``frames`` (playing from the start unless
    ``play`` is False); ``on_url`` gets the page's address with its token."""
    replay = ReplayClock(frames.t0_s, frames.t1_s)
    replay.playing = play

    def frame() -> dict[str, Any]:
        return frames.frame(replay.at(clock()), replay)

    def command(msg: dict[str, Any]) -> dict[str, Any]:
        return replay.command(msg, clock())

    hello = {"mode": "replay", "name": frames.record.name, "start": frames.t0_s,
             "duration": frames.t1_s, "speeds": list(SPEEDS)}  # fmt: skip

    @contextlib.asynccontextmanager
    async def lifetime() -> AsyncIterator[ViewServer]:
        async with ViewServer(frame, host=host, port=port, rate_hz=rate_hz, token=token,
                              on_command=command, hello=hello) as server:  # fmt: skip
            if on_url is not None:
                on_url(server.url)
            yield server

    return lifetime()
