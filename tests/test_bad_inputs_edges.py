"""Extreme inputs: seeds beyond the largest one on every command taking a seed, rates and
tolerances at the edge of their ranges, a unit written into a number, a mistyped command.

Each case runs ``capsule_mpc.cli.main`` in ``tmp_path`` and asserts exit status 2, the message
(one line, or for a scenario the file's header line and one line naming the field), that it
blames the field or option it names, and every file under ``tmp_path`` unchanged by hash.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import pytest

from capsule_mpc.cli import main

#: 2**64 and 2**63: past the largest seed, 2**63 - 1 (a signed 64-bit integer on the rig's wire).
BEYOND = ("18446744073709551616", "9223372036854775808")
LARGEST = str(2**63 - 1)
SEED_MESSAGE = r"argument --seed: must be an integer in \[0, 2\*\*63 - 1\], got {}$"
SHORT_PATH = "x_m,y_m\n0.0,0.0\n0.02,0.0\n"

#: Every command taking ``--seed``, with arguments that are valid but for it.
SEEDED = {
    "simulate": ["simulate", "--controller", "follow", "--out", "O"],
    "compare": ["compare", "--controllers", "follow", "--out", "O"],
    "sweep": ["sweep", "--controllers", "follow", "--runs", "1", "--out", "O"],
    "bench": ["bench", "--out", "O/b.json"],
    "demo": ["demo", "--out", "O"],
    "demonstrate": ["demonstrate", "--speeds", "0.02", "--out", "O"],
    "rig serve": ["rig", "serve", "--out", "O"],
}


def snapshot(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _run(argv: list[str], capsys) -> tuple[int, list[str]]:
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse's refusal
        status = exc.code if isinstance(exc.code, int) else 1
    err = capsys.readouterr().err
    return status, [line for line in err.splitlines() if line.strip()]


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    (tmp_path / "W.csv").write_text(SHORT_PATH)
    monkeypatch.chdir(tmp_path)
    return tmp_path


SEED_CASES = [
    pytest.param([*argv, "--seed", value], SEED_MESSAGE.format(value), id=f"{name}-{value[:4]}")
    for name, argv in SEEDED.items()
    for value in BEYOND
]
SEED_CASES += [
    pytest.param(
        ["compare", "--controllers", "follow", "--runs", "2", "--seed", LARGEST, "--out", "O"],
        rf"--seed: the last run's seed {LARGEST} \+ 2 - 1 is past the largest seed 2\*\*63 - 1; give a seed "
        rf"<= {2**63 - 2}$",
        id="compare-runs-past-the-largest",
    ),
    pytest.param(
        ["sweep", "--controllers", "follow", "--runs", "3", "--seed", LARGEST, "--out", "O"],
        r"--seed: the last run's seed .* is past the largest seed",
        id="sweep-runs-past-the-largest",
    ),
]


@pytest.mark.parametrize(("argv", "message"), SEED_CASES)
def test_a_seed_past_the_largest_is_refused_in_one_line_by_every_command(argv, message, workdir, capsys):
    before = snapshot(workdir)
    status, err = _run(argv, capsys)
    assert status == 2, err
    assert len(err) == 1, err
    assert re.search(message, err[0]), err
    assert snapshot(workdir) == before


#: A scenario value at the edge of its range: (the YAML after ``base: paper``, the field line).
EDGE_CASES = [
    pytest.param(
        "camera:\n  rate_hz: 5.0e-324\n", r"camera\.rate_hz: must be >= 1, got 5e-324", id="rate-subnormal"
    ),
    pytest.param(
        "camera:\n  rate_hz: 1.0e-200\n", r"camera\.rate_hz: must be >= 1, got 1e-200", id="rate-tiny"
    ),
    pytest.param(
        "camera:\n  rate_hz: 0.99\n", r"camera\.rate_hz: must be >= 1, got 0\.99", id="rate-below-1-hz"
    ),
    pytest.param(
        "arm:\n  plan_waypoint_rate_hz: 1.0e-300\n",
        r"arm\.plan_waypoint_rate_hz: must be >= 1, got 1e-300",
        id="plan-rate-tiny",
    ),
    pytest.param(
        "mpc:\n  position_tol_m: 5.0e-324\n",
        r"mpc\.position_tol_m: must be >= 1e-0?9, got 5e-324",
        id="tolerance-subnormal",
    ),
    pytest.param(
        "mpc:\n  input_jerk_tol_mps2: 1.0e-300\n",
        r"mpc\.input_jerk_tol_mps2: must be >= 1e-0?9, got 1e-300",
        id="jerk-tolerance-tiny",
    ),
    pytest.param(
        "sim:\n  seed: 9223372036854775808\n",
        r"sim\.seed: must be <= 9223372036854775807, got 9223372036854775808",
        id="config-seed-past-the-largest",
    ),
    pytest.param(
        'path:\n  speed_mps: "20 mm/s"\n',
        r"path\.speed_mps: must be a number .*got '20 mm/s' \(write the number alone: .*m/s, \(0, ",
        id="unit-in-a-speed",
    ),
    pytest.param(
        "capsule:\n  mass_kg: 20 g\n",
        r"capsule\.mass_kg: must be a number .*got '20 g' \(write the number alone: Capsule mass m, kg, > 0",
        id="unit-in-a-mass",
    ),
]


@pytest.mark.parametrize("command", ["info", "simulate"])
@pytest.mark.parametrize(("yaml", "field"), EDGE_CASES)
def test_a_value_at_the_edge_of_its_range_is_refused_blaming_its_field(yaml, field, command, workdir, capsys):
    (workdir / "c.yaml").write_text("base: paper\n" + yaml)
    argv = ["info", "--config", "c.yaml"]
    if command == "simulate":
        argv = [
            "simulate",
            "--config",
            "c.yaml",
            "--waypoints",
            "W.csv",
            "--controller",
            "follow",
            "--out",
            "O",
        ]
    before = snapshot(workdir)
    status, err = _run(argv, capsys)
    assert status == 2, err
    assert err[0] == "capsule-mpc: invalid config c.yaml:" and len(err) == 2, err
    assert re.search(field, err[1]), err
    assert snapshot(workdir) == before


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulat"], r"^capsule-mpc: error: argument COMMAND: invalid choice: 'simulat' \(choose from"),
        (
            ["log", "export"],
            r"^capsule-mpc log export: error: the following arguments are required: RUN_DIR$",
        ),
        (["simulate", "--out", "O"], r"^capsule-mpc simulate: error: the following arguments are required"),
        (["rig", "serve", "--bogus"], r"^capsule-mpc: error: unrecognized arguments: --bogus$"),
    ],
    ids=["unknown-command", "missing-run-dir", "missing-controller", "unknown-option"],
)
def test_a_mistyped_command_line_is_refused_in_one_line(argv, message, workdir, capsys):
    before = snapshot(workdir)
    status, err = _run(argv, capsys)
    assert status == 2 and len(err) == 1, err
    assert re.search(message, err[0]), err
    assert snapshot(workdir) == before
