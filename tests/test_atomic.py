"""Atomic output: a writer that fails leaves the old file and no temporary file behind; text is
UTF-8 under any locale; the files written are recorded for the output folders."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import capsule_mpc
from capsule_mpc.atomic import atomic_path, recording_writes, write_text_atomic


def test_success_replaces_and_creates_parents(tmp_path):
    target = tmp_path / "deep" / "run.json"
    write_text_atomic(target, "old")
    write_text_atomic(target, "new")
    assert target.read_text() == "new"
    assert sorted(p.name for p in target.parent.iterdir()) == ["run.json"]


def test_failure_keeps_the_old_file(tmp_path):
    target = tmp_path / "log.csv"
    target.write_text("complete")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "complete"
    assert [p.name for p in tmp_path.iterdir()] == ["log.csv"]


def test_temporary_name_keeps_the_suffix(tmp_path):
    # np.savez would append ".npz" to a name without it, and the rename would miss the file.
    target = tmp_path / "table.npz"
    with atomic_path(target) as tmp:
        assert tmp.suffix == ".npz" and tmp.parent == tmp_path
        np.savez_compressed(tmp, a=np.arange(3))
    assert np.load(target)["a"].tolist() == [0, 1, 2]


def test_text_is_utf8_whatever_the_locale(tmp_path):
    """Under ``LC_ALL=C`` without Python's UTF-8 mode the locale's encoding is ASCII."""
    target = tmp_path / "summary.md"
    code = (
        "import sys; from capsule_mpc.atomic import write_text_atomic; "
        "write_text_atomic(sys.argv[1], 'mean \\u00b1 sd, m/s\\u00b3, \\u00b5m')"
    )
    env = dict(os.environ, LC_ALL="C", LANG="C", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0")
    env["PYTHONPATH"] = str(Path(capsule_mpc.__file__).resolve().parents[1])
    proc = subprocess.run([sys.executable, "-c", code, str(target)], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert target.read_bytes() == "mean ± sd, m/s³, µm".encode()


def test_writes_are_recorded_by_the_blocks_whose_folder_holds_them(tmp_path):
    outer, inner = tmp_path / "demo", tmp_path / "demo" / "compare"
    with recording_writes(outer) as in_outer:
        write_text_atomic(outer / "scenario.yaml", "a")
        with recording_writes(inner) as in_inner:
            write_text_atomic(inner / "summary.md", "b")
            (inner / "notes.txt").write_text("not through the package's writers")
        write_text_atomic(tmp_path / "elsewhere.txt", "c")
    write_text_atomic(outer / "after.txt", "d")
    assert in_inner == {(inner / "summary.md").resolve()}
    assert in_outer == {(outer / "scenario.yaml").resolve(), (inner / "summary.md").resolve()}


def test_the_journal_lists_each_file_as_it_is_written(tmp_path):
    journal = tmp_path / "journal"
    with recording_writes(tmp_path, journal=journal):
        write_text_atomic(tmp_path / "a.csv", "1")
        assert journal.read_text() == "a.csv\n"  # on disk at once: a killed process leaves it
        write_text_atomic(tmp_path / "sub" / "b.json", "{}")
    assert journal.read_text().splitlines() == ["a.csv", "sub/b.json"]


def test_a_write_error_that_names_no_file_is_raised_naming_the_target(tmp_path):
    target = tmp_path / "log.csv"
    with pytest.raises(OSError, match="No space left on device") as info, atomic_path(target):
        raise OSError(28, "No space left on device")
    assert info.value.filename == str(target) and list(tmp_path.iterdir()) == []


def test_json_ready_writes_what_json_can_hold_and_nulls_what_it_cannot():
    import json
    import math
    from pathlib import Path

    import numpy as np

    from capsule_mpc.atomic import json_ready

    value = {
        1: np.float64(0.5),
        "nan": math.nan,
        "inf": np.float32(np.inf),
        "n": np.int64(3),
        "flag": np.bool_(True),
        "path": Path("a/b"),
        "rows": (np.array([1.0, np.nan]), [np.int32(2)]),
    }
    ready = json_ready(value)
    assert ready == {
        "1": 0.5,
        "nan": None,
        "inf": None,
        "n": 3,
        "flag": True,
        "path": "a/b",
        "rows": [[1.0, None], [2]],
    }
    assert [type(ready[k]) for k in ("1", "n", "flag")] == [float, int, bool]
    assert json.loads(json.dumps(ready, allow_nan=False)) == ready
