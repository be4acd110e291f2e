"""Awaited commands of one vehicle: one in flight, a FIFO behind it, resent on
timeout (STYLE.md habit 6: "Commands: awaited, under a timeout, retried").

A command is answered by a COMMAND_ACK with its MAV_CMD number, or, for a
PARAM_SET or PARAM_REQUEST_READ, by the PARAM_VALUE of the same name (a
PARAM_SET given ``expect`` only by a PARAM_VALUE carrying that value: a late
answer to an earlier read of the same name is not its echo).
MAV_RESULT_IN_PROGRESS restarts the wait. Resends carry an increasing
``confirmation`` as COMMAND_LONG asks. A command nobody answers fails the
queue (``failed``), unless it is ``optional``: then its ``on_done`` gets
``NO_ANSWER`` and the queue goes on. A command given ``not_before`` is not
sent before that time, and the commands behind it wait with it (the
start-up's status streams, asked at each vehicle's own phase:
``VehicleProtocol.status_phase``). No I/O: specs go to the ``out`` list
the owner drains; time is an argument.

The STATUSTEXT lines heard while a command waits for its answer (from its
first sending to its COMMAND_ACK: one command is in flight at a time) belong
to it; ``refusal_reason`` picks the autopilot's reasons among them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from gcs_swarm.mavlink.codec import MessageSpec

__all__ = [
    "MAV_RESULT_NAMES",
    "NO_ANSWER",
    "NO_REASON",
    "CommandQueue",
    "refusal_reason",
    "same_param_value",
]

MAV_RESULT_NAMES = {
    0: "accepted",
    1: "temporarily rejected",
    2: "denied",
    3: "unsupported",
    4: "failed",
    5: "in progress",
    6: "cancelled",
}
_IN_PROGRESS = 5
NO_ANSWER = -1
"""The result an ``optional`` command's ``on_done`` gets when nobody answered."""
_MAV_SEVERITY_WARNING = 4
NO_REASON = "no reason given"
"""What a refusal says when the autopilot gave no reason of its own."""

Done = Callable[[int, float], None]
"""Called with (MAV_RESULT, now [s]); a PARAM_VALUE answer counts as 0."""


def same_param_value(a: float, b: float) -> bool:
    """True when a PARAM_VALUE ``a`` echoes the value ``b`` that was sent: the
    same float32 (PARAM_VALUE carries REAL32), within 1e-6 relative."""
    return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-6)


@dataclass
class _Command:
    name: str
    make: Callable[[], MessageSpec]
    command: int  # MAV_CMD, or -1 when a PARAM_VALUE answers
    param: str | None
    on_done: Done
    expect: float | None = None
    optional: bool = False
    max_attempts: Callable[[], int] | None = None
    echo: float | None = None
    """The last PARAM_VALUE of ``param`` that was not ``expect`` (a mismatch)."""
    not_before: float = -math.inf
    """Not sent before this time [s]."""
    sent_at: float = 0.0
    attempts: int = 0
    texts: list[tuple[int, str]] = field(default_factory=list)
    """(MAV_SEVERITY, text) of the STATUSTEXT heard while this was pending."""


class CommandQueue:
    """Commands to one vehicle, each awaited ``timeout_s`` and sent at most
    ``attempts`` times; ``failed`` names the first command nobody answered."""

    def __init__(self, out: list[MessageSpec], *, timeout_s: float, attempts: int) -> None:
        self._out = out
        self.timeout_s = timeout_s
        self.attempts = attempts
        self._pending: _Command | None = None
        self._queue: list[_Command] = []
        self.failed: str | None = None
        self.last_sent_at = 0.0
        """When the most recently answered command was last sent [s]."""
        self.answered_texts: tuple[tuple[int, str], ...] = ()
        """The STATUSTEXT heard while the most recently answered command was
        pending (``note_text``), for its ``on_done`` to explain a refusal."""

    @property
    def busy(self) -> bool:
        return self._pending is not None or bool(self._queue)

    def push(
        self,
        now: float,
        name: str,
        make: Callable[[], MessageSpec],
        on_done: Done,
        *,
        command: int = -1,
        param: str | None = None,
        urgent: bool = False,
        expect: float | None = None,
        optional: bool = False,
        attempts: Callable[[], int] | None = None,
        not_before: float = -math.inf,
    ) -> None:
        """Queue a command (``urgent`` goes first); sends it now if idle
        (and ``not_before`` [s] has come: else at the first ``handle_timer``
        from then on, ``next_deadline`` says when).

        ``expect``: the value a PARAM_SET's echo must carry; ``optional``: no
        answer is ``on_done(NO_ANSWER)``, not a failure; ``attempts``: how
        many sends this command gets, asked at each timeout (default the
        queue's ``attempts``)."""
        cmd = _Command(name, make, command, param, on_done, expect, optional, attempts,
                       not_before=not_before)  # fmt: skip
        if urgent:
            self._queue.insert(0, cmd)
        else:
            self._queue.append(cmd)
        self._send_next(now)

    def note_text(self, severity: int, text: str) -> None:
        """A STATUSTEXT from the vehicle: it belongs to the pending command."""
        if self._pending is not None:
            self._pending.texts.append((severity, text))

    def clear(self) -> None:
        self._pending = None
        self._queue.clear()
        self.failed = None

    def on_ack(self, command: int, result: int, now: float) -> None:
        pending = self._pending
        if pending is None or pending.command != command:
            return
        if result == _IN_PROGRESS:
            pending.sent_at = now
            return
        self._answered(pending, result, now)

    def on_param(self, name: str, now: float, value: float = math.nan) -> None:
        pending = self._pending
        if pending is None or pending.param != name:
            return
        if pending.expect is not None and not same_param_value(value, pending.expect):
            pending.echo = value  # not (yet) the echo: keep waiting, resend on timeout
            return
        self._answered(pending, 0, now)

    def next_deadline(self) -> float | None:
        """When ``handle_timer`` has work: the pending command's timeout, or
        the time the next one may go (``not_before``); None: nothing to do."""
        if self._pending is not None:
            return self._pending.sent_at + self.timeout_s
        return self._queue[0].not_before if self._queue else None

    def handle_timer(self, now: float) -> None:
        """Resend an unanswered command, or give up on it (``failed``); send
        the next whose ``not_before`` has come."""
        pending = self._pending
        if pending is None:
            self._send_next(now)
            return
        if now < pending.sent_at + self.timeout_s:
            return
        limit = self.attempts if pending.max_attempts is None else pending.max_attempts()
        if pending.attempts < limit:
            self._transmit(pending, now)
        elif pending.optional:
            self._answered(pending, NO_ANSWER, now)
        else:
            self._pending = None
            self._queue.clear()
            if pending.echo is not None and pending.expect is not None:
                self.failed = (
                    f"{pending.param}: sent {pending.expect:g}, the vehicle reports "
                    f"{pending.echo:g} ({pending.attempts} attempts)"
                )
            else:
                self.failed = f"no answer to {pending.name} after {pending.attempts} attempts"

    def _answered(self, pending: _Command, result: int, now: float) -> None:
        self._pending = None
        self.last_sent_at = pending.sent_at
        self.answered_texts = tuple(pending.texts)
        pending.on_done(result, now)
        self._send_next(now)

    def _send_next(self, now: float) -> None:
        if self._pending is None and self._queue and self._queue[0].not_before <= now:
            self._transmit(self._queue.pop(0), now)

    def _transmit(self, cmd: _Command, now: float) -> None:
        spec = cmd.make()
        if cmd.attempts and spec.name == "COMMAND_LONG":
            fields = dict(spec.fields)
            fields["confirmation"] = min(cmd.attempts, 255)
            spec = MessageSpec(spec.name, fields, spec.kind)
        cmd.attempts += 1
        cmd.sent_at = now
        self._pending = cmd
        self._out.append(spec)


def refusal_reason(texts: Sequence[tuple[int, str]]) -> str:
    """The autopilot's own reasons among ``texts`` ((MAV_SEVERITY, text) heard
    while a command was pending), joined by "; ": first the ``PreArm:`` and
    ``Arm:`` lines, then any other line of severity WARNING (4) or worse, each
    once. INFO and NOTICE chatter ("Arming motors", "EKF3 IMU0 is using GPS")
    is never a reason: with nothing else, ``NO_REASON``."""
    checks = [t for _, t in texts if t.startswith(("PreArm:", "Arm:"))]
    severe = [t for sev, t in texts if sev <= _MAV_SEVERITY_WARNING and t not in checks]
    return "; ".join(dict.fromkeys(checks + severe)) or NO_REASON
