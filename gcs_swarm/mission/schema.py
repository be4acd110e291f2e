"""JSON Schema (draft 2020-12) of the mission format, generated from the same
field declarations the validator uses (``gcs_swarm.mission.format``).

Editors that understand JSON Schema (VS Code's YAML extension, JetBrains IDEs)
then autocomplete and check mission files. The schema is a little looser than
the validator: cross-field rules (duplicate system ids, px4 not supported yet,
events for reserves, ...) are only in ``gcs-swarm check``.
"""

from __future__ import annotations

from typing import Any

from gcs_swarm.mission.format import MISSION

__all__ = ["schema"]


def schema() -> dict[str, Any]:
    """The JSON Schema of a mission file, as a JSON-ready dict."""
    out: dict[str, Any] = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "gcs-swarm mission",
        "description": (
            "A gcs-swarm mission file. Units are SI; positions are in the mission frame "
            "(x east, y north, z up, metres from the mission origin)."
        ),
    }
    out.update(MISSION.schema())
    # Exactly one of the two: the vehicles on one network, or named networks.
    out["oneOf"] = [{"required": ["vehicles"]}, {"required": ["networks"]}]
    return out
