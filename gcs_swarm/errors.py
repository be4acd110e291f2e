"""The one exception tree of gcs_swarm.

::

    SwarmError                      anything the command line prints as one line
     +-- MissionError(ValueError)   a mission file is malformed or inconsistent
     +-- UsageError(ValueError)     a command-line argument is malformed
     +-- ExpressionError(ValueError) a leader-force expression does not parse or
     |                               uses a name that is not allowed
     +-- LinkError(OSError)         a MAVLink connection string or transport failed
     +-- VehicleError               a vehicle refused or did not answer (names the
     |    |                          vehicle and carries its own STATUSTEXT)
     |    +-- StartupError          the swarm could not be readied in time
     +-- ReportError(OSError)       a run folder, summary, picture or log failed
     +-- InfeasibleError            the safety filter cannot satisfy its constraints

The command line (``gcs_swarm.cli``) catches ``SwarmError``, prints ``str(err)``
as a single line and exits non-zero: 1 when a vehicle or a link failed
(``VehicleError``, ``LinkError``, ``InfeasibleError``), 2 for everything
refused before anything flew. Any other exception is a bug and keeps its
traceback.
"""

from __future__ import annotations

from collections.abc import Mapping

__all__ = [
    "ExpressionError",
    "InfeasibleError",
    "LinkError",
    "MissionError",
    "ReportError",
    "StartupError",
    "SwarmError",
    "UsageError",
    "VehicleError",
]


class SwarmError(Exception):
    """Base of every error the command line reports as one line."""


class MissionError(SwarmError, ValueError):
    """A mission file is malformed or inconsistent.

    ``str()`` is a single line naming file, line, key path, what was expected
    and what was found, e.g.
    ``mission.yaml:14: vehicles[2].sysid: expected an integer 1..255, got "x"``.
    When the loader finds several problems, ``problems`` lists them (one line
    each, file order) and ``str()`` joins them with newlines.
    """

    def __init__(self, message: str, problems: tuple[str, ...] | list[str] = ()) -> None:
        super().__init__(message)
        self.problems: tuple[str, ...] = tuple(problems) if problems else (message,)


class UsageError(SwarmError, ValueError):
    """A command-line argument is malformed (``--duration -5``, ``--out t.txt``)."""


class ExpressionError(SwarmError, ValueError):
    """A leader-force expression does not parse or uses a forbidden name."""


class LinkError(SwarmError, OSError):
    """A MAVLink connection string is malformed or its transport failed."""


class VehicleError(SwarmError):
    """A vehicle refused a command or stopped answering.

    ``reasons`` maps each vehicle it is about to what happened to it, in the
    vehicle's own words where it gave any (its STATUSTEXT or PX4 EVENT);
    ``sysids`` lists them. A vehicle is named by its key: its system id, plus
    network index * 256 on a mission's later network (``mission.model.vehicle_key``;
    ``mission.model.key_label`` turns it back into ``network:sysid``).

    The message names the vehicle (its system id, or ``network:sysid`` on a
    named network) and, where there is one, quotes the vehicle's own
    STATUSTEXT.
    """

    def __init__(self, message: str, reasons: Mapping[int, str] | None = None) -> None:
        super().__init__(message)
        self.reasons: dict[int, str] = dict(reasons) if reasons else {}

    @property
    def sysids(self) -> tuple[int, ...]:
        return tuple(sorted(self.reasons))


class StartupError(VehicleError):
    """The swarm could not be readied within the start-up timeout."""


class ReportError(SwarmError, OSError):
    """A run folder, summary, picture or log could not be created, written or read."""


class InfeasibleError(SwarmError):
    """The safety filter's constraints conflict and no command satisfies them all."""
