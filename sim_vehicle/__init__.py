"""sim_vehicle: a MAVLink point-mass vehicle emulator that behaves like ArduCopter 4.5 in GUIDED.

An independent MAVLink 2 peer (dialect ``ardupilotmega``; it never imports
``gcs_swarm``) hosting many vehicles in one process, vectorised. It follows
``shared/spec/mavlink-protocol.md`` wherever that sheet gives a behaviour.

Layers: ``dynamics`` (pure numpy point mass, the reference; ``dynamics_rows``
its plain-float variant for few vehicles), ``autopilot`` / ``px4`` (no I/O:
decoded messages + ``now`` -> mode, arming, setpoints, failsafe, replies),
``core`` (no I/O: the hosted vehicles, delivery, ``impairments``, the step,
the telemetry ``schedule``, ``lockstep``'s tests), ``server`` (the asyncio
shell: endpoints, the clock task, lockstep's wait), ``cli``. Where each
piece lives: docs/emulator.md, "How the code is laid out".

Test / embedding API
--------------------
::

    from sim_vehicle import Emulator, EmulatorConfig, VehicleSpec, Impairment

    cfg = EmulatorConfig(
        vehicles=(
            VehicleSpec(sysid=1),
            VehicleSpec(sysid=2, start_ned_m=(0, 5, -10), airborne=True),
        ),
        clock="lockstep",          # or "realtime" (default) with speedup=...
        dynamics="ideal",          # or "ardupilot" (0.2 s first-order accel lag, default;
        accel_shaping=None,        #   None: + ArduCopter's jerk / lean limits, docs/emulator.md)
        ekf_ready_s=0.0,           # arming refused ("PreArm: ...") until this sim time
        boot_s=1.0,                # 1 s after first contact: back to STABILIZE (0: never)
        tcp_base_port=0,           # also a TCP server per vehicle (0 ephemeral, 5760 SITL's)
    )
    async with Emulator(cfg) as emu:     # binds 127.0.0.1, port 0 = ephemeral
        emu.endpoints                    # {sysid: ("127.0.0.1", port)}; same address for all
                                         # sysids when EmulatorConfig.shared_port is set
        emu.tcp_endpoints                # {sysid: ("127.0.0.1", port)} with tcp_base_port
        addr = await emu.add_vehicle(VehicleSpec(sysid=3))   # -> (host, port) it serves on
        emu.remove_vehicle(3)            # stops it; its own endpoint is closed
        st = emu.vehicle_state(1)        # VehicleState: mode, armed, landed, pos_ned_m,
                                         # vel_ned_m_s, accel_ned_m_s2, sim_time_s, origin,
                                         # home_ned_m, params
        emu.set_param(1, "GUID_TIMEOUT", 0.5)
        await emu.wait_steps(10)         # until 10 more physics steps ran
        await emu.wait_until(lambda: emu.vehicle_state(1).armed)   # checked after every step
        emu.sim_time_s, emu.step_count, emu.stats   # stats: EmulatorStats counters

``VehicleSpec(sysid, port=None, origin=(lat, lon, alt), start_ned_m=(n, e, d),
airborne=False)``. ``EmulatorConfig(vehicles, host, base_port=0, shared_port=None,
out=None, rate_hz=50, clock, speedup=1, lockstep_timeout_s=0.5, dynamics,
accel_tau_s=None, accel_shaping=False, boot_s=0, ekf_ready_s=2,
tcp_base_port=None, noise_pos_m=0, noise_vel_m_s=0, seed=0,
uplink=Impairment(), downlink=Impairment(), streams={}, params={})``.
``Impairment(loss, delay_s, jitter_s, duplicate)``, seeded from ``seed``.

What the vehicle does (station's view)
--------------------------------------
- UDP server per endpoint: it answers every address it has heard from (send
  first, e.g. a HEARTBEAT, as ``mavutil.mavlink_connection("udpout:...")``),
  plus ``out`` if configured. System id per vehicle, component 1. With
  ``tcp_base_port`` also a TCP server per vehicle (``tcp:HOST:PORT``).
- Streams: only HEARTBEAT (1 Hz) unless asked, as ArduCopter. Ask with
  ``MAV_CMD_SET_MESSAGE_INTERVAL`` (511; interval us, 0 = default rate,
  -1 = off) or ``REQUEST_DATA_STREAM``. Streamable: SYS_STATUS 1, GPS_RAW_INT 24,
  ATTITUDE 30, LOCAL_POSITION_NED 32, GLOBAL_POSITION_INT 33,
  POSITION_TARGET_LOCAL_NED 85 (the setpoint echo: ask for it), EKF_STATUS_REPORT
  193, HOME_POSITION 242, EXTENDED_SYS_STATE 245 (landed_state).
  ``MAV_CMD_REQUEST_MESSAGE`` (512) sends one of these
  or GPS_GLOBAL_ORIGIN 49 / AUTOPILOT_VERSION 148. GPS_GLOBAL_ORIGIN and
  HOME_POSITION are also sent once when set (EKF ready; home again at arming).
- Every COMMAND_LONG / COMMAND_INT gets a COMMAND_ACK (unknown:
  MAV_RESULT_UNSUPPORTED). Modes (DO_SET_MODE 176 or SET_MODE): STABILIZE 0,
  ALT_HOLD 2, GUIDED 4, LOITER 5, RTL 6, LAND 9, POSHOLD 16, BRAKE 17.
  Arming (400) refused with MAV_RESULT_FAILED + STATUSTEXT "PreArm: ..." until
  ``ekf_ready_s``; disarms after DISARM_DELAY s armed on the ground;
  NAV_TAKEOFF (22, param7 m above home) climbs; LAND descends and disarms
  1 s after touchdown (land detector); RTL climbs to RTL_ALT, flies home,
  lands. A disarmed vehicle never moves. GCS failsafe (FS_GCS_ENABLE,
  SYSID_MYGCS) and fence (FENCE_*) as ArduCopter (docs/emulator.md).
- SET_POSITION_TARGET_LOCAL_NED: only in GUIDED, armed and airborne, with
  ArduCopter's type_mask table (accel-only 3135; velocity(+accel); position;
  position+velocity; FORCE_SET 512 -> dropped; any other combination or an
  unsupported frame -> stop and hold). Accel and velocity targets last
  GUID_TIMEOUT s, then the vehicle brakes to a hover in GUIDED.
- Parameters via PARAM_REQUEST_LIST / _READ / PARAM_SET (PARAM_VALUE replies):
  GUID_TIMEOUT, SYSID_THISMAV, WP_YAW_BEHAVIOR, DISARM_DELAY, RTL_ALT,
  WPNAV_*, PSC_JERK_XY/Z, ANGLE_MAX, FS_GCS_*, SYSID_MYGCS, FENCE_*, ... and
  the emulator's own SIM_* limits (every one: docs/emulator.md).

Lockstep rule (``clock="lockstep"``)
------------------------------------
Physics advances in fixed steps of ``1 / rate_hz`` sim seconds; telemetry due
at the new sim time is sent right after each step; inbound datagrams are
parsed on arrival and commands answered at once.

1. Sim time is frozen at 0 until every vehicle present at start has heard
   from a station (as SITL waits for its first connection). The first datagram
   from a new peer is answered with a HEARTBEAT at once, and a stream enabled by
   SET_MESSAGE_INTERVAL / REQUEST_DATA_STREAM sends its first message at once,
   so a station's whole start-up can run while the clock is frozen.
2. A vehicle *holds* the clock while it is armed, in GUIDED, airborne, and has
   received at least one SET_POSITION_TARGET_LOCAL_NED since it last became so
   (the station is streaming); vehicles started ``airborne`` hold from step 0.
3. A holding vehicle *blocks* step k+1 from the moment a LOCAL_POSITION_NED
   leaves the emulator towards it (at step k, or at once when its stream is
   enabled) until it receives a setpoint (one lost by the uplink impairment
   still counts as the answer). Step k+1 is taken as soon as no vehicle
   blocks, or when ``lockstep_timeout_s`` of wall time has passed since step k
   while one does and a few more turns of the event loop have brought no
   answer (after a stall of the whole process, a loaded machine or a garbage
   collection, the answers on their way get in first; issue 15);
   ``stats.lockstep_timeouts`` counts these. While vehicles hold but none is
   streamed LOCAL_POSITION_NED, the clock waits for the timeout too.
4. While no vehicle holds (start-up on the ground: commands, arming, takeoff),
   steps are paced at ``speedup`` x wall clock, so EKF delay, DISARM_DELAY and
   takeoff last what they last on a real vehicle.

Repeatability: each vehicle's telemetry bytes are a pure function of the
config, the seed and its inbound messages with the step they arrived in. While
holding, that step is fixed by the protocol, so a station that answers each
LOCAL_POSITION_NED (including the most recent one when it starts streaming)
with one setpoint gets identical bytes run after run on any machine, provided
``stats.lockstep_timeouts`` stays 0. Start-up under rule 4 depends on wall
time; for bit-identical runs from the first byte start the vehicles
``airborne``.

Command line: ``sim-vehicle --help`` (``sim_vehicle.cli``); add/remove vehicles
at run time by typing ``add SYSID [N,E,D]`` / ``remove SYSID`` / ``list`` on stdin.
"""

from __future__ import annotations

import os as _os

# One BLAS thread, set before numpy loads: the emulator's products are small
# and OpenBLAS's worker threads take the core of the station beside it (as
# gcs_swarm.cli; docs/architecture.md, "Threads"). A value the user set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

from sim_vehicle.config import DEFAULT_ORIGIN, EmulatorConfig, Impairment, VehicleSpec  # noqa: E402
from sim_vehicle.server import Emulator  # noqa: E402
from sim_vehicle.stats import EmulatorStats  # noqa: E402
from sim_vehicle.vehicles import VehicleState  # noqa: E402

__all__ = [
    "DEFAULT_ORIGIN",
    "Emulator",
    "EmulatorConfig",
    "EmulatorStats",
    "Impairment",
    "VehicleSpec",
    "VehicleState",
]
