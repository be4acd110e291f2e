"""Fly from your own asyncio program: the flight is one task among yours.
Here a second task watches the status lines while the swarm flies, and the
flight is given a deadline: cancelling it ends the flight the defined way
(zero acceleration, then the mission's end action for every vehicle).

    python examples/own_event_loop.py [MISSION]   (default: Example 1, the octahedron)
"""

import asyncio
import sys
from pathlib import Path

import gcs_swarm

ROOT = Path(__file__).resolve().parents[1]
path = sys.argv[1] if len(sys.argv) > 1 else ROOT / "config/missions/example1_octahedron.yaml"


async def main() -> int:
    lines: asyncio.Queue[str] = asyncio.Queue()

    async def watch() -> None:
        while True:
            line = await lines.get()
            print(f"[status] {line}")

    watcher = asyncio.create_task(watch())
    try:
        async with asyncio.timeout(300):  # your own deadline for the whole flight
            summary = await gcs_swarm.fly(path, on_status=lines.put_nowait)
    finally:
        watcher.cancel()
    print(summary.format())
    return 0 if summary.outcome == "completed" else 1


sys.exit(asyncio.run(main()))
