"""Hostile mission files (issue 15, items 1, 2, 6, 9, 10, 13): each is refused
by ``check`` (and so by ``run`` and ``simulate``, which load the same way)
with exactly one ``file:line: key.path: message`` line, never a traceback."""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

from gcs_swarm.commands import check_command
from gcs_swarm.control.expr import compile_expression
from gcs_swarm.control.formation import eq1_acceleration, formation_force
from gcs_swarm.control.params import Gains, Readings
from gcs_swarm.errors import ExpressionError, MissionError
from gcs_swarm.mavlink import inbound
from gcs_swarm.mavlink.codec import SIGNING_KEY_BYTES
from gcs_swarm.mavlink.vehicle import ACCEL_CEILING_MPS2
from gcs_swarm.mission import load_mission, parse_mission
from gcs_swarm.mission.checks import SAME_POINT_M

LINE_RE = re.compile(r"^m\.yaml:(\d+): (\S+): (.+)$")


def doc(
    *,
    duration: str = "60",
    force: str = "[0, 0, 0]",
    sysid: str = "1",
    start: str = "[2, 1, 2]",
    head: str = "",
    tail: str = "",
) -> str:
    return (
        f"mission: {{duration: {duration}, rate: 50{head}}}\n"  # line 1
        "emulator: {dynamics: ideal}\n"
        "leader:\n"
        "  start: [0, 0, 0]\n"
        f"  force: {force}\n"  # line 5
        "vehicles:\n"
        f"  - {{sysid: {sysid}, start: {start}}}\n"  # line 7
        "  - {sysid: 2, start: [-1, -1, -1]}\n"
        f"{tail}"
    )


def one_problem(text: str) -> tuple[int, str, str]:
    """The single problem line of ``text`` as (line, key path, message)."""
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    lines = str(info.value).splitlines()
    assert len(lines) == 1, lines
    m = LINE_RE.match(lines[0])
    assert m is not None, lines[0]
    return int(m[1]), m[2], m[3]


# ------------------------------------------------------------- item 1
@pytest.mark.parametrize(
    ("expr", "why"),
    [
        ("1/0", "division by zero"),
        ("sqrt(-1)", "math domain error"),
        ("log(0)", "math domain error"),
        ("9**9**9", "math range error"),
        ("10.0**400", "math range error"),
        ("1e999", "not a finite number"),
        ("x % 0", "modulo"),
        ("1/t", "t=0: float division by zero"),
        ("sqrt(3 - t)", "t=3.01: math domain error"),  # inside the 60 s, not at its start
        ("(-8)**(1/3)", "math domain error"),  # Python's ** would give a complex number
        ("exp(t*100)", "acceleration (Eq. 13) reaches"),  # 1000 m/s^2 before it overflows
        ("hypot(1e308, 1e308, 1e308)", "acceleration (Eq. 13) reaches"),
        ("9" * 400, "literal a 400-digit integer is not a finite number"),
    ],
)
def test_check_flies_the_leader_over_the_whole_mission(expr: str, why: str) -> None:
    line, path, message = one_problem(doc(force=f'["{expr}", 0, 0]'))
    assert line == 5 and path in ("leader.force[0]", "leader.force")
    assert why in message


def test_the_failing_component_is_named_and_a_good_leader_passes() -> None:
    line, path, message = one_problem(doc(force='[1, "2*sin(t)", "sqrt(30 - t)"]'))
    assert (line, path) == (5, "leader.force[2]")
    assert "t=30.01" in message  # the first RK4 stage past t = 30 s
    m = parse_mission(doc(force='[1, "2*sin(t)", "sqrt(70 - t)"]'), "m.yaml")
    assert m.law.leader.force.exprs[2] == "sqrt(70 - t)"  # type: ignore[union-attr]


def test_a_constant_force_that_leaves_the_bounds_is_refused() -> None:
    # 10 N at damping 10 N s/m: 1 m/s, so 100 km after 100,000 s > the 4 h bound,
    # but at 500 N the terminal 50 m/s crosses 100 km in 2,000 s.
    assert parse_mission(doc(force="[10, 0, 0]", duration="3600"), "m.yaml")
    line, path, message = one_problem(doc(force="[500, 0, 0]", duration="3600"))
    assert (line, path) == (5, "leader.force")
    assert message.startswith("the leader reaches x = 100") and "beyond 100000 m" in message
    line, path, message = one_problem(doc(force="[2500, 0, 0]"))
    assert "acceleration (Eq. 13) is 2500 m/s^2 at t = 0" in message


def test_the_evaluator_itself_never_returns_a_non_finite_or_complex_value() -> None:
    for text in ("(-8)**(1/3)", "9**9**9", "hypot(1e308, 1e308) * 2", "1e308*10 - 1e308*10"):
        with pytest.raises(ExpressionError):
            compile_expression(text)({})
    with pytest.raises(ExpressionError, match="400-digit integer is not a finite number"):
        compile_expression("x + " + "1" * 400)
    assert compile_expression("2**0.5")({}) == pytest.approx(math.sqrt(2), rel=1e-15)


# ------------------------------------------------------------- item 2
HUGE = "9" * 400
HUGER = "9" * 5000


@pytest.mark.parametrize(
    ("text", "where", "why"),
    [
        (doc(duration=HUGE), (1, "mission.duration"), "400-digit integer is too large"),
        (doc(duration=HUGER), (1, "mission.duration"), "5000-digit integer is too large"),
        (doc(sysid=HUGE), (7, "vehicles[0].sysid"), "400-digit integer is too large"),
        (doc(sysid=HUGER), (7, "vehicles[0].sysid"), "5000-digit integer is too large"),
        (doc(start=f"[{HUGE}, 0, 1]"), (7, "vehicles[0].start[0]"), "too large"),
        (doc(start=f"[{HUGER}, 0, 1]"), (7, "vehicles[0].start[0]"), "too large"),
        (doc(force=f'["x + {HUGE}", 0, 0]'), (5, "leader.force[0]"), "not a finite number"),
        (doc(force=f'["{HUGER}", 0, 0]'), (5, "leader.force[0]"), "at most 1000 allowed"),
        (doc().replace("rate: 50", "rate: !!float abc"), (1, "mission.rate"), "got abc"),
        (doc(sysid="!!int x1"), (7, "vehicles[0].sysid"), "got x1"),
        ("[" * 5000, (1, "(syntax)"), "nested more than 64 levels deep"),
        ("vehicles: " + "[" * 5000 + "]" * 5000, (1, "(syntax)"), "nested more than 64"),
    ],
    ids=[
        "duration400", "duration5000", "sysid400", "sysid5000", "start400", "start5000",
        "expr400", "expr5000", "float-abc", "int-x1", "nest", "nest-closed",
    ],
)  # fmt: skip
def test_hostile_numbers_and_yaml_are_one_line(text: str, where: tuple[int, str], why: str) -> None:
    line, path, message = one_problem(text)
    assert (line, path) == where
    assert why in message


def test_a_megabyte_of_brackets_is_refused_without_a_hang() -> None:
    # PyYAML's scanner works in proportion to the flow depth for each token:
    # 5,000 "[" took seconds and 200,000 would never end; the watchdog turns
    # a hang into a failure (it is not a timing: documents take milliseconds).
    from missionfuzz import watchdog

    with watchdog(60):
        line, path, message = one_problem("[" * 200_000)
    assert (line, path) == (1, "(syntax)") and "nested more than 64 levels" in message
    # Block nesting (indentation) is bounded by the composer.
    deep = "".join(f"{' ' * k}k{k}:\n" for k in range(100)) + " " * 100 + "v: 1\n"
    with watchdog(60):
        line, path, message = one_problem(deep)
    assert path == "(syntax)" and "nested more than 64 levels" in message and line == 64


# ------------------------------------------------------------- item 6
def test_only_regular_files_are_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # opening it would block until a writer came
    for path in ("/dev/zero", str(fifo), str(tmp_path)):
        assert check_command(path) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1
        assert err.startswith(f"{path}:1: (file): cannot read the file: ")
        assert "not a regular file" in err or "a directory" in err
    # The key file is checked too, at its line; the content is never shown.
    monkeypatch.chdir(tmp_path)
    for key_file, why in (
        ("/dev/zero", "not a regular file"),
        ("nope.key", "No such file"),
        ("short.key", f"expected a {SIGNING_KEY_BYTES}-byte signing key"),
    ):
        (tmp_path / "short.key").write_bytes(b"secret")
        line, path, message = one_problem(doc(head=f", signing: {{key_file: {key_file}}}"))
        assert (line, path) == (1, "mission.signing.key_file") and why in message
        assert "secret" not in message
    (tmp_path / "good.key").write_text("ab" * 32 + "\n")
    assert parse_mission(doc(head=", signing: {key_file: good.key}"), "m.yaml")
    from gcs_swarm.mission import source  # new in issue 15: inside, so the others run before

    assert source.SIGNING_KEY_BYTES == SIGNING_KEY_BYTES


def test_4000_vehicles_packed_0_1_mm_apart_give_capped_problems() -> None:
    lines = ["limits: {safety: {enabled: true}}", "vehicles:"]
    lines += [f"  - {{sysid: {1 + i % 250}, start: [{i * 1e-4:.4f}, 0, 2]}}" for i in range(4000)]
    with pytest.raises(MissionError) as info:
        parse_mission("\n".join(lines) + "\n", "m.yaml")
    got = str(info.value).splitlines()
    starts = [g for g in got if ".start" in g]
    assert len(starts) == 21  # the first 20, then one line with the count
    assert starts[0] == (
        "m.yaml:4: vehicles[1].start: 0.0001 m from vehicles[0], closer than"
        " limits.safety.separation = 1"
    )
    assert starts[-1] == (
        "m.yaml:24: vehicles[].start: 3979 more problems of this kind not shown (the first 20 are)"
    )
    assert len(got) <= 2 * 21  # and as many for the repeated system ids


class _Counted(list[tuple[float, float, float]]):
    """A list of points counting how often a point is read."""

    reads = 0

    def __getitem__(self, i):  # type: ignore[no-untyped-def]
        type(self).reads += 1
        return super().__getitem__(i)


@pytest.mark.parametrize("layout", ["packed", "two-clusters", "lattice", "random"])
def test_the_start_separation_search_reads_each_point_a_bounded_number_of_times(
    layout: str,
) -> None:
    from gcs_swarm.mission.checks import earlier_within

    n, r = 4000, 1.0
    rng = np.random.default_rng(7)
    if layout == "packed":
        pts = [(i * 1e-4, 0.0, 2.0) for i in range(n)]
    elif layout == "two-clusters":  # 1.7 r apart: the pairs across are not within r
        pts = [((i % 2) * 1.7 * r + 1e-7 * i, 0.0, 0.0) for i in range(n)]
    elif layout == "lattice":  # exactly r apart: nothing within r
        pts = [(float(i % 16), float(i // 16 % 16), float(i // 256)) for i in range(n)]
    else:
        pts = [tuple(p) for p in rng.uniform(-20.0, 20.0, (n, 3))]
    counted = _Counted(pts)
    _Counted.reads = 0
    got = earlier_within(counted, r)
    # 124 neighbour searches at most per point (docstring), plus one own-cell read
    assert _Counted.reads <= 126 * n
    brute = [next((j for j in range(i) if math.dist(pts[i], pts[j]) < r), None) for i in range(200)]
    assert [g is not None for g in got[:200]] == [b is not None for b in brute]
    for i, g in enumerate(got[:200]):
        if g is not None:
            assert g[1] == pytest.approx(math.dist(pts[i], pts[g[0]])) and g[1] < r
    assert earlier_within([(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)], SAME_POINT_M)[1] == (0, 0.0)


# ------------------------------------------------------------- item 9
@pytest.mark.parametrize(
    ("text", "where"),
    [
        (doc(tail="gains: {k_s: 1.0e308}\n"), (9, "gains.k_s")),
        (doc(start="[1.0e300, 0, 1]"), (7, "vehicles[0].start[0]")),
        (doc(tail="gains: {M: 1.0e-300}\n"), (9, "gains.M")),
        (doc().replace("start: [0, 0, 0]", "start: [0, 2.0e5, 0]"), (4, "leader.start[1]")),
        (doc(tail="leader_typo: 1\n").replace("leader_typo: 1\n", ""), None),
    ],
)
def test_absurd_magnitudes_are_refused(text: str, where: tuple[int, str] | None) -> None:
    if where is None:
        assert parse_mission(text, "m.yaml")
        return
    line, path, _ = one_problem(text)
    assert (line, path) == where


def test_the_bounds_agree_with_what_the_station_believes() -> None:
    from gcs_swarm.mission import bounds

    assert bounds.POSITION_LIMIT_M == inbound.POSITION_LIMIT_M
    assert bounds.SPEED_LIMIT_MPS == inbound.SPEED_LIMIT_MPS
    assert bounds.ACCEL_LIMIT_MPS2 == ACCEL_CEILING_MPS2


@pytest.mark.parametrize("printed", [False, True])
def test_the_law_stays_finite_at_the_corners_of_the_bounds(printed: bool) -> None:
    from gcs_swarm.mission import bounds

    big, small, far = bounds.GAIN_MAX, bounds.GAIN_MIN, bounds.POSITION_LIMIT_M
    g = Gains(M=small, D=big, k=big, k_s=big, k_r=big, alpha=big, q_default=big)
    rd = Readings(eq10_printed=printed, eq12_printed=printed)
    pos = np.array([[far, far, far], [far - 2e-6, far, far], [-far, -far, -far]])
    vel = np.full((3, 3), bounds.SPEED_LIMIT_MPS)
    leader = np.array([-far, far, -far])
    f = formation_force(pos, np.full(3, big), leader, g, rd)
    a = eq1_acceleration(f, vel, g)
    assert np.all(np.isfinite(f)) and np.all(np.isfinite(a))


# ------------------------------------------------------------- item 10
@pytest.mark.parametrize(
    ("text", "where", "why"),
    [
        (
            doc().replace("{dynamics: ideal}", "{dynamics: ideal, host: 999.1.1.1}"),
            (2, "emulator.host"),
            '"999.1.1.1" is not an IPv4 address',
        ),
        (
            doc().replace("{sysid: 1, ", '{sysid: 1, link: "udpin:1.2.3:14550", '),
            (7, "vehicles[0].link"),
            '"1.2.3" is not an IPv4 address',
        ),
        (
            doc().replace("{sysid: 1, ", '{sysid: 1, link: "udpin:127.0.0.1:14550", '),
            (1, "mission.origin"),
            "sim vehicles with a real first vehicle need a geodetic origin",
        ),
        (
            doc(head=", origin: {lat: 0, lon: 0, alt: 0}")
            .replace("{dynamics: ideal}", "{dynamics: ideal, base_port: 5760}")
            .replace("{sysid: 1, ", '{sysid: 1, link: "udpin:0.0.0.0:5760", '),
            (7, "vehicles[0].link"),
            "port 5760 is also a sim vehicle's (emulator.base_port = 5760, line 2)",
        ),
    ],
    ids=["emulator-host", "link-host", "real-first-no-origin", "base-port-vs-udpin"],
)
def test_check_catches_what_run_would_fail_on(text: str, where: tuple[int, str], why: str) -> None:
    line, path, message = one_problem(text)
    assert (line, path) == where
    assert why in message


@pytest.mark.parametrize("host", ["localhost", "0.0.0.0", "::1", "my-host.local", "10.1.2.3"])
def test_good_hosts_pass(host: str) -> None:
    m = parse_mission(doc().replace("{dynamics: ideal}", f'{{dynamics: ideal, host: "{host}"}}'))
    assert m.emulator.host == host


# ------------------------------------------------------------- item 13
@pytest.mark.parametrize(
    ("value", "why"),
    [
        ("1:30", "YAML 1.2 reads 1:30 as a string, not a base-60 number"),
        ("010", "a leading zero is ambiguous: YAML 1.1 reads 010 as octal; write 10 or 0o10"),
        ("1_000", 'got "1_000"'),
        ("0b101", 'got "0b101"'),
    ],
)
def test_yaml_1_2_numbers(value: str, why: str) -> None:
    line, path, message = one_problem(doc(duration=value))
    assert (line, path) == (1, "mission.duration") and why in message


def test_yaml_1_2_forms_that_are_numbers() -> None:
    m = parse_mission(doc(duration="0o17", sysid="0x0A"), "m.yaml")
    assert m.settings.duration == 15.0 and m.vehicles[0].sysid == 10
    assert parse_mission(doc(duration="1e1"), "m.yaml").settings.duration == 10.0
    m = parse_mission(doc(head=", name: yes"), "m.yaml")  # a string in YAML 1.2
    assert m.settings.name == "yes"


def test_signing_key_env_must_be_a_variable_name() -> None:
    line, path, message = one_problem(doc(head=", signing: {key_env: 'a b'}"))
    assert (line, path) == (1, "mission.signing.key_env")
    assert message.startswith("expected an environment variable name")
    m = parse_mission(doc(head=", signing: {key_env: GCS_KEY_1}"), "m.yaml")
    assert m.settings.signing is not None and m.settings.signing.key_env == "GCS_KEY_1"


def test_a_shipped_mission_still_loads() -> None:
    root = Path(__file__).resolve().parents[2] / "config" / "missions"
    for path in sorted(root.glob("*.yaml")):
        assert load_mission(path).source == str(path)
