"""Atomic output: a writer that fails leaves the old file and no temporary file behind."""

from __future__ import annotations

import numpy as np
import pytest

from capsule_mpc.atomic import atomic_path, write_text_atomic


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
