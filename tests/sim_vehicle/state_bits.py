"""An object's whole state as a value compared bit for bit (floats by their
hex, so 0.0 is not -0.0), for tests that hold two paths of the emulator to
the same autopilot state."""

from __future__ import annotations

import math
from collections.abc import Collection
from typing import Any


def canon(x: Any, skip: Collection[str] = (), depth: int = 0) -> Any:
    """``x`` with floats as their hex, containers and plain objects by their
    contents; attributes or keys named in ``skip`` left out (at any depth)."""
    if depth > 6:
        return repr(type(x))
    if isinstance(x, float):
        return x.hex() if math.isfinite(x) else repr(x)
    if isinstance(x, (str, int, bool, type(None))):
        return x
    if isinstance(x, dict):
        return {k: canon(v, skip, depth + 1) for k, v in x.items() if k not in skip}
    if isinstance(x, (list, tuple)):
        return (type(x).__name__, [canon(v, skip, depth + 1) for v in x])
    if hasattr(x, "__dict__"):
        return (type(x).__name__, canon(vars(x), skip, depth + 1))
    return repr(x)
