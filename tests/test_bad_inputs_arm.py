"""Bad inputs of ``capsule-mpc arm-export``: each is refused with exit status 2, a message naming the
file and the data row and field (or the time) and the allowed range, and nothing in ``--out``.

Every plan is derived from one short plan the arm follows (``good_rows``): a smooth 2 s motion at
the camera rate, inside the default workspace and well within the limits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from capsule_mpc.cli import main
from capsule_mpc.config import packaged_config_path

HEADER = "t_s,epm_x_m,epm_y_m,epm_z_m"
#: The scenario the plans are exported with unless a case gives its own.
PAPER = str(packaged_config_path("paper"))
#: The good plan: 2 s at 30 Hz, x from -0.03 to +0.03 m along a cosine (peak 47 mm/s, 74 mm/s^2).
T_END_S, RATE_HZ = 2.0, 30.0

Rows = list[list[float]]


def good_rows() -> Rows:
    t = np.arange(0.0, T_END_S + 1e-9, 1.0 / RATE_HZ)
    x = -0.03 + 0.06 * (1 - np.cos(np.pi * t / T_END_S)) / 2
    return np.column_stack([t, x, 0.5 * (x + 0.03), np.full(t.shape, 0.095)]).tolist()


def csv_text(rows: Rows) -> str:
    return HEADER + "\n" + "".join(",".join(repr(v) for v in row) + "\n" for row in rows)


def shifted(rows: Rows, col: int, by: float, start: int = 0, stop: int | None = None) -> Rows:
    """Rows with ``by`` added to column ``col`` of data rows start..stop-1 (0-based)."""
    out = [list(r) for r in rows]
    for r in out[start:stop]:
        r[col] += by
    return out


def replaced(rows: Rows, index: int, col: int, value: float) -> Rows:
    out = [list(r) for r in rows]
    out[index][col] = value
    return out


def replaced_all(rows: Rows, col: int, value: float) -> Rows:
    return [[*r[:col], value, *r[col + 1 :]] for r in rows]


def step_mm(col: int, index: int, added_mm: float) -> str:
    """The text of the step into data row index + 1 (0-based ``index``) of GOOD plus ``added_mm``."""
    return f"{(GOOD[index][col] - GOOD[index - 1][col]) * 1e3 + added_mm:+.2f}"


def first_row_above(rows: Rows, col: int, limit: float) -> int:
    """1-based data row of the first value of ``col`` above ``limit``."""
    return next(i + 1 for i, r in enumerate(rows) if r[col] > limit + 1e-6)


def from_rest_at_speed_limit() -> Rows:
    """x at the 0.08 m/s speed limit from the first row: every row within the limits, but an arm
    starting at rest can never catch up (it lags by >= v^2 / 2a = 6.4 mm > the 5 mm tolerance)."""
    t = np.arange(0.0, 2.0 + 1e-9, 1.0 / RATE_HZ)
    x = -0.08 + 0.08 * t * (1 - 1e-9)
    return np.column_stack([t, x, np.zeros_like(t), np.full(t.shape, 0.095)]).tolist()


@dataclass(frozen=True)
class Case:
    """One bad input: the plan file's text (or bytes), extra CLI arguments, and what the message says."""

    id: str
    plan: Callable[[], str | bytes | None]
    expect: Callable[[], str]
    config: str | None = None


GOOD = good_rows()
N = len(GOOD)

CASES = [
    Case(
        "z-zero",  # awk '$4=0'
        lambda: csv_text(replaced_all(GOOD, 3, 0.0)),
        lambda: (
            "data row 1 (t_s = 0), epm_z_m: must be in the EPM workspace [0.085, 0.105] m "
            "(limits.workspace_min_m[2] .. limits.workspace_max_m[2]), got 0"
        ),
    ),
    Case(
        "x-plus-0.3",
        lambda: csv_text(shifted(GOOD, 1, 0.3)),
        lambda: "data row 1 (t_s = 0), epm_x_m: must be in the EPM workspace [-0.18, 0.18] m",
    ),
    Case(
        "y-drifts-out-mid-plan",
        lambda: csv_text(shifted(GOOD, 2, 0.115)),
        lambda: f"data row {first_row_above(shifted(GOOD, 2, 0.115), 2, 0.13)} ",
    ),
    Case(
        "5cm-step",
        lambda: csv_text(shifted(GOOD, 1, 0.05, start=30)),
        lambda: (
            f"data row 31 (t_s = 1), epm_x_m: moves {step_mm(1, 30, 50.0)} mm from data row 30 in 33.3 ms"
        ),
    ),
    Case(
        "1m-jump-one-row",  # blamed on the jump, not on a singularity
        lambda: csv_text(shifted(GOOD, 2, 1.0, start=40, stop=41)),
        lambda: f"data row 41 (t_s = 1.33333), epm_y_m: moves {step_mm(2, 40, 1000.0)} mm from data row 40",
    ),
    Case(
        "duplicate-time",
        lambda: csv_text([*GOOD[:10], GOOD[9], *GOOD[10:]]),
        lambda: (
            "data row 11 (t_s = 0.3), t_s: must be > 0.3 s of data row 10 (times strictly increasing), "
            "got 0.3 (a duplicate time)"
        ),
    ),
    Case(
        "earlier-time",
        lambda: csv_text(replaced(GOOD, 20, 0, 0.1)),
        lambda: "data row 21 (t_s = 0.1), t_s: must be > 0.633333 s of data row 20",
    ),
    Case(
        "single-row",  # not "at nan Hz"
        lambda: csv_text(GOOD[:1]),
        lambda: "the plan needs at least 2 data rows (a start and an end), got 1 data row",
    ),
    Case(
        "header-only",
        lambda: csv_text([]),
        lambda: "the plan needs at least 2 data rows (a start and an end), got no data rows",
    ),
    Case(
        "nan-value",
        lambda: csv_text(replaced(GOOD, 7, 2, math.nan)),
        lambda: "data row 8 (t_s = 0.233333), epm_y_m: must be a finite number, got nan",
    ),
    Case(
        "infinite-time",
        lambda: csv_text(replaced(GOOD, 12, 0, math.inf)),
        lambda: "data row 13, t_s: must be a finite number, got inf",
    ),
    Case(
        "not-a-number",
        lambda: csv_text(GOOD[:5]).replace(repr(GOOD[3][1]), "abc"),
        lambda: "data row 4 (line 5), epm_x_m: not a number, got 'abc'",
    ),
    Case(
        "missing-column",
        lambda: "t_s,epm_x_m\n0,0\n1,0.001\n",
        lambda: "needs a time column (t_s) and EPM position columns (epm_x_m, epm_y_m[, epm_z_m])",
    ),
    Case(
        "binary-file",
        lambda: b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe",
        lambda: "not a UTF-8 text CSV",
    ),
    Case(
        "missing-file",
        lambda: None,
        lambda: "No such file or directory",
    ),
    Case(
        "too-fast-from-rest",  # 50 mm in 1 s from rest with 0.01 m/s^2: at most 10 mm
        lambda: csv_text([[0.0, 0.0, 0.0, 0.095], [1.0, 0.05, 0.0, 0.095], [2.0, 0.06, 0.0, 0.095]]),
        lambda: (
            "data row 2 (t_s = 1), epm_x_m: moves +50.00 mm from data row 1 in 1000.0 ms; starting at "
            "rest there, the arm can move at most 10.00 mm (acceleration limit 0.01 m/s^2"
        ),
        config="limits: {accel_mps2: 0.01}",
    ),
    Case(
        "reversal-beyond-acceleration",  # +20 mm/s to -20 mm/s at one row, 1 s apart
        lambda: csv_text([[float(i), x, 0.0, 0.095] for i, x in enumerate([0.0, 0.004, 0.024, 0.004])]),
        lambda: (
            "data row 4 (t_s = 3), epm_x_m: reaching it needs the plan's speed to change from "
            "+0.0200 m/s (data rows 2 -> 3) to -0.0200 m/s (data rows 3 -> 4); the arm can change it "
            "by at most 0.0300 m/s"
        ),
        config="limits: {accel_mps2: 0.01}",
    ),
    Case(
        "rows-1e4-s-apart",  # Ruckig cannot plan a step that long: refused by the row, before it is asked
        lambda: csv_text([[0.0, 0.0, 0.0, 0.095], [1e4, 0.01, 0.0, 0.095], [2e4, 0.02, 0.0, 0.095]]),
        lambda: (
            "data row 2 (t_s = 10000), t_s: is 1e+04 s after data row 1 (t_s = 0); a plan spans at most "
            "3600 s (capsule_mpc.budget.MAX_SIM_TIME_S)"
        ),
    ),
    Case(
        "span-over-an-hour-at-the-camera-rate",
        lambda: csv_text([[k / 30.0, 0.0, 0.0, 0.095] for k in range(108_000 + 2)]),
        lambda: "data row 108002 (t_s = 3600.03), t_s: is 3.6e+03 s after data row 1 (t_s = 0)",
    ),
    Case(
        "setpoints-beyond-the-memory",  # 3000 s at 10 kHz: 3e7 setpoints, 57 GiB
        lambda: csv_text([[0.0, 0.0, 0.0, 0.095], [3000.0, 0.01, 0.0, 0.095]]),
        lambda: (
            "t_s: the plan spans 3e+03 s: 3e+07 arm setpoints at 10000 Hz (arm.arm_rate_hz) needing 57 GiB; "
            "at most 50% of the 8 GiB of memory available: at most 2.1e+02 s at this rate"
        ),
        config="arm: {arm_rate_hz: 10000}",
    ),
    Case(
        "deviation-beyond-tolerance",  # every row within the limits, the whole beyond the arm
        lambda: csv_text(from_rest_at_speed_limit()),
        lambda: "the arm trajectory fails its check at t = ",
    ),
    Case(
        "unreachable-arm-base",  # the arm's base 1.5 m away: out of the UR5's reach
        lambda: csv_text(GOOD),
        lambda: "is not reachable by the arm",
        config="arm: {base_xyz_m: [0.0, -1.5, 0.0]}",
    ),
]


def write_plan(path: Path, content: str | bytes | None) -> None:
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)


def files_in(out: Path) -> list[Path]:
    return sorted(p for p in out.rglob("*")) if out.exists() else []


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_plan_is_refused_with_the_row_and_nothing_written(case: Case, tmp_path, capsys, monkeypatch):
    from capsule_mpc import budget

    monkeypatch.setattr(budget, "available_memory_bytes", lambda: 8 * 2**30)  # figures independent of it
    plan = tmp_path / "plan.csv"
    write_plan(plan, case.plan())
    out = tmp_path / "out"
    args = ["arm-export", "--plan", str(plan), "--out", str(out), "--config", PAPER]
    if case.config is not None:
        cfg = tmp_path / "scenario.yaml"
        cfg.write_text(f"base: paper\n{case.config}\n")
        args[-1] = str(cfg)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("capsule-mpc arm-export: ") and err.count("\n") == 1, err
    assert "plan.csv" in err  # the file is named
    assert case.expect() in err, err
    assert err.rstrip().endswith("(nothing written)")
    assert files_in(out) == []


def test_the_good_plan_is_exported(tmp_path, capsys):
    """The plan every case derives from passes (so the cases fail for their own reason)."""
    plan = tmp_path / "plan.csv"
    plan.write_text(csv_text(GOOD))
    args = ["arm-export", "--plan", str(plan), "--out", str(tmp_path / "out"), "--config", PAPER, "--no-plot"]
    assert main(args) == 0
    assert "EPM deviation from the plan max" in capsys.readouterr().out
    assert (tmp_path / "out" / "joint_trajectory.yaml").exists()


def test_out_is_an_existing_file(tmp_path, capsys):
    plan = tmp_path / "plan.csv"
    plan.write_text(csv_text(GOOD))
    out = tmp_path / "out"
    out.write_text("keep me\n")
    assert main(["arm-export", "--plan", str(plan), "--out", str(out), "--config", PAPER, "--no-plot"]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and err.rstrip().endswith("(nothing written)")
    assert out.read_text() == "keep me\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "plan.csv"]


def test_too_many_rows_are_refused_while_read(tmp_path, capsys, monkeypatch):
    """Rows beyond the maximum stop the reading at the first one (a smaller maximum keeps it quick)."""
    import capsule_mpc.arm.export as export

    monkeypatch.setattr(export, "MAX_PLAN_ROWS", 50)
    plan = tmp_path / "plan.csv"
    plan.write_text(csv_text(GOOD))
    out = tmp_path / "out"
    assert main(["arm-export", "--plan", str(plan), "--out", str(out), "--config", PAPER]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"capsule-mpc arm-export: {plan}: data row 51 (line 52): more than 50 data rows; a plan has at most "
        "50 (capsule_mpc.budget.MAX_PLAN_ROWS) (nothing written)\n"
    )
    assert files_in(out) == []


def test_without_a_config_the_one_beside_the_plan_is_used_and_named(tmp_path, capsys):
    plan = tmp_path / "run" / "epm_plan.csv"
    plan.parent.mkdir()
    plan.write_text(csv_text(GOOD))
    out = tmp_path / "out"
    assert main(["arm-export", "--plan", str(plan), "--out", str(out), "--no-plot"]) == 2
    assert capsys.readouterr().err == (
        f"capsule-mpc arm-export: --config: required: no config.yaml beside {plan}; give the scenario the "
        "plan was made for (its limits, workspace and arm), e.g. --config configs/paper.yaml "
        "(nothing written)\n"
    )
    assert files_in(out) == []
    # The rig the plan was made for sits beside it (as plan and simulate leave it): its limits apply.
    (plan.parent / "config.yaml").write_text("base: paper\nlimits: {speed_mps: 0.01}\n")
    assert main(["arm-export", "--plan", str(plan), "--out", str(out), "--no-plot"]) == 2
    captured = capsys.readouterr()
    assert captured.out == f"config: {plan.parent / 'config.yaml'} (the config beside the plan)\n"
    assert "epm_x_m: moves" in captured.err and "(per-axis speed limit 0.01 m/s)" in captured.err
    assert files_in(out) == []
