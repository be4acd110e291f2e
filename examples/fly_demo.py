"""Fly the paper's Example 1: six emulated copters settle as an octahedron
(the bundled emulator in lockstep: about 7 s). ``python examples/fly_demo.py``"""

import sys
from pathlib import Path

import gcs_swarm

mission = Path(__file__).resolve().parents[1] / "config/missions/example1_octahedron.yaml"
summary = gcs_swarm.run(mission)
print(summary.format())
sys.exit(0 if summary.outcome == "completed" else 1)
