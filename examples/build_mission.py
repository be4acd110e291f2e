"""Build a mission in code: N emulated copters on a ring, the paper's gains,
checked by the same validator as a mission file (a mistake is a MissionError
naming the key), simulated, then flown.

    python examples/build_mission.py [N]   (default 5: a triangular bipyramid)
"""

import sys

import yaml

import gcs_swarm

n = int(sys.argv[1]) if len(sys.argv) > 1 else 5
spec = {
    "mission": {"name": f"{n} on a ring", "duration": 60, "rate": 50, "end": "hold"},
    "emulator": {"dynamics": "ideal", "mode": "lockstep"},
    "leader": {"start": [0, 0, 10], "force": [0, 0, 0]},
    "vehicles": [
        {"sysid": i + 1, "start": [3.0 * ((i % 3) - 1), 3.0 * ((i // 3) - 1), 8.0 + i]}
        for i in range(n)
    ],
}
mission = gcs_swarm.parse_mission(yaml.safe_dump(spec), f"<{n} on a ring>")
print(gcs_swarm.simulate(mission).text())  # the reference, in process
summary = gcs_swarm.run(mission)  # the same over MAVLink, on the emulator
print(summary.format())
sys.exit(0 if summary.outcome == "completed" else 1)
