"""Run folders: replacing a run is all or nothing, a stopped run keeps what it recorded, a killed
one is cleaned up by the next command, a full disk ends in one line, a cut log is refused.

Every case runs ``capsule_mpc.cli.main`` (or, for a killed command, a child process) on a short
run (``follow`` on a 20 mm path, ``ideal`` plant) and asserts the exit status, a one-line message,
and the files on disk before and after by hash.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from mcap.reader import make_reader

from capsule_mpc.cli import main
from capsule_mpc.errors import ConfigError
from capsule_mpc.interrupt import Interrupted
from capsule_mpc.outputs import LOCK_NAME, MANIFEST_NAME, output_folder, read_manifest
from capsule_mpc.sim.log import read_log
from capsule_mpc.telemetry.partial import PartialRun

REPO = Path(__file__).resolve().parents[1]
QUICK = str(REPO / "tests" / "data" / "rectangle_quick.yaml")
SHORT_PATH = "x_m,y_m\n-0.05,-0.03\n-0.03,-0.03\n"
#: Frames a stopped run has run before its signal.
STOPPED_AFTER = 10


def snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root``: relative path -> sha256 of its bytes."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _simulate(out: Path, *extra: str, waypoints: Path | None = None) -> list[str]:
    return [
        "simulate",
        "--config",
        QUICK,
        "--waypoints",
        str(waypoints or out.parent / "W.csv"),
        "--controller",
        "follow",
        "--plant",
        "ideal",
        "--no-progress",
        "--out",
        str(out),
        *extra,
    ]


@pytest.fixture(scope="module")
def previous_run(tmp_path_factory) -> Path:
    """A complete run folder (written once for the module; copy it before changing it)."""
    root = tmp_path_factory.mktemp("previous")
    (root / "W.csv").write_text(SHORT_PATH)
    main(_simulate(root / "run"))
    assert read_manifest(root / "run")["status"] in ("complete", "failed")
    return root / "run"


@pytest.fixture
def old(tmp_path, previous_run) -> Path:
    """A copy of the previous run in ``tmp_path/R`` (with the waypoint file beside it)."""
    (tmp_path / "W.csv").write_text(SHORT_PATH)
    shutil.copytree(previous_run, tmp_path / "R")
    return tmp_path / "R"


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


# -- replacing a run: all or nothing -----------------------------------------------------------


def test_a_previous_run_that_cannot_be_moved_refuses_the_new_one_before_any_work(old, capsys, monkeypatch):
    real = pathlib.Path.replace

    def replace(self, target):
        if self.name == "log.csv" and ".capsule-mpc.previous" in str(target):
            raise PermissionError(errno.EPERM, "Operation not permitted", str(self))
        return real(self, target)

    monkeypatch.setattr(pathlib.Path, "replace", replace)
    before = snapshot(old.parent)
    assert main(_simulate(old)) == 2
    err = _lines(capsys.readouterr().err)
    assert err == [
        f"capsule-mpc: --out: {old} holds a previous run that cannot be replaced: {old}/log.csv cannot be "
        "moved (Operation not permitted); nothing was changed"
    ]
    assert snapshot(old.parent) == before


def test_an_immutable_file_of_the_previous_run_refuses_the_new_one(old, capsys):
    if subprocess.run(["chattr", "+i", str(old / "log.csv")], capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not available here")
    try:
        before = snapshot(old.parent)
        assert main(_simulate(old)) == 2
        err = _lines(capsys.readouterr().err)
        assert len(err) == 1 and "cannot be moved (Operation not permitted)" in err[0], err
        assert snapshot(old.parent) == before
    finally:
        subprocess.run(["chattr", "-i", str(old / "log.csv")], check=True)


def _disk_full(monkeypatch) -> None:
    """The errors figure meets a full disk (after the log, config and summary are written)."""

    def full(logs, path, out, *args, **kw):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(out))

    monkeypatch.setattr("capsule_mpc.experiments.runs.plot_errors", full)


def test_a_full_disk_while_writing_keeps_the_previous_run_exactly(old, capsys, monkeypatch):
    _disk_full(monkeypatch)
    before = snapshot(old.parent)
    assert main(_simulate(old)) == 1
    err = _lines(capsys.readouterr().err)
    assert err == [f"capsule-mpc: stopped: No space left on device: {old / 'errors.png'}"]
    assert snapshot(old.parent) == before


def test_a_full_disk_in_a_new_folder_leaves_no_folder(tmp_path, capsys, monkeypatch):
    _disk_full(monkeypatch)
    (tmp_path / "W.csv").write_text(SHORT_PATH)
    before = snapshot(tmp_path)
    assert main(_simulate(tmp_path / "new")) == 1
    assert len(_lines(capsys.readouterr().err)) == 1
    assert snapshot(tmp_path) == before and not (tmp_path / "new").exists()


def test_a_crash_keeps_the_previous_run_exactly(old, monkeypatch):
    def broken(*args, **kw):
        raise RuntimeError("a bug")

    monkeypatch.setattr("capsule_mpc.experiments.runs.plot_trajectories", broken)
    before = snapshot(old.parent)
    with pytest.raises(RuntimeError, match="a bug"):
        main(_simulate(old))
    assert snapshot(old.parent) == before


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs (root only; skipped where it cannot be mounted)."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    if (
        os.geteuid() != 0
        or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)], capture_output=True
        ).returncode
    ):
        pytest.skip("cannot mount a small tmpfs here")
    yield mount
    subprocess.run(["umount", str(mount)], check=True)


@pytest.mark.parametrize("telemetry", [[], ["--no-mcap"]], ids=["mcap", "no-mcap"])
def test_a_real_full_disk_ends_in_one_line_and_leaves_nothing(tiny_disk, telemetry, capsys):
    waypoints = tiny_disk.parent / "W.csv"
    waypoints.write_text(SHORT_PATH)
    assert main(_simulate(tiny_disk / "R", *telemetry, waypoints=waypoints)) == 1
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("capsule-mpc: stopped: No space left on device: "), err
    assert list(tiny_disk.iterdir()) == []


# -- a stopped run keeps what it recorded ------------------------------------------------------


def _stop_after(monkeypatch, signum: int, frames: int) -> None:
    """The run gets ``signum`` after ``frames`` frames (0: before its first)."""

    def frame_end(self, loop, frame):
        if self.frames >= frames:
            raise Interrupted(signum)

    def on_reset(self, loop):
        self.loop = loop
        if frames == 0:
            raise Interrupted(signum)

    monkeypatch.setattr(PartialRun, "frame_end", frame_end)
    monkeypatch.setattr(PartialRun, "on_reset", on_reset)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=lambda s: s.name)
def test_a_signal_leaves_the_log_so_far_a_readable_mcap_and_a_manifest_saying_interrupted(
    old, capsys, monkeypatch, signum
):
    _stop_after(monkeypatch, signum, STOPPED_AFTER)
    assert main(_simulate(old)) == 128 + signum
    by = "" if signum == signal.SIGINT else f" by {signal.Signals(signum).name}"
    assert _lines(capsys.readouterr().err) == [f"capsule-mpc: interrupted{by}"]
    manifest = read_manifest(old)
    assert manifest["status"] == "interrupted" and manifest["exit_status"] == 128 + signum
    assert manifest["files"] == ["config.yaml", "log.csv", "run.mcap"]
    assert sorted(p.name for p in old.iterdir()) == ["config.yaml", "log.csv", MANIFEST_NAME, "run.mcap"]
    assert len(read_log(old / "log.csv")["t_s"]) == STOPPED_AFTER
    with (old / "run.mcap").open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics.message_count > STOPPED_AFTER


def test_a_run_stopped_before_its_first_frame_leaves_the_previous_run_exactly(old, capsys, monkeypatch):
    _stop_after(monkeypatch, signal.SIGTERM, 0)
    before = snapshot(old.parent)
    assert main(_simulate(old)) == 143
    assert _lines(capsys.readouterr().err) == ["capsule-mpc: interrupted by SIGTERM"]
    assert snapshot(old.parent) == before


def test_a_run_stopped_before_its_first_frame_in_a_new_folder_leaves_nothing(tmp_path, monkeypatch):
    _stop_after(monkeypatch, signal.SIGINT, 0)
    (tmp_path / "W.csv").write_text(SHORT_PATH)
    assert main(_simulate(tmp_path / "new")) == 130
    assert not (tmp_path / "new").exists()


def test_a_stopped_compare_keeps_the_logs_of_its_seeds_runs(tmp_path, capsys, monkeypatch):
    def frame_end(self, loop, frame):
        if loop.name == "paper_0.8v" and self.frames >= STOPPED_AFTER:
            raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(PartialRun, "frame_end", frame_end)
    (tmp_path / "W.csv").write_text(SHORT_PATH)
    argv = _simulate(tmp_path / "C")
    argv[argv.index("simulate")] = "compare"
    argv[argv.index("--controller")] = "--controllers"
    argv.insert(argv.index("follow") + 1, "paper_0.8v")
    assert main(argv) == 143
    assert _lines(capsys.readouterr().err) == ["capsule-mpc: interrupted by SIGTERM"]
    manifest = read_manifest(tmp_path / "C")
    assert manifest["status"] == "interrupted"
    assert manifest["files"] == [
        f"{c}/{f}" for c in ("follow", "paper_0.8v") for f in ("config.yaml", "log.csv", "run.mcap")
    ]
    assert len(read_log(tmp_path / "C" / "paper_0.8v" / "log.csv")["t_s"]) == STOPPED_AFTER
    assert len(read_log(tmp_path / "C" / "follow" / "log.csv")["t_s"]) > STOPPED_AFTER  # it had finished
    for controller in ("follow", "paper_0.8v"):
        with (tmp_path / "C" / controller / "run.mcap").open("rb") as fh:
            assert make_reader(fh).get_summary() is not None


# -- a killed command ---------------------------------------------------------------------------

KILLED = textwrap.dedent(
    """
    import os, signal, sys
    from capsule_mpc.atomic import atomic_path, write_text_atomic
    from capsule_mpc.outputs import output_folder
    with output_folder(sys.argv[1], "simulate"):
        if sys.argv[2] == "wrote":
            write_text_atomic(os.path.join(sys.argv[1], "log.csv"), "t_s\\n0.0\\n")
        with atomic_path(os.path.join(sys.argv[1], "run.mcap")) as tmp:
            tmp.write_bytes(b"\\x89MCAP0\\r\\n half a file")
            os.kill(os.getpid(), signal.SIGKILL)
    """
)


def _kill_while_writing(folder: Path, wrote: bool) -> int:
    """A command killed (SIGKILL) while it writes into ``folder`` (after writing ``log.csv`` if
    ``wrote``, with an MCAP half written); its process id."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    argv = [sys.executable, "-c", KILLED, str(folder), "wrote" if wrote else "nothing"]
    child = subprocess.Popen(argv, env=env)
    assert child.wait(timeout=60) == -signal.SIGKILL
    return child.pid


def _refused_in(folder: Path) -> None:
    """A command into ``folder`` that refuses its input: the folder is left as recovered."""
    with pytest.raises(ConfigError), output_folder(folder, "simulate"):
        raise ConfigError("refused")


def test_a_killed_command_that_wrote_nothing_leaves_the_previous_run_exactly(old, capsys):
    before = snapshot(old.parent)
    pid = _kill_while_writing(old, wrote=False)
    assert (old / LOCK_NAME).exists() and (old / f".run.tmp{pid}.mcap").exists()
    _refused_in(old)
    assert _lines(capsys.readouterr().err) == [
        f"capsule-mpc simulate: warning: --out: {old} was locked by process {pid}, which no longer runs; "
        f"taking the lock; restored the previous run ({len(before) - 1} files); removed its unfinished "
        f".run.tmp{pid}.mcap (a file cut short cannot be read)"
    ]
    assert snapshot(old.parent) == before
    _refused_in(old)
    assert capsys.readouterr().err == ""  # said once


@pytest.mark.parametrize("previous", [True, False], ids=["replacing-a-run", "new-folder"])
def test_a_killed_command_keeps_what_it_wrote_as_a_stopped_one(old, capsys, previous):
    if not previous:
        shutil.rmtree(old)
    pid = _kill_while_writing(old, wrote=True)
    _refused_in(old)
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1, err
    assert "listed the 1 complete files it wrote in a manifest saying interrupted" in err[0]
    assert ("dropped the previous run it was replacing" in err[0]) == previous
    assert f"removed its unfinished .run.tmp{pid}.mcap" in err[0]
    manifest = json.loads((old / MANIFEST_NAME).read_text())
    assert (manifest["status"], manifest["exit_status"], manifest["files"]) == (
        "interrupted",
        137,
        ["log.csv"],
    )
    assert sorted(p.name for p in old.iterdir()) == ["log.csv", MANIFEST_NAME]
    assert (old / "log.csv").read_text() == "t_s\n0.0\n"


# -- log export of a cut log --------------------------------------------------------------------


def test_log_export_refuses_a_log_cut_at_a_row_boundary(old, capsys):
    lines = (old / "log.csv").read_text().splitlines(keepends=True)
    (old / "log.csv").write_text("".join(lines[: len(lines) // 2]))
    before = snapshot(old.parent)
    assert main(["log", "export", str(old)]) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and f"{old / 'log.csv'}: covers " in err[0] and "the log is cut short" in err[0], err
    assert snapshot(old.parent) == before


@pytest.mark.parametrize(
    "io_error",
    [
        'Os { code: 28, kind: StorageFull, message: "No space" }',
        # the system's error wrapped in another (what a full tmpfs gives)
        "Custom { kind: Other, error: No space left on device (os error 28) }",
    ],
    ids=["os", "wrapped"],
)
def test_the_mcap_writers_reports_of_a_full_disk_become_one_error_naming_the_file(tmp_path, capsys, io_error):
    import logging

    import foxglove

    from capsule_mpc.telemetry.sinks import ChannelSpec, Sinks

    sinks = Sinks(tmp_path / "run.mcap")
    schema = foxglove.Schema(name="note", encoding="jsonschema", data=b"{}")
    sinks.open([ChannelSpec("/note", schema, "json")])
    report = f"error logging message: McapError(Io({io_error}))"
    for _ in range(100):  # what the SDK says for each message it cannot write
        logging.getLogger("foxglove.log_sink_set").warning(report)
    with pytest.raises(OSError, match="No space left on device") as info:
        sinks.log("/note", b"{}", 0)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(tmp_path / "run.mcap")
    with pytest.raises(OSError):
        sinks.close()
    assert capsys.readouterr().err == "" and list(tmp_path.iterdir()) == []
