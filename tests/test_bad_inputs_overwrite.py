"""No output overwrites an input: every command's outputs checked against its inputs in one rule.

Each case runs a command through ``capsule_mpc.cli.main`` in ``tmp_path`` (the working directory)
with an output (``--out``, ``--mcap``, ``log export --out``) that is, holds or links to one of the
command's inputs (the config and its whole ``base:`` chain, the waypoints, the run folder being
exported), or cannot be resolved (a symbolic link loop). It must end with exit status 2, one line
on stderr naming both paths, and every file under ``tmp_path`` (and in the package) byte for byte
as it was. ``learn-friction``'s cases are in ``test_bad_inputs_learn.py``.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

import capsule_mpc
from capsule_mpc.cli import main

PACKAGE = Path(capsule_mpc.__file__).resolve().parent
PAPER = PACKAGE / "configs" / "paper.yaml"
#: A short straight path inside the plate.
SHORT_PATH = "x_m,y_m\n0.0,0.0\n0.02,0.0\n"
#: The scenario (C.yaml) and its base (B.yaml, itself on the packaged paper.yaml).
CONFIG, BASE = "base: B.yaml\nname: c\n", "base: paper\nsim:\n  settle_s: 0.3\n  tail_s: 1.0\n"
#: The files of a run folder ``log export`` reads (their content does not matter to a refusal).
RUN_FILES = ("log.csv", "run.json", "config.yaml")


def snapshot(root: Path) -> dict[str, str]:
    """Every file (and symbolic link) under ``root``: relative path -> sha256 of its bytes or link
    (Python's byte-code caches aside)."""
    out: dict[str, str] = {}
    for here, _dirs, files in os.walk(root):
        for name in files:
            path = Path(here) / name
            if name.endswith(".pyc"):
                continue
            data = str(path.readlink()).encode() if path.is_symlink() else path.read_bytes()
            out[path.relative_to(root).as_posix()] = hashlib.sha256(data).hexdigest()
    return out


def _simulate(*extra: str) -> list[str]:
    return ["simulate", "--config", "C.yaml", "--waypoints", "W.csv", "--controller", "follow", *extra]


@dataclass(frozen=True)
class Case:
    """A refused output: ``prepare(tmp)`` makes extra files; the arguments; what the line says."""

    id: str
    argv: list[str]
    says: list[str]
    prepare: Callable[[Path], None] = lambda tmp: None


def _run_folder(tmp: Path) -> None:
    (tmp / "R").mkdir()
    for name in RUN_FILES:
        (tmp / "R" / name).write_text(f"the run's {name}\n")


def _hard_link(tmp: Path) -> None:
    os.link(tmp / "W.csv", tmp / "linked.mcap")


def _symbolic_link(tmp: Path) -> None:
    (tmp / "to_config.mcap").symlink_to(tmp / "C.yaml")


def _loop(tmp: Path) -> None:
    (tmp / "loop").symlink_to("loop")


def _config_named_json(tmp: Path) -> None:
    (tmp / "C.json").write_text(CONFIG)


def _base_in_out(tmp: Path) -> None:
    (tmp / "O").mkdir()
    (tmp / "O" / "B.yaml").write_text(BASE)
    (tmp / "C2.yaml").write_text("base: O/B.yaml\n")


CASES = [
    Case(
        "log-export-over-its-log",
        ["log", "export", "R", "--out", "R/log.csv"],
        ["--out: R/log.csv is RUN_DIR R/log.csv, an input of this command, which it would overwrite"],
        _run_folder,
    ),
    Case(
        "log-export-over-its-config",
        ["log", "export", "R", "--out", "R/config.yaml"],
        ["--out: R/config.yaml is RUN_DIR R/config.yaml"],
        _run_folder,
    ),
    Case(
        "log-export-onto-the-run-folder",
        ["log", "export", "R", "--out", "R"],
        ["--out: R is RUN_DIR R, an input of this command"],
        _run_folder,
    ),
    Case(
        "log-export-symlink-loop",
        ["log", "export", "R", "--out", "loop/x.mcap"],
        ["cannot be resolved"],
        _loop,
    ),
    Case(
        "simulate-mcap-over-waypoints",
        _simulate("--out", "O", "--mcap", "W.csv"),
        ["--mcap: W.csv is --waypoints W.csv, an input of this command, which it would overwrite"],
    ),
    Case(
        "simulate-mcap-over-config",
        _simulate("--out", "O", "--mcap", "C.yaml"),
        ["--mcap: C.yaml is --config C.yaml"],
    ),
    Case(
        "simulate-mcap-over-the-configs-base",
        _simulate("--out", "O", "--mcap", "B.yaml"),
        ["--mcap: B.yaml is B.yaml, the base: of --config C.yaml"],
    ),
    Case(
        "simulate-mcap-over-the-packaged-base",
        _simulate("--out", "O", "--mcap", str(PAPER)),
        [f"--mcap: {PAPER} is {PAPER}, the base: of --config C.yaml"],
    ),
    Case(
        "simulate-mcap-hard-link-to-waypoints",
        _simulate("--out", "O", "--mcap", "linked.mcap"),
        ["--mcap: linked.mcap is --waypoints W.csv"],
        _hard_link,
    ),
    Case(
        "simulate-mcap-symbolic-link-to-config",
        _simulate("--out", "O", "--mcap", "to_config.mcap"),
        ["--mcap: to_config.mcap is --config C.yaml"],
        _symbolic_link,
    ),
    Case(
        "simulate-out-holds-the-configs-base",
        ["simulate", "--config", "C2.yaml", "--waypoints", "W.csv", "--controller", "follow", "--out", "O"],
        ["--out: O holds O/B.yaml, the base: of --config C2.yaml, an input of this command"],
        _base_in_out,
    ),
    Case(
        "compare-out-holds-the-configs-base",
        ["compare", "--config", "C2.yaml", "--waypoints", "W.csv", "--controllers", "follow", "--out", "O"],
        ["--out: O holds O/B.yaml, the base: of --config C2.yaml"],
        _base_in_out,
    ),
    Case(
        "plan-out-holds-the-configs-base",
        ["plan", "--config", "C2.yaml", "--waypoints", "W.csv", "--out", "O"],
        ["--out: O holds O/B.yaml, the base: of --config C2.yaml"],
        _base_in_out,
    ),
    Case(
        "simulate-out-symlink-loop", _simulate("--out", "loop/x"), ["--out: loop/x cannot be resolved"], _loop
    ),
    Case(
        "simulate-mcap-symlink-loop",
        _simulate("--out", "O", "--mcap", "loop/x.mcap"),
        ["--mcap: loop/x.mcap cannot be resolved"],
        _loop,
    ),
    Case(
        "bench-out-over-its-config",
        ["bench", "--config", "C.json", "--out", "C.json", "--frames", "1"],
        ["--out: C.json is --config C.json, an input of this command, which it would overwrite"],
        _config_named_json,
    ),
    Case(
        "rig-serve-mcap-over-waypoints",
        [
            "rig",
            "serve",
            "--config",
            "C.yaml",
            "--waypoints",
            "W.csv",
            "--mcap",
            "W.csv",
            "--wait-controller",
            "1",
        ],
        ["--mcap: W.csv is --waypoints W.csv"],
    ),
]


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    """``tmp_path`` as the working directory, holding the scenario, its base and a waypoint file."""
    (tmp_path / "C.yaml").write_text(CONFIG)
    (tmp_path / "B.yaml").write_text(BASE)
    (tmp_path / "W.csv").write_text(SHORT_PATH)
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_an_output_that_is_an_input_is_refused_in_one_line_before_any_work(case, workdir, capsys):
    case.prepare(workdir)
    before, package_before = snapshot(workdir), snapshot(PACKAGE)
    try:
        status = main(case.argv)
    except SystemExit as exc:  # pragma: no cover - argparse: not expected here
        status = exc.code
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert status == 2, err
    assert len(err) == 1, err
    for fragment in case.says:
        assert fragment in err[0], (fragment, err[0])
    assert snapshot(workdir) == before
    assert snapshot(PACKAGE) == package_before
    assert not (workdir / "O" / "manifest.json").exists()
