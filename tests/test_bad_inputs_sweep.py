"""Bad input to ``sweep``: its arguments, ``--vary`` (syntax, field, order, ranges) and Dask's
(``--workers`` with ``--scheduler``, a scheduler that does not answer).

Every case runs the command through ``capsule_mpc.cli.main`` and asserts exit code 2, that the
message on stderr is one line naming the argument (and the allowed values where there are some),
and that nothing was written: no output folder, or the folder of an earlier sweep left as it was.
Errors argparse finds print its usage first, then the one-line error.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from capsule_mpc.cli import main
from capsule_mpc.experiments.sweep.results import SPEC_FILE, code_fingerprint, sweep_spec
from capsule_mpc.experiments.sweep.vary import parse_vary

REPO = Path(__file__).resolve().parents[1]
RECTANGLE = REPO / "configs" / "rectangle.yaml"


@pytest.fixture
def base(tmp_path) -> list[str]:
    """A valid sweep's arguments but --out (the short path, one controller)."""
    wp = tmp_path / "wp.csv"
    wp.write_text("x_m,y_m\n0.0,0.0\n0.02,0.0\n0.02,0.015\n")
    return ["sweep", "--config", str(RECTANGLE), "--waypoints", str(wp), "--controllers", "follow"]


def _refused_by_argparse(args: list[str], capsys) -> str:
    """Run ``args``; argparse must exit 2. Returns the error line."""
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("capsule-mpc sweep: error: argument "), err
    return err[-1]


def _refused(args: list[str], capsys) -> str:
    """Run ``args``; the command must return 2 with one line on stderr. Returns it."""
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize(
    ("vary", "says"),
    [
        ("plant.mu0_scale", "must be plant.FIELD=LO:HI, got 'plant.mu0_scale'"),
        ("plant.mu0_scale=0.8-1.2", "must be plant.FIELD=LO:HI"),
        ("plant.mu0_scale=low:1.2", "LO and HI must be numbers, got 'plant.mu0_scale=low:1.2'"),
        ("plant.mu0_scale=nan:1.2", "LO and HI must be finite"),
        ("plant.mu_scale=0.8:1.2", "unknown field 'plant.mu_scale'"),
        ("mpc.horizon=5:10", "unknown field 'mpc.horizon'"),
        ("plant.preset=0:1", "unknown field 'plant.preset'"),
        ("plant.mu0_scale=1.2:0.8", "LO must be <= HI, got 'plant.mu0_scale=1.2:0.8'"),
        ("plant.mu0_scale=0.1:1.2", "LO 0.1 is outside plant.mu0_scale's allowed range [0.3, 3]"),
        ("plant.mass_scale=1:2.5", "HI 2.5 is outside plant.mass_scale's allowed range [0.5, 2]"),
        (
            "plant.servo_bandwidth_hz=0:5",
            "LO 0 is outside plant.servo_bandwidth_hz's allowed range (0, 1000]",
        ),
    ],
)
def test_vary_syntax_field_order_and_range(base, tmp_path, capsys, vary, says):
    out = tmp_path / "out"
    line = _refused_by_argparse([*base, "--runs", "2", "--vary", vary, "--out", str(out)], capsys)
    assert line.startswith("capsule-mpc sweep: error: argument --vary: ") and says in line
    assert not out.exists()


def test_an_unknown_field_lists_the_fields_that_can_vary(base, tmp_path, capsys):
    line = _refused_by_argparse(
        [*base, "--runs", "2", "--vary", "plant.x=0:1", "--out", str(tmp_path)], capsys
    )
    assert "one of plant.epm_remanence_scale, " in line and "plant.start_dead_zone_fraction" in line


def test_vary_past_what_the_scenario_allows(base, tmp_path, capsys):
    """The delay must stay below one camera period (1/30 s): a rule of the scenario, not the field's."""
    out = tmp_path / "out"
    line = _refused(
        [*base, "--runs", "2", "--vary", "plant.compute_delay_s=0:0.05", "--out", str(out)], capsys
    )
    assert line.startswith(
        "capsule-mpc: --vary plant.compute_delay_s=0:0.05: with plant.compute_delay_s = 0.05: "
    )
    assert "must be < one camera period" in line
    assert not out.exists()


def test_the_same_field_varied_twice(base, tmp_path, capsys):
    out = tmp_path / "out"
    args = [*base, "--runs", "2", "--vary", "plant.mu0_scale=0.8:1", "--vary", "plant.mu0_scale=1:1.2"]
    line = _refused([*args, "--out", str(out)], capsys)
    assert line == "capsule-mpc: --vary: plant.mu0_scale is given more than once"
    assert not out.exists()


@pytest.mark.parametrize("runs", ["0", "-1", "two"])
def test_runs_below_one(base, tmp_path, capsys, runs):
    out = tmp_path / "out"
    line = _refused_by_argparse([*base, "--runs", runs, "--out", str(out)], capsys)
    assert "argument --runs: must be an integer >= 1" in line and not out.exists()


def test_runs_is_required(base, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*base, "--out", str(tmp_path / "out")])
    assert exc.value.code == 2 and "--runs" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("workers", ["0", "-2", "many"])
def test_workers_below_one(base, tmp_path, capsys, workers):
    out = tmp_path / "out"
    line = _refused_by_argparse([*base, "--runs", "2", "--workers", workers, "--out", str(out)], capsys)
    assert "argument --workers: must be an integer >= 1" in line and not out.exists()


def test_workers_with_a_scheduler(base, tmp_path, capsys):
    out = tmp_path / "out"
    args = [*base, "--runs", "2", "--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"]
    line = _refused([*args, "--out", str(out)], capsys)
    assert line == "capsule-mpc: --workers: not with --scheduler (the cluster's workers are its own)"
    assert not out.exists()


def test_an_unreachable_scheduler(base, tmp_path, capsys, monkeypatch):
    import capsule_mpc.experiments.sweep.tasks as tasks

    monkeypatch.setattr(tasks, "SCHEDULER_TIMEOUT_S", 1.0)
    out = tmp_path / "out"
    address = "tcp://127.0.0.1:9"  # the discard port: nothing listens there
    line = _refused([*base, "--runs", "2", "--scheduler", address, "--out", str(out)], capsys)
    assert line.startswith(f"capsule-mpc: --scheduler {address}: cannot reach the Dask scheduler: ")
    assert not out.exists()


def test_an_unknown_controller(base, tmp_path, capsys):
    out = tmp_path / "out"
    line = _refused([*base, "--runs", "2", "--controllers", "follow", "pid", "--out", str(out)], capsys)
    assert line.startswith("capsule-mpc: --controllers: unknown ['pid']; available: [") and not out.exists()


def test_a_folder_holding_another_sweep_is_left_as_it_is(base, tmp_path, capsys):
    """A sweep with --runs 3 is in the folder; asked for --runs 2 (to resume it?): refused, untouched."""
    from capsule_mpc.experiments.runs import prepare_run

    out = tmp_path / "out"
    (out / "runs").mkdir(parents=True)
    scenario, path, _ = prepare_run(RECTANGLE, base[4], None, None)
    spec = sweep_spec(
        scenario, path, scenario.sim.seed, 3, ["follow"], [parse_vary("plant.mu0_scale=0.8:1.2")]
    )
    (out / SPEC_FILE).write_text(json.dumps(spec))
    (out / "runs" / "seed_0.json").write_text("{}")
    before = sorted((p.relative_to(out), p.read_bytes()) for p in out.rglob("*") if p.is_file())
    args = [*base, "--runs", "2", "--vary", "plant.mu0_scale=0.8:1.2", "--out", str(out)]
    line = _refused(args, capsys)
    assert line.startswith(
        f"capsule-mpc: --out: {out} holds a sweep with other arguments (--runs: 3 in the folder, 2 now)"
    )
    line = _refused([*base, "--runs", "3", "--out", str(out)], capsys)
    assert '(--vary: {"mu0_scale": [0.8, 1.2]} in the folder, {} now)' in line
    line = _refused(
        [*base, "--runs", "3", "--vary", "plant.mu0_scale=0.8:1.2", "--plant", "hard", "--out", str(out)],
        capsys,
    )
    assert '(config plant.preset: "lab" in the folder, "hard" now)' in line
    assert sorted((p.relative_to(out), p.read_bytes()) for p in out.rglob("*") if p.is_file()) == before


def test_a_sweep_begun_by_other_code_is_not_resumed(base, tmp_path, capsys):
    """The folder's runs were made by another version of the package's code: the same arguments
    do not resume it (its runs and the new ones would mix two controllers under one name)."""
    from capsule_mpc.experiments.runs import prepare_run

    out = tmp_path / "out"
    (out / "runs").mkdir(parents=True)
    scenario, path, _ = prepare_run(RECTANGLE, base[4], None, None)
    spec = sweep_spec(scenario, path, scenario.sim.seed, 2, ["follow"], [])
    assert spec["code"] == code_fingerprint() and len(spec["code"]["sha256"]) == 16
    spec["code"] = {**spec["code"], "sha256": "0" * 16}
    (out / SPEC_FILE).write_text(json.dumps(spec))
    (out / "runs" / "seed_0.json").write_text("{}")
    before = sorted((p.relative_to(out), p.read_bytes()) for p in out.rglob("*") if p.is_file())
    line = _refused([*base, "--runs", "2", "--out", str(out)], capsys)
    assert line.startswith(
        f"capsule-mpc: --out: {out} holds a sweep with other arguments (the capsule_mpc code: "
    )
    assert '"0000000000000000"' in line and code_fingerprint()["sha256"] in line
    assert line.endswith("its runs cannot be resumed by this code; use another folder")
    assert sorted((p.relative_to(out), p.read_bytes()) for p in out.rglob("*") if p.is_file()) == before
