"""Unit tests of the pure pieces: dynamics (Eqs. D1-D4), the vectorised codec, imports."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav

from sim_vehicle.codec import encode_local_position_ned, lpn_frames_small
from sim_vehicle.dynamics import DynParams, KinState, step
from sim_vehicle.fleet import Fleet
from sim_vehicle.small import SMALL_N

DT = 0.02


def _params(n: int, tau: float, acc_max: float = 50.0) -> DynParams:
    return DynParams(np.full(n, tau), np.full(n, acc_max), np.zeros(n))


def _airborne(n: int) -> KinState:
    st = KinState.zeros(n)
    st.pos_ned_m[:, 2] = -10.0
    return KinState(st.pos_ned_m, st.vel_ned_m_s, st.acc_ned_m_s2, np.zeros(n, dtype=bool))


def test_ideal_constant_acceleration_matches_closed_form() -> None:
    rng = np.random.default_rng(1)
    n, steps = 7, 500
    a = rng.uniform(-2, 2, (n, 3))
    a[:, 2] = -np.abs(a[:, 2])  # climbing, so the ground never interferes
    st = _airborne(n)
    p0 = st.pos_ned_m.copy()
    for _ in range(steps):
        st = step(st, a, DT, _params(n, 0.0))
    t = steps * DT
    # Eq. D2 with tau = 0 is exact for constant acceleration; 1e-9 leaves room for
    # 500 steps of float64 rounding on values of order 100 m.
    np.testing.assert_allclose(st.pos_ned_m, p0 + 0.5 * a * t * t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(st.vel_ned_m_s, a * t, rtol=0, atol=1e-9)


def test_lagged_step_matches_first_order_solution() -> None:
    tau, c, steps = 0.2, 1.0, 150
    st = _airborne(1)
    cmd = np.array([[c, 0.0, 0.0]])
    for _ in range(steps):
        st = step(st, cmd, DT, _params(1, tau))
    t = steps * DT
    e = math.exp(-t / tau)
    # closed form of Eq. D1 from rest: a = c(1-e), v = c(t - tau(1-e)),
    # p = c(t^2/2 - tau t + tau^2 (1-e))
    assert abs(st.acc_ned_m_s2[0, 0] - c * (1 - e)) < 1e-12
    assert abs(st.vel_ned_m_s[0, 0] - c * (t - tau * (1 - e))) < 1e-9
    assert abs(st.pos_ned_m[0, 0] - c * (t * t / 2 - tau * t + tau * tau * (1 - e))) < 1e-9


def test_drag_gives_the_first_order_velocity_of_a_dragged_point_mass() -> None:
    """Eq. D7 with no lag: dv/dt = c - k v from rest gives v = c/k (1 - exp(-k t)),
    PX4 SIH's terminal speed c/k under a held acceleration setpoint (measured on PX4
    SITL: 1.0 m/s under 1 m/s^2 east, docs/sitl.md). Explicit drag at h = 0.02 s and
    k = 1/s: the error is about k h / 2 = 1 % of the velocity change, hence 0.01 c/k."""
    k, c, steps = 1.0, 0.5, 300
    st = _airborne(1)
    par = DynParams(np.zeros(1), np.full(1, 50.0), np.zeros(1), drag_1_s=np.full(1, k))
    for _ in range(steps):
        st = step(st, np.array([[c, 0.0, 0.0]]), DT, par)
    t = steps * DT
    want = c / k * (1 - math.exp(-k * t))
    assert abs(st.vel_ned_m_s[0, 0] - want) < 0.01 * c / k
    assert st.vel_ned_m_s[0, 0] < c / k  # never past the terminal speed
    undragged = DynParams(np.zeros(1), np.full(1, 50.0), np.zeros(1), drag_1_s=np.zeros(1))
    st0 = _airborne(1)
    for _ in range(steps):
        st0 = step(st0, np.array([[c, 0.0, 0.0]]), DT, undragged)
    assert abs(st0.vel_ned_m_s[0, 0] - c * t) < 1e-9  # k = 0: Eq. D2 untouched


def test_command_norm_is_clamped() -> None:
    st = _airborne(1)
    st = step(st, np.array([[30.0, 40.0, 0.0]]), DT, _params(1, 0.0, acc_max=5.0))
    np.testing.assert_allclose(st.acc_ned_m_s2[0], [3.0, 4.0, 0.0], atol=1e-12)


def test_ground_plane_stops_a_descent_and_lands() -> None:
    st = _airborne(1)
    st.vel_ned_m_s[0] = [1.0, 0.0, 5.0]  # diving at 5 m/s
    for _ in range(200):
        st = step(st, np.array([[0.0, 0.0, 1.0]]), DT, _params(1, 0.0))
    assert st.pos_ned_m[0, 2] == 0.0
    assert st.landed[0]
    np.testing.assert_array_equal(st.vel_ned_m_s[0], [0.0, 0.0, 0.0])


def test_lpn_encoders_are_byte_identical_to_pymavlink() -> None:
    rng = np.random.default_rng(7)
    n = 300
    pos, vel = rng.normal(size=(n, 3)) * 50, rng.normal(size=(n, 3))
    vel[::3, 2] = 0.0  # trailing zero bytes are trimmed in MAVLink 2
    vel[::5] = 0.0
    pos[::10] = 0.0
    t = rng.integers(0, 2**32, n)
    t[::10] = 0
    seq, sysid = rng.integers(0, 256, n), rng.integers(1, 255, n)
    buf, lens = encode_local_position_ned(t, pos, vel, seq, sysid, np.ones(n, dtype=np.int64))
    small = lpn_frames_small(
        t.tolist(), pos.tolist(), vel.tolist(), seq.tolist(), sysid.tolist(), [1] * n
    )
    assert small is not None
    for i in range(n):
        enc = mav.MAVLink(None, int(sysid[i]), 1)
        enc.seq = int(seq[i])
        ref = mav.MAVLink_local_position_ned_message(
            int(t[i]), *map(float, pos[i]), *map(float, vel[i])
        ).pack(enc)
        assert buf[i, : lens[i]].tobytes() == ref, i
        assert small[i] == ref, i
    assert lpn_frames_small([0], [[1e39, 0.0, 0.0]], [[0.0] * 3], [0], [1], [1]) is None


def test_dynamics_imports_only_numpy() -> None:
    src = Path(__file__).parents[2] / "sim_vehicle" / "dynamics.py"
    names = set()
    for node in ast.walk(ast.parse(src.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module.split(".")[0])
    # the reference: numpy only (its plain-float variant is dynamics_rows)
    assert names <= {"__future__", "dataclasses", "numpy"}, names


def test_sim_vehicle_never_imports_gcs_swarm() -> None:
    pkg = Path(__file__).parents[2] / "sim_vehicle"
    for src in pkg.glob("*.py"):
        for node in ast.walk(ast.parse(src.read_text())):
            mods = []
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                mods = [node.module]
            assert not any(m.startswith("gcs_swarm") for m in mods), src


def test_exported_names() -> None:
    import sim_vehicle

    assert sorted(sim_vehicle.__all__) == [
        "DEFAULT_ORIGIN",
        "Emulator",
        "EmulatorConfig",
        "EmulatorStats",
        "Impairment",
        "VehicleSpec",
        "VehicleState",
    ]


def test_fast_setpoint_decoder_agrees_with_pymavlink() -> None:
    from sim_vehicle.codec import decode_setpoint

    def _fast_setpoint(frame: bytes) -> mav.MAVLink_message | None:  # a whole frame
        sp = decode_setpoint(frame, 0, frame[1])
        return None if sp is None else sp.message()

    rng = np.random.default_rng(3)
    enc = mav.MAVLink(None, 255, 190)
    for i in range(200):
        vals = [float(np.float32(v)) for v in rng.normal(size=11)]
        if i % 3 == 0:
            vals[3:] = [0.0] * 8  # trailing zeros: truncated payload
        frame = enc.set_position_target_local_ned_encode(
            i, int(rng.integers(0, 255)), 1, int(rng.integers(0, 12)), int(rng.integers(0, 4096)),
            *vals,
        ).pack(enc)  # fmt: skip
        ref = mav.MAVLink(None, 0, 0).parse_buffer(frame)[0]
        got = _fast_setpoint(frame)
        assert got is not None and got.to_dict() == ref.to_dict()
        assert got.get_msgId() == 84
        bad = frame[:-1] + bytes(((frame[-1] + 1) % 256,))
        assert _fast_setpoint(bad) is None  # CRC checked
    hb = enc.heartbeat_encode(6, 8, 0, 0, 0).pack(enc)
    assert _fast_setpoint(hb) is None


def _awkward(rng: np.random.Generator, shape: tuple[int, ...], scale: float) -> np.ndarray:
    """Random values with many exact zeros, negative zeros and repeats (the ties where
    numpy's and Python's min / max / clip could pick a different zero)."""
    x = rng.standard_normal(shape) * scale * 10.0 ** rng.uniform(-3, 1, shape)
    pick = rng.integers(0, 8, shape)
    x = np.where(pick == 0, 0.0, x)
    x = np.where(pick == 1, -0.0, x)
    return np.where(pick == 2, np.round(x), x)


def _random_fleet(rng: np.random.Generator, n: int) -> Fleet:
    f = Fleet()
    for i in range(n):
        f.add(i + 1, 1, (0.0, 0.0, 0.0), landed=False)
    for name in ("pos", "vel", "acc", "a_ff", "p_t", "v_t"):
        setattr(f, name, _awkward(rng, (n, 3), 5.0))
    f.wp = rng.integers(0, 2, (n, 3)).astype(float)
    f.wv = rng.integers(0, 2, n).astype(float)
    for name, lo, hi in (
        ("vmax_xy", 0.0, 12.0), ("vmax_up", 0.0, 3.0), ("vmax_dn", 0.0, 2.0),
        ("acc_lim", 0.0, 8.0), ("acc_max", 0.0, 8.0), ("tau", -0.1, 0.4),
    ):  # fmt: skip
        v = rng.uniform(lo, hi, n)
        v = np.where(rng.integers(0, 5, n) == 0, 0.0, v)  # zero limits, ideal dynamics
        setattr(f, name, v)
    f.shp = _awkward(rng, (n, 3), 5.0)  # the jerk limiter's state (Eqs. D5-D6)
    for name, hi in (("jerk_xy", 20.0), ("jerk_z", 20.0), ("lean", 8.0)):
        v = rng.uniform(0.0, hi, n)
        pick = rng.integers(0, 4, n)  # unlimited (the ideal preset), zero, or a limit
        setattr(f, name, np.where(pick == 0, np.inf, np.where(pick == 1, 0.0, v)))
    f.drag = np.where(rng.integers(0, 2, n) == 0, 0.0, rng.uniform(0.0, 2.0, n))  # Eq. D7
    f.ground = np.where(rng.integers(0, 3, n) == 0, f.pos[:, 2], rng.uniform(-1, 1, n))
    f.pos[:, 2] = np.where(rng.integers(0, 4, n) == 0, f.ground + 1e-3, f.pos[:, 2])
    return f


def test_small_step_is_bit_identical_to_numpy() -> None:
    """advance_small (the Fleet path below small.SMALL_N vehicles) against the numpy path:
    the same bits on 3000 random fleets of 1 to SMALL_N - 1 vehicles, several steps
    each, with zeros of both signs, ties, landings, ideal (tau <= 0) vehicles, jerk /
    lean limits (Eqs. D5-D6) infinite, zero or finite, including the shaped command,
    and drag (Eq. D7) zero or not."""
    rng = np.random.default_rng(8)
    small_runs = 0
    for case in range(3000):
        n = case % (SMALL_N - 1) + 1
        fast = _random_fleet(rng, n)
        ref = Fleet()
        ref.__dict__.update({k: (v.copy() if isinstance(v, np.ndarray) else v)
                             for k, v in fast.__dict__.items()})  # fmt: skip
        for _ in range(3):
            small_runs += fast._step_small(DT)
            ref.step_numpy(DT)
            for name in ("pos", "vel", "acc", "landed", "shp"):
                got, want = getattr(fast, name), getattr(ref, name)
                assert got.dtype == want.dtype and got.shape == want.shape, (case, name)
                assert got.tobytes() == want.tobytes(), (case, name, got, want)
    assert small_runs == 3 * 3000  # every case ran the small path (none fell back)


def test_small_step_falls_back_to_numpy_on_a_domain_error() -> None:
    f = _random_fleet(np.random.default_rng(3), 4)
    f.acc_lim[:] = -1.0  # sqrt of a negative: numpy warns and gives NaN, math raises
    assert not f._step_small(DT)


def test_lpn_frames_from_lists_are_byte_identical() -> None:
    """Fleet.lpn_frames_rows (the schedule's path below small.SMALL_N rows: lists, round()) against
    Fleet.lpn_frames fed as before (numpy arrays, np.rint) on 3000 random cases: the same
    frames and the same sequence numbers afterwards. One case in 20 is a fleet of
    33-255 (beyond SMALL_N: the rows' values taken alone) with 1-5 rows, as a stream's
    first report is one row of a network."""
    rng = np.random.default_rng(32)
    for case in range(3000):
        large = case % 20 == 0
        n = int(rng.integers(33, 256)) if large else case % 12 + 1
        fast = _random_fleet(rng, n)
        fast.seq = rng.integers(0, 256, n)
        fast.boot = np.where(rng.integers(0, 2, n) == 0, 0.0, rng.uniform(0, 100, n))
        ref = Fleet()
        ref.__dict__.update({k: (v.copy() if isinstance(v, np.ndarray) else v)
                             for k, v in fast.__dict__.items()})  # fmt: skip
        rows = np.flatnonzero(rng.integers(0, 3, n) > 0)
        if large:
            rows = np.sort(rng.choice(n, int(rng.integers(1, 6)), replace=False))
        now = float(rng.uniform(0, 200)) if case % 3 else round(float(rng.uniform(0, 200)), 3)
        boot = fast.boot.tolist()
        got = fast.lpn_frames_rows(rows.tolist(), [round((now - boot[r]) * 1000.0) for r in rows])
        t_ms = np.rint((now - ref.boot[rows]) * 1000.0).astype(np.int64)
        want = ref.lpn_frames(rows, t_ms, ref.pos[rows], ref.vel[rows])
        assert got == want, case
        assert fast.seq.tolist() == ref.seq.tolist(), case
    big = Fleet()
    big.add(1, 1, (1e39, 0.0, 0.0), landed=False)
    assert big.lpn_frames_rows([0], [0]) is None and big.seq.tolist() == [0]


def test_a_rows_feed_forward_is_its_last_target_at_the_step() -> None:
    """``Fleet.set_target`` writes ``a_ff`` at the next step (one numpy write
    per step, not per setpoint): several targets of a row between two steps,
    streamed (only ``a_ff`` new) or whole, rows added and removed between,
    step the fleet as the last target of each row alone does."""
    from sim_vehicle.targets import ControlTarget

    rng = np.random.default_rng(8)
    many, last = Fleet(), Fleet()
    for f in (many, last):
        for i in range(6):
            f.add(i + 1, 1, (float(i), 0.0, -10.0), landed=False)
    base = ControlTarget(wv=1.0)
    prev: list[ControlTarget | None] = [None] * 6
    for k in range(40):
        final: dict[int, ControlTarget] = {}
        for _ in range(int(rng.integers(1, 15))):
            row = int(rng.integers(0, many.n))
            a = tuple(float(x) for x in rng.normal(0.0, 2.0, 3))
            tg = base._replace(a_ff=a) if rng.random() < 0.8 else ControlTarget(a_ff=a, wv=0.5)
            many.set_target(row, tg, prev[row])
            prev[row] = final[row] = tg
        if k == 20:  # a row leaves between a target and the step: the rest keep theirs
            for f in (many, last):
                f.remove(2)
            prev.pop(2)
            final = {r - (r > 2): t for r, t in final.items() if r != 2}
        for row, tg in final.items():
            last.set_target(row, tg)
        many.step(0.02)
        last.step(0.02)
        for name in ("pos", "vel", "acc", "a_ff"):
            np.testing.assert_array_equal(getattr(many, name), getattr(last, name), err_msg=name)
    assert np.abs(many.a_ff).max() > 1.0


def test_a_ff_batches_and_single_rows_keep_the_order_they_were_set_in() -> None:
    """The deferred lane's batches (``set_a_ff_rows``, an array per network,
    a row twice in one) and single rows (``set_a_ff``) interleaved between
    two steps: each row's ``a_ff`` at the step is the last set, as setting
    them one at a time in the same order gives (the bits, -0.0 included)."""
    rng = np.random.default_rng(19)
    batched, one_by_one = Fleet(), Fleet()
    for f in (batched, one_by_one):
        for i in range(9):
            f.add(i + 1, 1, (float(i), 0.0, -10.0), landed=False)
    duplicated = 0
    for _ in range(60):
        for _ in range(int(rng.integers(1, 5))):
            if rng.random() < 0.5:
                rows = rng.integers(0, 9, int(rng.integers(1, 12))).tolist()
                a = rng.normal(0.0, 2.0, (len(rows), 3))
                a[rng.random(a.shape) < 0.1] = -0.0
                duplicated += len(set(rows)) < len(rows)
                batched.set_a_ff_rows(rows, a)
                for r, v in zip(rows, a.tolist(), strict=True):
                    one_by_one.set_a_ff(r, (v[0], v[1], v[2]))
            else:
                r = int(rng.integers(0, 9))
                v = tuple(float(x) for x in rng.normal(0.0, 2.0, 3))
                batched.set_a_ff(r, v)  # type: ignore[arg-type]
                one_by_one.set_a_ff(r, v)  # type: ignore[arg-type]
        batched.step(0.02)
        one_by_one.step(0.02)
        assert batched.a_ff.tobytes() == one_by_one.a_ff.tobytes()
        assert batched.pos.tobytes() == one_by_one.pos.tobytes()
    assert duplicated > 10  # the case of a row twice in one batch was met
