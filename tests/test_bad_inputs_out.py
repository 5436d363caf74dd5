"""Output folders a command refuses, and what it never loses.

Each refused ``--out`` (the working directory or a folder holding it, a folder in the package, a
folder holding the command's own input, a folder holding files named like outputs that no manifest
lists, a name too long) is run through ``capsule_mpc.cli.main`` in ``tmp_path`` as the working
directory, for every command it applies to, and must end with exit status 2, one line on stderr
naming ``--out`` and why, and every file under ``tmp_path`` (and in the package) byte for byte as
it was. Then what a command that runs must not do: claim or later remove a file someone else wrote
during the run, record a failed run as complete, print a stale lock as a Python warning, or fail
to write its files under a C locale.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

import capsule_mpc
from capsule_mpc.cli import main
from capsule_mpc.outputs import LOCK_NAME, MANIFEST_NAME, read_manifest

REPO = Path(__file__).resolve().parents[1]
RECTANGLE = str(REPO / "configs" / "rectangle.yaml")
#: The rectangle with runs cut off 1 s after the short path's nominal end (for the commands that run).
QUICK = str(REPO / "tests" / "data" / "rectangle_quick.yaml")
PACKAGE = Path(capsule_mpc.__file__).resolve().parent
#: A short L path (35 mm at the config's 20 mm/s): a plan of ~100 steps, a run of ~2 s.
SHORT_PATH = "x_m,y_m\n0.0,0.0\n0.02,0.0\n0.02,0.015\n"
#: A plan the arm follows: 1 s at rest, inside the default workspace.
ARM_PLAN = "t_s,epm_x_m,epm_y_m,epm_z_m\n0.0,0.0,0.0,0.095\n0.5,0.0,0.0,0.095\n1.0,0.0,0.0,0.095\n"
LONG_NAME = "a" * 300

#: Every command that writes into an ``--out`` folder, with valid arguments but ``--out`` (run in a
#: folder holding ``wp.csv`` and ``plan.csv``).
COMMANDS: dict[str, list[str]] = {
    "simulate": ["simulate", "--config", QUICK, "--waypoints", "wp.csv", "--controller", "follow"],
    "compare": ["compare", "--config", QUICK, "--waypoints", "wp.csv", "--controllers", "follow"],
    "sweep": ["sweep", "--config", QUICK, "--waypoints", "wp.csv", "--controllers", "follow", "--runs", "1"],
    "plan": ["plan", "--config", RECTANGLE, "--waypoints", "wp.csv"],
    "arm-export": ["arm-export", "--config", RECTANGLE, "--plan", "plan.csv"],
    "demonstrate": ["demonstrate", "--speeds", "0.02"],
}
#: The commands with a --no-progress option.
NO_PROGRESS = {"simulate", "compare", "sweep", "plan"}


def files_under(root: Path) -> dict[str, bytes]:
    """Every file under ``root``: relative path -> its bytes."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@dataclass(frozen=True)
class Case:
    """A refused ``--out``: ``prepare(tmp_path, command)`` -> (arguments replacing the command's own
    input options, the ``--out`` value); what the one-line message says."""

    id: str
    prepare: Callable[[Path, str], tuple[list[str], str]]
    says: Callable[[Path], list[str]]
    commands: tuple[str, ...] = tuple(COMMANDS)


def _same(tmp: Path, command: str) -> tuple[list[str], str]:
    return [], ""


def _dot(tmp: Path, command: str) -> tuple[list[str], str]:
    return [], "."


def _parent(tmp: Path, command: str) -> tuple[list[str], str]:
    return [], ".."


def _package_configs(tmp: Path, command: str) -> tuple[list[str], str]:
    return [], str(PACKAGE / "configs")


def _new_folder_in_package(tmp: Path, command: str) -> tuple[list[str], str]:
    return [], str(PACKAGE / "results" / "run")


def _input_inside(tmp: Path, command: str) -> tuple[list[str], str]:
    """The command's first input file moved into the output folder (which holds a previous run)."""
    out = tmp / "P"
    out.mkdir()
    if command == "arm-export":
        (out / "epm_plan.csv").write_text(ARM_PLAN)
        (out / MANIFEST_NAME).write_text(json.dumps({"command": "plan", "files": ["epm_plan.csv"]}))
        return ["--plan", "P/epm_plan.csv"], "P"
    (out / "wp.csv").write_text(SHORT_PATH)
    return ["--waypoints", "P/wp.csv"], "P"


def _config_inside(tmp: Path, command: str) -> tuple[list[str], str]:
    out = tmp / "P"
    out.mkdir()
    (out / "config.yaml").write_text((PACKAGE / "configs" / "paper.yaml").read_text())
    return ["--config", "P/config.yaml"], "P"


def _old_outputs_without_manifest(tmp: Path, command: str) -> tuple[list[str], str]:
    out = tmp / "old"
    out.mkdir()
    (out / "predictions.npz").write_bytes(b"an earlier run's predictions")
    (out / "notes.txt").write_text("mine")
    return [], "old"


def _unlisted_output_beside_a_manifest(tmp: Path, command: str) -> tuple[list[str], str]:
    """A folder whose manifest lists the last run's files, and a config.yaml of the user's."""
    out = tmp / "run"
    (out / "runs" / "seed_0" / "follow").mkdir(parents=True)
    (out / "runs" / "seed_0" / "follow" / "log.csv").write_text("t_s\n0\n")
    (out / MANIFEST_NAME).write_text(
        json.dumps({"command": "compare", "files": ["runs/seed_0/follow/log.csv"]})
    )
    (out / "config.yaml").write_text("# my own notes, not an output\n")
    return [], "run"


def _long_name(tmp: Path, command: str) -> tuple[list[str], str]:
    return [], LONG_NAME


CASES = [
    Case("empty", _same, lambda tmp: ["--out: '' is the working directory"]),
    Case("dot", _dot, lambda tmp: ["--out: . is the working directory"]),
    Case("parent", _parent, lambda tmp: [f"--out: .. holds the working directory ({tmp})"], ("simulate",)),
    Case(
        "package-configs",
        _package_configs,
        lambda tmp: [f"--out: {PACKAGE / 'configs'} is in the capsule_mpc package"],
        ("simulate", "plan", "arm-export"),
    ),
    Case(
        "new-folder-in-package",
        _new_folder_in_package,
        lambda tmp: [f"--out: {PACKAGE / 'results' / 'run'} is in the capsule_mpc package"],
        ("simulate", "sweep"),
    ),
    Case(
        "input-inside",
        _input_inside,
        lambda tmp: ["--out: P holds --", "an input of this command, which it could remove or overwrite"],
        ("simulate", "compare", "sweep", "plan", "arm-export"),
    ),
    Case(
        "config-inside",
        _config_inside,
        lambda tmp: ["--out: P holds --config P/config.yaml, an input of this command"],
        ("simulate", "plan", "demonstrate"),
    ),
    Case(
        "old-outputs-without-manifest",
        _old_outputs_without_manifest,
        lambda tmp: [
            "--out: old holds predictions.npz, named like this package's outputs but listed in no "
            "manifest there; they would be overwritten or mixed with the new files"
        ],
        ("simulate", "compare", "sweep", "plan", "arm-export"),
    ),
    Case(
        "unlisted-output-beside-a-manifest",
        _unlisted_output_beside_a_manifest,
        lambda tmp: ["--out: run holds config.yaml, named like this package's outputs"],
        ("simulate", "compare", "plan"),
    ),
    Case(
        "name-too-long",
        _long_name,
        lambda tmp: ["--out", f"{LONG_NAME[:60]}...{LONG_NAME[:20]} (300 characters)", "File name too long"],
    ),
]

PARAMS = [
    pytest.param(case, command, id=f"{case.id}-{command}") for case in CASES for command in case.commands
]


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    """``tmp_path`` as the working directory, holding a waypoint file and an arm plan."""
    (tmp_path / "wp.csv").write_text(SHORT_PATH)
    (tmp_path / "plan.csv").write_text(ARM_PLAN)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _args(command: str, replaced: list[str], out: str) -> list[str]:
    """The command's arguments with ``replaced`` options swapped in and ``--out``."""
    args = list(COMMANDS[command])
    for option, value in zip(replaced[::2], replaced[1::2], strict=True):
        if option in args:
            args[args.index(option) + 1] = value
        else:
            args += [option, value]
    return [*args, *(["--no-progress"] if command in NO_PROGRESS else []), "--out", out]


@pytest.mark.parametrize(("case", "command"), PARAMS)
def test_a_refused_out_says_why_in_one_line_and_nothing_is_written_or_lost(case, command, workdir, capsys):
    replaced, out = case.prepare(workdir, command)
    before, package_before = files_under(workdir), files_under(PACKAGE)
    status = main(_args(command, replaced, out))
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert status == 2, err
    assert len(err) == 1, err
    line = err[0]
    assert line.startswith("capsule-mpc"), line
    for part in case.says(workdir):
        assert part in line, line
    assert files_under(workdir) == before  # nothing written, nothing lost
    assert files_under(PACKAGE) == package_before
    assert not (PACKAGE / "results").exists()


# --- the case for real: a plan, then its arm export into the plan's own folder ------------------------------


def test_arm_export_into_the_folder_of_its_plan_is_refused_and_the_plan_kept(workdir, capsys):
    args = ["plan", "--config", RECTANGLE, "--waypoints", "wp.csv", "--no-progress", "--no-arm", "--out", "P"]
    assert main(args) == 0
    plan = files_under(workdir / "P")
    assert {"epm_plan.csv", "plan.json", "plan.png", "config.yaml", MANIFEST_NAME} <= set(plan)
    capsys.readouterr()
    assert main(["arm-export", "--plan", "P/epm_plan.csv", "--out", "P"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "capsule-mpc arm-export: --out: P holds --plan P/epm_plan.csv, an input of this command, which it "
        "could remove or overwrite; give another folder (nothing written)"
    ]
    assert files_under(workdir / "P") == plan
    assert main(["arm-export", "--plan", "P/epm_plan.csv", "--out", "arm"]) == 0  # elsewhere: written
    assert files_under(workdir / "P") == plan
    assert "joint_trajectory.csv" in read_manifest(workdir / "arm")["files"]


# --- what a command that runs must not do -------------------------------------------------------------------


def test_a_file_written_into_the_folder_during_a_run_is_not_claimed_nor_removed_by_the_next(
    workdir, capsys, monkeypatch
):
    """The user saves notes into the run's folder while ``simulate`` runs (here: as its result is told)."""
    from capsule_mpc.experiments import runs

    summary = runs.run_summary_text

    def summary_and_meanwhile_save_notes(result, out):
        (Path(out) / "notes.md").write_text("seen during the run\n")
        return summary(result, out)

    monkeypatch.setattr(runs, "run_summary_text", summary_and_meanwhile_save_notes)
    args = [*COMMANDS["simulate"], "--no-progress", "--out", "run"]
    main(args)
    assert "notes.md" not in read_manifest(workdir / "run")["files"]
    monkeypatch.setattr(runs, "run_summary_text", summary)
    main(args)  # replaces the previous run's files: not the notes
    assert (workdir / "run" / "notes.md").read_text() == "seen during the run\n"
    assert "notes.md" not in read_manifest(workdir / "run")["files"]


def test_a_failed_run_is_recorded_failed_with_its_exit_status(workdir, capsys):
    """``follow`` on the short path ends short of the path's end: exit status 1, its files written."""
    status = main([*COMMANDS["simulate"], "--no-progress", "--out", "run"])
    manifest = read_manifest(workdir / "run")
    completed = json.loads((workdir / "run" / "run.json").read_text())["flags"]["completed"]
    assert status == (0 if completed else 1) == manifest["exit_status"]
    assert manifest["status"] == ("complete" if completed else "failed")
    assert "log.csv" in manifest["files"]


def test_a_stale_lock_is_one_line_on_stderr_not_a_python_warning(workdir, capsys):
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    (workdir / "run").mkdir()
    lock = {"pid": int(dead.stdout), "host": socket.gethostname(), "command": "simulate"}
    (workdir / "run" / LOCK_NAME).write_text(json.dumps(lock))
    main([*COMMANDS["simulate"], "--no-progress", "--out", "run"])
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"capsule-mpc simulate: warning: --out: run was locked by process {lock['pid']}, which no longer "
        "runs; taking the lock"
    ]
    assert not (workdir / "run" / LOCK_NAME).exists()


def test_a_c_locale_writes_utf8_files_and_prints_what_it_cannot_show_escaped(tmp_path):
    """``compare --runs 2``'s summary.md holds ± and ³; under ``LC_ALL=C`` without UTF-8 mode."""
    (tmp_path / "wp.csv").write_text(SHORT_PATH)
    env = dict(os.environ, LC_ALL="C", LANG="C", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0")
    env["PYTHONPATH"] = str(PACKAGE.parent)
    code = "import sys; from capsule_mpc.cli import main; sys.exit(main())"
    args = [*COMMANDS["compare"], "paper_0.8v", "--runs", "2", "--no-progress", "--out", "cmp"]
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=tmp_path, env=env, capture_output=True)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")[-2000:]
    assert "±" in (tmp_path / "cmp" / "summary.md").read_text(encoding="utf-8")
    assert b"\\xb1" in proc.stdout and b"Traceback" not in proc.stderr
    assert read_manifest(tmp_path / "cmp")["status"] == "complete"
