"""Atomic file output: write to a temporary file beside the target, then rename it.

An interrupted run leaves either the old file or the new one, never half a file. One
helper for every writer in the package (CSV logs, YAML/JSON, ``.npz`` tables, figures).

Every file renamed into place is also reported to the :func:`recording_writes` blocks that
cover its folder: that is how a command's output folder knows which files the command wrote
(:func:`capsule_mpc.outputs.output_folder`), and never claims a file someone else put there
meanwhile. Text is always UTF-8, whatever the locale.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path, PurePath
from typing import Any

__all__ = ["ENCODING", "atomic_path", "json_ready", "recording_writes", "write_text_atomic"]

#: The encoding of every text file the package reads or writes.
ENCODING = "utf-8"


def json_ready(value: Any) -> Any:
    """``value`` made ready for :func:`json.dumps`: mappings with string keys, sequences and numpy
    arrays as lists, numpy scalars as Python ones, paths as strings, and non-finite floats as None
    (JSON has no NaN or infinity; the package writes them as null)."""
    if isinstance(value, Mapping):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, PurePath):
        return str(value)
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return json_ready(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


#: The active :func:`recording_writes` blocks: (resolved folder, the files written under it, the
#: journal file each is appended to, or None).
_recorders: list[tuple[Path, set[Path], Path | None]] = []
_recorders_lock = threading.Lock()


def _record(target: Path) -> None:
    """Report a file just written to every block whose folder holds it."""
    if not _recorders:
        return
    path = target.parent.resolve() / target.name  # the file itself, even if a link pointed there
    with _recorders_lock:
        for root, files, journal in _recorders:
            if root in path.parents:
                files.add(path)
                if journal is not None:
                    _append(journal, path.relative_to(root).as_posix())


def _append(journal: Path, line: str) -> None:
    """Append ``line`` to ``journal``, flushed to disk (it must survive the process being killed)."""
    with journal.open("a", encoding=ENCODING) as fh:
        fh.write(line + "\n")
        fh.flush()
        os.fsync(fh.fileno())


@contextmanager
def recording_writes(folder: str | Path, journal: str | Path | None = None) -> Iterator[set[Path]]:
    """Collect, in the yielded set, every file written under ``folder`` while the block runs.

    A file counts when :func:`atomic_path` (and so :func:`write_text_atomic`) renames it into
    place, from any thread of this process; the set holds resolved paths. Blocks nest: a file is
    reported to every block whose folder holds it. With ``journal``, each file's path relative to
    ``folder`` is also appended to that file as it is written (what a killed process wrote).
    """
    entry = (Path(folder).resolve(), set[Path](), None if journal is None else Path(journal))
    with _recorders_lock:
        _recorders.append(entry)
    try:
        yield entry[1]
    finally:
        with _recorders_lock:
            _recorders.remove(entry)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    The temporary name keeps the suffix of ``path`` (NumPy and matplotlib infer the format
    from it) and lies in the same folder (same file system, so the rename is atomic). The
    parent folder is created. On an exception the temporary file is removed and ``path``
    is left untouched (an ``OSError`` that names no file is raised again naming ``path``). The
    written file is reported to the :func:`recording_writes` blocks
    that cover it.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.stem}.tmp{os.getpid()}{target.suffix}")
    try:
        yield tmp
        tmp.replace(target)
        _record(target)
    except OSError as exc:
        if exc.filename is None:  # e.g. a full disk on a write: say which file
            raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from exc
        raise
    finally:
        tmp.unlink(missing_ok=True)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically in UTF-8 (flushed to disk before the rename); the path."""
    with atomic_path(path) as tmp, tmp.open("w", encoding=ENCODING, newline="") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    return Path(path)
