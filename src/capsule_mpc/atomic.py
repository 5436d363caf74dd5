"""Atomic file output: write to a temporary file beside the target, then rename it.

An interrupted run leaves either the old file or the new one, never half a file. One
helper for every writer in the package (CSV logs, YAML/JSON, ``.npz`` tables, figures).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text_atomic"]


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    The temporary name keeps the suffix of ``path`` (NumPy and matplotlib infer the format
    from it) and lies in the same folder (same file system, so the rename is atomic). The
    parent folder is created. On an exception the temporary file is removed and ``path``
    is left untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.stem}.tmp{os.getpid()}{target.suffix}")
    try:
        yield tmp
        tmp.replace(target)
    finally:
        tmp.unlink(missing_ok=True)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (flushed to disk before the rename); returns the path."""
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    return Path(path)
