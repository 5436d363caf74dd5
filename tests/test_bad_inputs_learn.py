"""Bad input to ``learn-friction`` and ``demonstrate``: run logs, samples CSVs and output paths.

Every case runs the command through ``capsule_mpc.cli.main`` and asserts exit code 2, that
the one-line message on stderr names the file (and the row or column where there is one),
and that nothing was written: no model, no samples CSV, no figures, no temporary files.
"""

from __future__ import annotations

import errno
import hashlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from capsule_mpc.cli import main
from capsule_mpc.learning import steady_lead

FRAME_S = 1.0 / 30.0
LOG_HEADER = ["t_s", "epm_x_m", "epm_y_m", "epm_z_m", "meas_x_m", "meas_y_m", "meas_capture_t_s"]
SAMPLES_HEADER = "v_mps,a_mps2,traction_n,normal_n"
#: Fit options that keep a successful fit fast (no force map, one coefficient).
FAST = ["--degree", "0", "--force-model", "dipole"]


def _rows(scenario, n: int = 360) -> list[list[str]]:
    """A valid camera log: the EPM speeds up from 15 to ~27 mm/s along x, the capsule a steady lead behind."""
    lead = steady_lead(scenario, 0.15, (1.0, 0.0), force_model="dipole")
    t = np.arange(n) * FRAME_S
    x = -0.08 + 0.015 * t + 0.0005 * t**2
    noise = np.random.default_rng(0).normal(0, 3e-4, (n, 2))
    capture = t - FRAME_S
    x_capture = -0.08 + 0.015 * capture + 0.0005 * capture**2
    cols = [t, x, np.zeros(n), np.full(n, scenario.plate.epm_height_m)]
    cols += [x_capture - lead[0] + noise[:, 0], -lead[1] + noise[:, 1], capture]
    return [[f"{v:.10g}" for v in row] for row in np.column_stack(cols)]


def _write_log(path: Path, rows: list[list[str]], header: list[str] = LOG_HEADER) -> Path:
    path.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")
    return path


def _col(name: str) -> int:
    return LOG_HEADER.index(name)


@pytest.fixture()
def base(tmp_path, scenario):
    """(inputs folder, valid log rows); outputs go to tmp_path/out (must stay absent)."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    return inputs, _rows(scenario)


def _learn(*args: str) -> list[str]:
    return ["learn-friction", *args]


# Each case: (inputs folder, valid rows, out folder) -> (argv, fragments the message must hold).
Case = Callable[[Path, list[list[str]], Path], tuple[list[str], list[str]]]


def log_binary(d, rows, out):
    p = d / "log.csv"
    p.write_bytes(bytes(range(128, 256)) * 8)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "not a CSV text file"]


def log_binary_after_header(d, rows, out):
    p = _write_log(d / "log.csv", rows[:40])
    p.write_bytes(p.read_bytes() + b"\xff\xfe\xfa" * 50)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "not a CSV text file", "line"]


def log_nul_bytes(d, rows, out):
    p = _write_log(d / "log.csv", rows[:40])
    p.write_bytes(p.read_bytes() + b"1,2\x00,3\n")
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "line 42, column epm_x_m"]


def log_missing_column(d, rows, out):
    keep = [i for i, c in enumerate(LOG_HEADER) if c != "meas_y_m"]
    p = _write_log(d / "log.csv", [[r[i] for i in keep] for r in rows], [LOG_HEADER[i] for i in keep])
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "missing column(s) meas_y_m"]


def log_nan_rows(d, rows, out):
    rows[4][_col("epm_z_m")] = "nan"
    rows[8][_col("epm_z_m")] = ""
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "epm_z_m", "line(s) 6, 10"]


def log_inf_value(d, rows, out):
    rows[20][_col("epm_x_m")] = "inf"
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "epm_x_m", "line(s) 22"]


def log_too_few_rows(d, rows, out):
    p = _write_log(d / "log.csv", rows[:3])
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "too few rows: 3"]


def log_not_a_number(d, rows, out):
    rows[5][_col("epm_y_m")] = "abc"
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "line 7, column epm_y_m", "'abc'"]


def log_time_not_increasing(d, rows, out):
    rows[10][0] = rows[9][0]
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "t_s must be strictly", "line 12"]


def log_capture_time_not_increasing(d, rows, out):
    rows[30][_col("meas_capture_t_s")] = rows[29][_col("meas_capture_t_s")]
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "meas_capture_t_s", "line 32"]


def log_epm_height_not_positive(d, rows, out):
    rows[15][_col("epm_z_m")] = "0"
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "epm_z_m must be > 0", "line 17"]


def log_no_camera_frame(d, rows, out):
    for r in rows:
        r[_col("meas_x_m")] = r[_col("meas_y_m")] = "nan"
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "0 camera frame(s)", "meas_x_m"]


def log_empty_file(d, rows, out):
    p = d / "log.csv"
    p.write_text("")
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "empty file"]


def log_missing_path(d, rows, out):
    p = d / "nowhere.csv"
    return _learn("--log", str(p), "--out", str(out / "m.yaml")), [str(p), "no such file or folder"]


def log_folder_without_logs(d, rows, out):
    (d / "notes.csv").write_text("a,b\n1,2\n")
    return _learn("--log", str(d), "--out", str(out / "m.yaml")), [str(d), "holds no run log"]


def log_folder_with_binary_csv(d, rows, out):
    _write_log(d / "a_log.csv", rows)
    bad = d / "b_broken.csv"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(128, 256)))
    return _learn("--log", str(d), "--out", str(out / "m.yaml")), [str(bad), "not a CSV text file"]


def log_shorter_than_the_filter_window(d, rows, out):
    p = _write_log(d / "log.csv", rows[:12])
    return _learn("--log", str(p), "--out", str(out / "m.yaml"), *FAST), [str(p), "no stretch of at least"]


def log_without_usable_samples(d, rows, out):
    for r in rows:  # the EPM stands still: every sample is below the speed floor
        r[_col("epm_x_m")] = rows[0][_col("epm_x_m")]
    p = _write_log(d / "log.csv", rows)
    argv = _learn("--log", str(p), "--out", str(out / "m.yaml"), *FAST)
    return argv, [str(p), "cannot fit c(v)", "below_speed_floor"]


def log_given_three_times(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    argv = _learn("--log", str(p), str(p), str(p), "--out", str(out / "m.yaml"), *FAST)
    return argv, [f"{p}: the same run log is given more than once; each log counts once"]


def log_in_its_folder_and_by_a_link(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    link = d.parent / "elsewhere.csv"
    link.symlink_to(p)
    argv = _learn("--log", str(d), str(link), "--out", str(out / "m.yaml"), *FAST)
    return argv, [f"{link}: the same run log is given more than once (also given as {p})"]


def samples_without_friction(d, rows, out):
    """Traction that only pulls the tether: a model of zero friction, which mu0 = 0.22 contradicts."""
    p = d / "s.csv"
    speeds = np.linspace(0.005, 0.04, 200)
    p.write_text(f"{SAMPLES_HEADER}\n" + "".join(f"{v:.6f},0,0.03,0.5\n" for v in speeds))
    return _learn("--samples", str(p), "--out", str(out / "m.yaml")), [
        f"{p}: the learned law predicts no friction: mu(v) is at most ",
        "over its whole range 0.005-0.04 m/s, below 2% of friction.mu0 = 0.22",
    ]


def samples_binary(d, rows, out):
    p = d / "s.csv"
    p.write_bytes(b"\x00\xff" * 200)
    return _learn("--samples", str(p), "--out", str(out / "m.yaml")), [str(p), "not a CSV text file"]


def samples_missing_column(d, rows, out):
    p = d / "s.csv"
    p.write_text("v_mps,a_mps2,traction_n\n0.01,0,0.1\n")
    return _learn("--samples", str(p), "--out", str(out / "m.yaml")), [str(p), "missing column(s) normal_n"]


def samples_nan_row(d, rows, out):
    p = d / "s.csv"
    p.write_text(f"{SAMPLES_HEADER}\n0.01,0,0.1,0.7\n0.02,0,0.1,0.7\nnan,0,0.1,0.7\n")
    return _learn("--samples", str(p), "--out", str(out / "m.yaml")), [str(p), "v_mps", "line(s) 4"]


def out_is_a_folder(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    out.mkdir()
    return _learn("--log", str(p), "--out", str(out), *FAST), [f"--out {out}: is a folder"]


def out_under_a_file(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(p / "m.yaml"), *FAST), [str(p / "m.yaml"), "is a file"]


def out_unwritable(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    target = Path("/proc/capsule_mpc_test/m.yaml")  # not writable, even by root
    return _learn("--log", str(p), "--out", str(target), *FAST), ["/proc"]


def out_is_the_input_log(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(p), *FAST), [f"--out: {p} is --log {p}, an input"]


def out_is_the_input_samples(d, rows, out):
    p = d / "s.csv"
    p.write_text(f"{SAMPLES_HEADER}\n" + "".join(f"{0.01 + 0.001 * k},0,0.15,0.7\n" for k in range(20)))
    return _learn("--samples", str(p), "--out", str(p), "--degree", "0"), [f"--out: {p} is --samples {p}"]


def _run_folder(d: Path, rows: list[list[str]], config: str) -> Path:
    """A run folder: the log and the scenario it was recorded with (``base: paper`` + ``config``)."""
    run = d / "run"
    run.mkdir()
    (run / "config.yaml").write_text("base: paper\n" + config)
    _write_log(run / "log.csv", rows)
    return run


def out_is_the_config(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    cfg = d / "rig.yaml"
    cfg.write_text("base: paper\n")
    argv = _learn("--config", str(cfg), "--log", str(p), "--out", str(cfg), *FAST)
    return argv, [f"--out: {cfg} is --config {cfg}, an input of this command, which it would overwrite"]


def out_is_the_base_of_the_config(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    (d / "base.yaml").write_text("base: paper\n")
    cfg = d / "rig.yaml"
    cfg.write_text("base: base.yaml\n")
    argv = _learn("--config", str(cfg), "--log", str(p), "--out", str(d / "base.yaml"), *FAST)
    return argv, [f"--out: {d / 'base.yaml'} is {d / 'base.yaml'}, the base: of --config {cfg}"]


def out_is_the_config_recorded_with_the_log(d, rows, out):
    run = _run_folder(d, rows, "")
    argv = _learn("--log", str(run), "--out", str(run / "config.yaml"), *FAST)
    return argv, [f"--out: {run / 'config.yaml'} is --log {run / 'config.yaml'}, an input"]


def figures_hold_the_log(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    argv = _learn("--log", str(p), "--out", str(out / "m.yaml"), "--figures", str(d), *FAST)
    return argv, [f"--figures: {d} holds --log {p}, an input of this command"]


def log_recorded_on_another_rig(d, rows, out):
    run = _run_folder(d, rows, "capsule:\n  mass_kg: 0.05\nplate:\n  epm_height_m: 0.1\n")
    argv = _learn("--log", str(run), "--out", str(out / "m.yaml"), *FAST)
    return argv, [
        f"{run / 'log.csv'}: recorded on another rig than --config",
        "capsule.mass_kg (log: 0.05, --config: 0.0209)",
        "plate.epm_height_m (log: 0.1, --config: 0.095)",
    ]


def log_recorded_with_other_friction(d, rows, out):
    run = _run_folder(d, rows, "friction:\n  mu0: 0.4\n")
    argv = _learn("--log", str(run), "--out", str(out / "m.yaml"), *FAST)
    return argv, ["recorded on another rig than --config", "friction.mu0 (log: 0.4, --config: 0.22)"]


def samples_with_a_huge_traction(d, rows, out):
    p = d / "s.csv"
    lines = [f"{0.01 + 0.001 * k},0,0.15,0.7" for k in range(20)]
    lines[6] = "0.016,0,1e300,0.7"
    p.write_text(SAMPLES_HEADER + "\n" + "\n".join(lines) + "\n")
    argv = _learn("--samples", str(p), "--out", str(out / "m.yaml"), "--degree", "0")
    return argv, [f"{p}: line 8, column traction_n: 1e+300 is outside [-1000, 1000] N"]


def samples_with_a_huge_speed(d, rows, out):
    p = d / "s.csv"
    lines = [f"{0.01 + 0.001 * k},0,0.15,0.7" for k in range(20)]
    lines[0] = "-1e300,0,0.15,0.7"
    lines[3] = "1e20,0,0.15,0.7"
    p.write_text(SAMPLES_HEADER + "\n" + "\n".join(lines) + "\n")
    argv = _learn("--samples", str(p), "--out", str(out / "m.yaml"), "--degree", "0")
    return argv, [f"{p}: line 2, column v_mps: -1e+300 is outside [-10, 10] m/s", "and 1 more row"]


def samples_out_is_a_folder(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    out.mkdir()
    argv = _learn("--log", str(p), "--out", str(out / "m.yaml"), "--samples-out", str(out), *FAST)
    return argv, [f"--samples-out {out}: is a folder"]


def samples_out_with_samples(d, rows, out):
    p = d / "s.csv"
    p.write_text(f"{SAMPLES_HEADER}\n0.01,0,0.1,0.7\n")
    argv = _learn("--samples", str(p), "--out", str(out / "m.yaml"), "--samples-out", str(out / "s.csv"))
    return argv, ["--samples-out", "only with --log"]


def samples_out_is_out(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    argv = _learn("--log", str(p), "--out", str(out / "m.yaml"), "--samples-out", str(out / "m.yaml"), *FAST)
    return argv, ["--out and --samples-out", str(out / "m.yaml")]


def figures_is_a_file(d, rows, out):
    p = _write_log(d / "log.csv", rows)
    return _learn("--log", str(p), "--out", str(out / "m.yaml"), "--figures", str(p), *FAST), [
        f"--figures: {p} is --log {p}, an input of this command"
    ]


def demonstrate_out_is_a_file(d, rows, out):
    p = d / "taken.txt"
    p.write_text("not a folder\n")
    return ["demonstrate", "--speeds", "0.02", "--out", str(p)], [f"--out {p}: is a file"]


def demonstrate_speed_over_the_limit(d, rows, out):
    return ["demonstrate", "--speeds", "0.5", "--out", str(out)], ["speeds_mps", "0.08", "0.5"]


CASES: list[Case] = [
    log_binary,
    log_binary_after_header,
    log_nul_bytes,
    log_missing_column,
    log_nan_rows,
    log_inf_value,
    log_too_few_rows,
    log_not_a_number,
    log_time_not_increasing,
    log_capture_time_not_increasing,
    log_epm_height_not_positive,
    log_no_camera_frame,
    log_empty_file,
    log_missing_path,
    log_folder_without_logs,
    log_folder_with_binary_csv,
    log_shorter_than_the_filter_window,
    log_without_usable_samples,
    log_given_three_times,
    log_in_its_folder_and_by_a_link,
    samples_without_friction,
    samples_binary,
    samples_missing_column,
    samples_nan_row,
    out_is_a_folder,
    out_under_a_file,
    out_unwritable,
    out_is_the_input_log,
    out_is_the_input_samples,
    samples_out_is_a_folder,
    samples_out_with_samples,
    samples_out_is_out,
    figures_is_a_file,
    out_is_the_config,
    out_is_the_base_of_the_config,
    out_is_the_config_recorded_with_the_log,
    figures_hold_the_log,
    log_recorded_on_another_rig,
    log_recorded_with_other_friction,
    samples_with_a_huge_traction,
    samples_with_a_huge_speed,
    demonstrate_out_is_a_file,
    demonstrate_speed_over_the_limit,
]


def _snapshot(folder: Path) -> dict[str, str]:
    """Every file below ``folder`` with a hash of its content."""
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("case", CASES, ids=[c.__name__ for c in CASES])
def test_bad_input_exits_2_naming_it_and_writes_nothing(case, base, tmp_path, capsys):
    inputs, rows = base
    out = tmp_path / "out"
    argv, fragments = case(inputs, rows, out)
    out_existed = out.exists()
    before = _snapshot(tmp_path)
    assert main(argv) == 2
    captured = capsys.readouterr()
    message = captured.err.strip()
    assert len(message.splitlines()) == 1, message
    assert message.startswith(f"capsule-mpc {argv[0]}: "), message
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    assert "Traceback" not in captured.err
    assert _snapshot(tmp_path) == before  # inputs untouched, nothing added anywhere
    assert out.exists() == out_existed
    assert not Path("/proc/capsule_mpc_test").exists()


def test_a_write_failing_midway_leaves_nothing(base, tmp_path, capsys, monkeypatch):
    """Disk full while the second output is written: the first one must not appear either."""
    import matplotlib.figure

    inputs, rows = base
    log = _write_log(inputs / "log.csv", rows)
    out = tmp_path / "out" / "deeper"

    def full(self, fname, *args, **kwargs):
        Path(fname).write_bytes(b"partial")
        raise OSError(errno.ENOSPC, "No space left on device", str(fname))

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    argv = _learn(
        "--log",
        str(log),
        "--out",
        str(out / "m.yaml"),
        "--samples-out",
        str(out / "s.csv"),
        "--figures",
        str(out / "fig"),
        *FAST,
    )
    before = _snapshot(tmp_path)
    assert main(argv) == 2
    message = capsys.readouterr().err
    assert "No space left on device" in message and "nothing written" in message
    assert str(out / "fig") in message
    assert _snapshot(tmp_path) == before
    assert not (tmp_path / "out").exists()  # the folders it created are removed again


def test_a_valid_run_writes_every_output_and_no_temporary_file(base, tmp_path, capsys):
    """The control case of the catalogue: the same inputs, valid, write exactly the promised files."""
    inputs, rows = base
    log = _write_log(inputs / "log.csv", rows)
    out = tmp_path / "out"
    argv = _learn(
        "--log",
        str(log),
        "--out",
        str(out / "m.yaml"),
        "--samples-out",
        str(out / "s.csv"),
        "--figures",
        str(out / "fig"),
        *FAST,
    )
    assert main(argv) == 0
    written = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert written == ["fig/friction_c_fit.png", "fig/friction_residuals.png", "m.yaml", "s.csv"]
