"""Replacing the run in an output folder all or nothing, and what a killed command left there.

When a command writes into a folder that holds a previous run (the files its manifest lists),
:func:`set_aside` first moves those files and the manifest into :data:`BACKUP_NAME` inside the
folder, so the new run never mixes with the old one. If a file cannot be moved (an immutable
file, a read-only sub-folder), what was moved is put back and the command is refused before any
work (:class:`~capsule_mpc.errors.OutputError`, exit status 2). When the command ends,
:meth:`Backup.discard` drops the old run (the new one replaced it) or :meth:`Backup.restore` puts
it back exactly as it was, after removing the new run's files (a command that crashed, or was
stopped before it wrote anything).

While a command runs, every file it writes is appended to :data:`JOURNAL_NAME`. A command killed
outright (SIGKILL, a power cut) cannot clean up: the next command into the folder calls
:func:`recover` once it holds the folder's lock, which ends the killed run as a stopped one: the
complete files it wrote are listed in a manifest saying ``interrupted`` (a sweep resumes from
them) and the previous run it was replacing is dropped, or, if it wrote nothing, the previous run
is put back; and it removes the temporary files (``.<name>.tmp<PID>.<suffix>``) of processes that
no longer run, such as the unfinished MCAP of a killed run, which has no index and cannot be read
back. It says what it did in one line.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import time
from collections.abc import Sequence
from pathlib import Path

from .atomic import ENCODING, write_text_atomic
from .errors import OutputError

__all__ = ["BACKUP_NAME", "JOURNAL_NAME", "Backup", "pid_alive", "recover", "set_aside"]

#: The hidden folder holding the previous run while a command replaces it.
BACKUP_NAME = ".capsule-mpc.previous"
#: The list of the files the running command wrote (one relative path a line).
JOURNAL_NAME = ".capsule-mpc.journal"
#: The start of the names of the files that keep the folder (lock, journal, backup).
_PREFIX = ".capsule-mpc."
#: The manifest's name (as :data:`capsule_mpc.outputs.MANIFEST_NAME`).
_MANIFEST = "manifest.json"
#: A temporary file of :func:`capsule_mpc.atomic.atomic_path`: ``.<stem>.tmp<PID><suffix>``.
_TEMPORARY = re.compile(r"^\..+\.tmp(\d+)(\.[^.]*)?$")
#: How deep below the folder temporaries are looked for.
_DEPTH = 3
#: Exit status recorded for a command that was killed (128 + SIGKILL).
_KILLED = 137


def _inside(folder: Path, rel: str) -> Path | None:
    """``folder / rel`` if it stays inside ``folder`` (paths read from files are data)."""
    path = (folder / rel).resolve()
    root = folder.resolve()
    return path if path != root and root in path.parents else None


def _ours(folder: Path, path: Path) -> bool:
    """Whether ``path`` (resolved, inside ``folder``) is one of the files that keep the folder
    (the lock, the journal, the backup): never part of a run."""
    return path.relative_to(folder).parts[0].startswith(_PREFIX)


def _prune(folder: Path, below: Path) -> None:
    """Remove the empty folders between ``below`` (excluded) and ``folder`` (excluded)."""
    for parent in below.parents:
        if parent == folder or folder not in parent.parents:
            break
        try:
            parent.rmdir()
        except OSError:  # not empty
            break


class Backup:
    """The previous run of ``folder`` set aside in :data:`BACKUP_NAME` (:func:`set_aside`)."""

    def __init__(self, folder: Path, moved: list[str]) -> None:
        self.folder = folder.resolve()
        self.moved = moved

    @property
    def path(self) -> Path:
        """The backup folder."""
        return self.folder / BACKUP_NAME

    def restore(self, written: Sequence[str] = ()) -> None:
        """Remove the new run's files ``written`` (relative paths) and put the previous run back."""
        for rel in written:
            path = _inside(self.folder, rel)
            if path is not None and path.is_file():
                path.unlink()
                _prune(self.folder, path)
        for rel in self.moved:
            target = self.folder / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            (self.path / rel).replace(target)
        shutil.rmtree(self.path, ignore_errors=True)

    def discard(self) -> None:
        """Drop the previous run (the new one replaced it)."""
        shutil.rmtree(self.path, ignore_errors=True)


def set_aside(folder: Path, files: Sequence[str], shown: str) -> Backup | None:
    """Move the previous run's ``files`` and its manifest into the backup folder; None when there
    is nothing to move.

    Raises
    ------
    OutputError
        A file cannot be moved: everything is put back, the folder is as it was.
    """
    folder = folder.resolve()
    rels = [
        r
        for r in dict.fromkeys([*files, _MANIFEST])
        if (p := _inside(folder, r)) and p.is_file() and not _ours(folder, p)
    ]
    if not rels:
        return None
    backup = Backup(folder, [])
    try:
        for rel in rels:
            dest = backup.path / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            (folder / rel).replace(dest)
            backup.moved.append(rel)
    except OSError as exc:
        backup.restore()
        raise OutputError(
            f"--out: {shown} holds a previous run that cannot be replaced: {shown}/{rel} cannot be moved "
            f"({exc.strerror or exc}); nothing was changed"
        ) from None
    for rel in backup.moved:
        _prune(folder, folder / rel)
    return backup


def read_journal(folder: Path) -> list[str]:
    """The files the journal of ``folder`` lists (none without one)."""
    try:
        text = (folder / JOURNAL_NAME).read_text(encoding=ENCODING)
    except OSError:
        return []
    return list(dict.fromkeys(line for line in text.splitlines() if line))


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this host (one of another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _stale_temporaries(folder: Path) -> list[Path]:
    """The temporary files under ``folder`` whose process no longer runs (on this host)."""
    found: list[Path] = []
    root_depth = len(folder.parts)
    for here, dirs, files in os.walk(folder):
        if len(Path(here).parts) - root_depth >= _DEPTH:
            dirs.clear()
        for name in files:
            match = _TEMPORARY.match(name)
            if match and int(match.group(1)) != os.getpid() and not pid_alive(int(match.group(1))):
                found.append(Path(here) / name)
    return sorted(found)


def _manifest_of_killed(folder: Path, written: list[str]) -> None:
    """A manifest saying ``interrupted`` for the files a killed command left."""
    manifest = {
        "command": "unknown (killed)",
        "argv": [],
        "started": None,
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "status": "interrupted",
        "exit_status": _KILLED,
        "files": written,
    }
    write_text_atomic(folder / _MANIFEST, json.dumps(manifest, indent=2) + "\n")


def recover(folder: Path) -> str:
    """Clean up after a command killed while it wrote into ``folder`` (module docstring); what was
    done, for one line ("" for nothing). Call it holding the folder's lock."""
    folder = folder.resolve()
    written = [
        r
        for r in read_journal(folder)
        if r != _MANIFEST and (p := _inside(folder, r)) is not None and p.is_file()
    ]
    said: list[str] = []
    backup_path = folder / BACKUP_NAME
    backup = None
    if backup_path.is_dir():
        moved = sorted(p.relative_to(backup_path).as_posix() for p in backup_path.rglob("*") if p.is_file())
        backup = Backup(folder, moved)
    if written:  # as a stopped run: it keeps what it wrote, and replaced the previous run
        _manifest_of_killed(folder, written)
        said.append(f"listed the {len(written)} complete files it wrote in a manifest saying interrupted")
        if backup is not None:
            backup.discard()
            said.append(f"dropped the previous run it was replacing ({len(backup.moved)} files)")
    elif backup is not None:  # it wrote nothing: the previous run stays
        backup.restore()
        said.append(f"restored the previous run ({len(backup.moved)} files)")
    (folder / JOURNAL_NAME).unlink(missing_ok=True)
    stale = _stale_temporaries(folder)
    for path in stale:
        path.unlink(missing_ok=True)
    if stale:
        names = ", ".join(p.relative_to(folder).as_posix() for p in stale[:3])
        more = f" and {len(stale) - 3} more" if len(stale) > 3 else ""
        said.append(f"removed its unfinished {names}{more} (a file cut short cannot be read)")
    return "; ".join(said)
