"""Output folders: refusal of unusable paths, the lock, the manifest, and cleanup of earlier outputs."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys

import pytest

from capsule_mpc.atomic import write_text_atomic
from capsule_mpc.config import ConfigError
from capsule_mpc.interrupt import Interrupted
from capsule_mpc.outputs import (
    LOCK_NAME,
    MANIFEST_NAME,
    OutputError,
    output_folder,
    read_manifest,
    write_report_file,
)


def test_manifest_lists_what_the_command_wrote_and_its_status(tmp_path):
    out = tmp_path / "run"
    with output_folder(out, "simulate", argv=["simulate", "--out", str(out)]) as folder:
        assert folder.path == out and (out / LOCK_NAME).exists()
        write_text_atomic(out / "log.csv", "t\n")
        write_text_atomic(out / "sub" / "a.json", "{}")
    m = read_manifest(out)
    assert m["command"] == "simulate" and m["status"] == "complete" and m["exit_status"] == 0
    assert m["files"] == ["log.csv", "sub/a.json"]
    assert m["argv"] == ["simulate", "--out", str(out)]
    assert not (out / LOCK_NAME).exists()


def test_a_file_someone_else_writes_during_the_run_is_not_claimed_nor_removed_later(tmp_path):
    out = tmp_path / "run"
    with output_folder(out, "simulate") as folder:
        write_text_atomic(out / "log.csv", "t\n")
        (folder.path / "notes.txt").write_text("mine, written while the command ran")
    assert read_manifest(out)["files"] == ["log.csv"]
    with output_folder(out, "simulate"):
        write_text_atomic(out / "log.csv", "t\n")
    assert (out / "notes.txt").read_text() == "mine, written while the command ran"


def test_the_status_the_command_sets_is_the_manifests(tmp_path):
    out = tmp_path / "run"
    with output_folder(out, "simulate") as folder:
        write_text_atomic(out / "log.csv", "t\n")
        folder.status = 1  # e.g. the run stalled: its files are written all the same
    m = read_manifest(out)
    assert (m["status"], m["exit_status"], m["files"]) == ("failed", 1, ["log.csv"])


def test_next_run_removes_the_previous_outputs_but_not_the_users_files(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with output_folder(out, "simulate"):
        write_text_atomic(out / "predictions.npz", "x")
        write_text_atomic(out / "log.csv", "old")
        write_text_atomic(out / "runs" / "seed_0" / "log.csv", "old")
    with output_folder(out, "simulate"):
        assert not (out / "predictions.npz").exists()  # the earlier mpc run's extra file is gone
        assert not (out / "runs").exists()  # and its emptied sub-folders
        write_text_atomic(out / "log.csv", "new")
    assert (out / "notes.txt").read_text() == "mine"
    assert read_manifest(out)["files"] == ["log.csv"]
    assert sorted(p.name for p in out.iterdir()) == ["log.csv", MANIFEST_NAME, "notes.txt"]


def test_keep_previous_lists_only_this_commands_files(tmp_path):
    out = tmp_path / "cache"
    with output_folder(out, "demonstrate"):
        write_text_atomic(out / "a.csv", "1")
    with output_folder(out, "demonstrate", replace_previous=False):
        assert (out / "a.csv").exists()
        write_text_atomic(out / "b.csv", "2")
    assert read_manifest(out)["files"] == ["b.csv"]


def test_a_second_command_into_a_locked_folder_is_refused(tmp_path):
    out = tmp_path / "run"
    with output_folder(out, "compare"):
        with pytest.raises(OutputError, match=r"--out: .*in use by process \d+ .*\(compare\)"):
            with output_folder(out, "simulate"):
                pass
        assert (out / LOCK_NAME).exists()  # the refused command did not release the holder's lock


def test_a_stale_lock_is_taken_over_with_one_line_on_stderr(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )

    lock = {"pid": int(dead.stdout), "host": socket.gethostname(), "command": "simulate"}
    (out / LOCK_NAME).write_text(json.dumps(lock))
    with output_folder(out, "simulate"):
        write_text_atomic(out / "x", "1")
    assert read_manifest(out)["status"] == "complete"
    assert capsys.readouterr().err == (
        f"capsule-mpc simulate: warning: --out: {out} was locked by process {lock['pid']}, which no "
        "longer runs; taking the lock\n"
    )


@pytest.mark.parametrize(
    "status, exit_status, exc",
    [
        ("interrupted", 130, KeyboardInterrupt()),
        ("interrupted", 143, Interrupted(signal.SIGTERM)),
        ("interrupted", 129, Interrupted(signal.SIGHUP)),
        ("failed", 1, RuntimeError()),
    ],
)
def test_an_interrupted_or_crashed_command_says_so_and_keeps_its_complete_files(
    tmp_path, status, exit_status, exc
):
    out = tmp_path / "run"
    with pytest.raises(type(exc)), output_folder(out, "plan"):
        write_text_atomic(out / "plan.json", "{}")
        raise exc
    m = read_manifest(out)
    assert m["status"] == status and m["exit_status"] == exit_status and m["files"] == ["plan.json"]
    assert not (out / LOCK_NAME).exists()


def test_bad_input_found_late_leaves_no_output_but_what_the_user_wrote(tmp_path):
    out = tmp_path / "new" / "run"
    with pytest.raises(ConfigError, match="speed"), output_folder(out, "simulate"):
        write_text_atomic(out / "config.yaml", "x")
        raise ConfigError("path.speed_mps: must be <= 0.08")
    assert not out.exists()
    mine = tmp_path / "mine"
    with pytest.raises(ConfigError), output_folder(mine, "simulate"):
        write_text_atomic(mine / "config.yaml", "x")
        (mine / "notes.txt").write_text("mine")
        raise ConfigError("path.speed_mps: must be <= 0.08")
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]


def test_a_file_or_unwritable_path_is_refused_naming_it(tmp_path):
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(OutputError, match=rf"--out: {f} exists and is not a folder"):
        with output_folder(f, "simulate"):
            pass
    with pytest.raises(OutputError, match=r"--out: cannot create .*file.txt/sub"):
        with output_folder(f / "sub", "simulate"):
            pass


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write into a read-only folder")
def test_a_read_only_folder_is_refused(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o500)
    with pytest.raises(OutputError, match="not writable"), output_folder(ro, "simulate"):
        pass


def test_a_manifest_cannot_remove_files_outside_its_folder(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    (out / MANIFEST_NAME).write_text(json.dumps({"files": ["../victim.txt", "/etc/hostname", 3]}))
    with output_folder(out, "simulate"):
        pass
    assert victim.read_text() == "keep"


def test_a_manifest_cannot_remove_the_lock_of_the_command(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / MANIFEST_NAME).write_text(json.dumps({"files": [LOCK_NAME]}))
    with output_folder(out, "simulate"):
        assert (out / LOCK_NAME).exists()


def test_a_command_interrupted_before_writing_leaves_nothing(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt), output_folder(out, "plan"):
        raise KeyboardInterrupt
    assert not out.exists()


def test_a_report_file_is_written_or_refused_naming_the_program(tmp_path, capsys):
    out = tmp_path / "report.json"
    assert write_report_file(out, '{"a": 1}\n', "bench_x") == 0
    assert out.read_text() == '{"a": 1}\n' and f"wrote {out}" in capsys.readouterr().out
    blocked = tmp_path / "a_file" / "report.json"  # its folder is a file
    (tmp_path / "a_file").write_text("")
    assert write_report_file(blocked, "{}\n", "bench_x") == 2
    assert f"bench_x: --out: cannot write {blocked}" in capsys.readouterr().err
    assert not blocked.exists()
