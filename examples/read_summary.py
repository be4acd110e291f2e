"""Fly a mission and read its summary: each vehicle's final radius round
the virtual leader, the distances between vehicles, the shape they make.

    python examples/read_summary.py [MISSION]   (default: Example 1, the octahedron)
"""

import sys
from pathlib import Path

import numpy as np

import gcs_swarm
from gcs_swarm.analysis import group_values, pairwise_distances, shape_name

ROOT = Path(__file__).resolve().parents[1]
path = sys.argv[1] if len(sys.argv) > 1 else ROOT / "config/missions/example1_octahedron.yaml"
summary = gcs_swarm.run(path)
print(f"outcome: {summary.outcome}, {summary.steps} control steps")
positions = summary.positions()  # system id -> final position, mission frame [m]
leader = np.asarray(summary.leader_pos_m)
for sysid, p in sorted(positions.items()):
    print(f"vehicle {sysid}: radius {np.linalg.norm(p - leader):.5f} m")
distances = pairwise_distances(np.array(list(positions.values())))
groups = ", ".join(f"{n} x {d:.5f} m" for d, n in group_values(distances, tol=1e-3))
print(f"{shape_name(len(positions))}: distances {groups}")
print(f"closest approach in flight: {summary.min_separation_m:.3f} m")
sys.exit(0 if summary.outcome == "completed" else 1)
