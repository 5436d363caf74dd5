"""Output folders of the commands: one run per folder at a time, and a manifest of what it wrote.

A command that writes into ``--out`` enters :func:`output_folder`, which

1. refuses a path that is a file or cannot be created or written (:class:`OutputError`, exit 2);
2. takes a lock file (``.capsule-mpc.lock``, created exclusively): a second command into the same
   folder is refused while the first runs; a lock left by a process that no longer exists on
   this host is taken over with a warning;
3. removes what the previous command there produced, as listed in its manifest, so a folder never
   mixes the outputs of two runs (files the user put there are never touched);
4. on exit writes ``manifest.json``: the command, its arguments, the start and end times, how it
   ended (``status``: ``complete`` when its exit status is 0, else ``failed`` or
   ``interrupted``), its exit status (``exit_status``: the one the command set on the
   :class:`OutputFolder`, 1 for an error it did not handle, 128 + N for signal N) and the files it
   wrote: those renamed into place by :mod:`capsule_mpc.atomic` while it ran, so a file someone
   else creates in the folder meanwhile is never claimed, nor removed by the next command (a
   command that failed or was interrupted before writing anything leaves no manifest);
5. if the command refused its input (:class:`~capsule_mpc.config.ConfigError`, or the command's
   own refusals) after the folder was prepared, removes what it wrote and the folder too if it
   created it: bad input leaves no output.

Single files are written atomically (:mod:`capsule_mpc.atomic`), so an interrupted command leaves
complete files only, and the manifest says it was interrupted.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import time
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from .atomic import ENCODING, recording_writes, write_text_atomic
from .config import ConfigError
from .interrupt import exit_status

__all__ = [
    "LOCK_NAME",
    "MANIFEST_NAME",
    "OutputError",
    "OutputFolder",
    "output_file_problem",
    "output_folder",
    "read_manifest",
    "write_report_file",
]

#: The manifest a command leaves in its output folder.
MANIFEST_NAME = "manifest.json"
#: The lock file present while a command writes into the folder.
LOCK_NAME = ".capsule-mpc.lock"
#: Exit status of a command stopped by an error it did not handle (as Python's own).
_EXIT_ERROR = 1


class OutputError(ConfigError):
    """An output folder that cannot be used (a file, not writable, or in use by another command)."""


class OutputFolder:
    """The folder :func:`output_folder` prepared, and how the command that writes into it ends.

    Attributes
    ----------
    path : Path
        The folder (as given, not resolved).
    status : int
        The command's exit status, recorded in the manifest: 0 (the default) means the work was
        done (``complete``); a command that ends with another status sets it before leaving the
        block (``failed``). When an exception leaves the block, the status set is recorded if not
        0 (a command that turns that error into its own exit status), else 1.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.status = 0


def output_file_problem(out: Path, example_name: str) -> str | None:
    """Why a report file cannot be written to ``out`` (to check before a long run), or None.

    ``example_name`` is suggested when ``out`` is a folder.
    """
    if out.is_dir():
        return f"{out} is a folder; give a file name, e.g. {out / example_name}"
    folder = next(p for p in out.parents if p.exists())  # ends at "." or "/", which exist
    if not folder.is_dir():
        return f"{folder} is not a folder"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"cannot write in {folder.resolve()}"
    return None


def write_report_file(out: Path, text: str, prog: str) -> int:
    """Write a report ``text`` to ``out`` atomically and say so; the exit status: 0, or 2 with the
    reason on stderr (``prog: --out: cannot write ...``) when it cannot be written."""
    try:
        write_text_atomic(out, text)
    except OSError as exc:
        print(f"{prog}: --out: cannot write {out}: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


def read_manifest(folder: str | Path) -> dict | None:
    """The manifest the last command left in ``folder``; ``None`` if there is none or it is unreadable."""
    try:
        data = json.loads((Path(folder) / MANIFEST_NAME).read_text(encoding=ENCODING))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _listed(folder: Path) -> list[str]:
    """The files the manifest in ``folder`` lists (none without a readable manifest)."""
    previous = read_manifest(folder) or {}
    files = previous.get("files", [])
    return [f for f in files if isinstance(f, str)] if isinstance(files, list) else []


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def _acquire_lock(folder: Path, command: str) -> Path:
    lock = folder / LOCK_NAME
    info = {"pid": os.getpid(), "host": socket.gethostname(), "command": command, "since": time.time()}
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                held = json.loads(lock.read_text(encoding=ENCODING))
                pid, host = int(held["pid"]), str(held["host"])
            except (OSError, ValueError, KeyError, TypeError):
                held, pid, host = {}, -1, ""
            if host == socket.gethostname() and pid > 0 and not _pid_alive(pid):
                warnings.warn(
                    f"--out: {folder} was locked by process {pid}, which no longer runs; taking the lock",
                    stacklevel=3,
                )
                lock.unlink(missing_ok=True)
                continue
            who = f"process {pid} on {host} ({held.get('command', '?')})" if held else "another command"
            raise OutputError(
                f"--out: {folder} is in use by {who}; use another folder, or delete {lock} if no "
                "command is writing there"
            ) from None
        except OSError as exc:
            raise OutputError(f"--out: cannot write into {folder}: {exc.strerror}") from None
        with os.fdopen(fd, "w", encoding=ENCODING) as fh:
            json.dump(info, fh)
        return lock
    raise OutputError(f"--out: could not take the lock {lock}")  # pragma: no cover - a race lost twice


def _inside(folder: Path, rel: str) -> Path | None:
    """``folder / rel`` if it stays inside ``folder`` (a manifest is data, not trusted paths)."""
    path = (folder / rel).resolve()
    root = folder.resolve()
    return path if path != root and root in path.parents else None


def _remove_files(folder: Path, rels: Sequence[str]) -> None:
    """Remove the listed files, then the sub-folders that became empty."""
    parents: set[Path] = set()
    for rel in rels:
        path = _inside(folder, rel)
        if path is not None and path.is_file() and path.name not in (LOCK_NAME, MANIFEST_NAME):
            path.unlink()
            parents.update(p for p in path.parents if folder.resolve() in p.parents)
    for parent in sorted(parents, key=lambda p: len(p.parts), reverse=True):
        if parent.is_dir() and not any(parent.iterdir()):
            parent.rmdir()


def _prepare(path: str | Path) -> tuple[Path, bool]:
    """Check and create the folder; (the folder, whether this call created it).

    Raises
    ------
    OutputError
        See :func:`output_folder`.
    """
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"--out: {folder} exists and is not a folder")
    created = not folder.exists()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"--out: cannot create {folder}: {exc.strerror}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        if created:
            folder.rmdir()
        raise OutputError(f"--out: {folder} is not writable")
    return folder, created


def _relative(folder: Path, files: set[Path]) -> list[str]:
    """The files written under ``folder`` that are still there, as paths relative to it."""
    root = folder.resolve()
    return sorted(
        f.relative_to(root).as_posix()
        for f in files
        if f.name not in (LOCK_NAME, MANIFEST_NAME) and f.is_file() and root in f.parents
    )


def _write_manifest(
    folder: Path,
    command: str,
    argv: Sequence[str] | None,
    started: float,
    outcome: tuple[str, int],
    written: list[str],
    kept: list[str],
) -> None:
    """Write the manifest of a command that ended with ``outcome`` (status, exit status)."""
    status, code = outcome
    if written or status == "complete":  # the earlier work resumed is part of this result
        written = sorted(
            set(written) | {f for f in kept if (k := _inside(folder, f)) is not None and k.is_file()}
        )
    # A command stopped before it wrote anything leaves nothing, not a manifest of nothing.
    if status == "complete" or written:
        manifest = {
            "command": command,
            "argv": list(sys.argv[1:] if argv is None else argv),
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(started)),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "status": status,
            "exit_status": code,
            "files": written,
        }
        write_text_atomic(folder / MANIFEST_NAME, json.dumps(manifest, indent=2) + "\n")


@contextmanager
def output_folder(
    path: str | Path,
    command: str,
    *,
    replace_previous: bool = True,
    argv: Sequence[str] | None = None,
    refusals: tuple[type[BaseException], ...] = (ConfigError,),
    resume: bool = False,
) -> Iterator[OutputFolder]:
    """Prepare ``path`` for ``command``'s outputs and yield it; see the module docstring.

    Parameters
    ----------
    path : str or Path
        The ``--out`` folder (created with its parents).
    command : str
        The command's name, recorded in the lock and the manifest.
    replace_previous : bool
        Remove the files the previous command listed in its manifest (default). ``False`` keeps
        them (a command that reuses earlier outputs as a cache); the manifest then lists the files
        written by this command only.
    argv : sequence of str, optional
        The arguments recorded in the manifest; default ``sys.argv[1:]``.
    refusals : tuple of exception types
        Exceptions that mean the command refused its input (default ``ConfigError``): what it
        wrote is removed, and the folder too if this call created it.
    resume : bool
        The command continues its own earlier, unfinished work in ``path`` (``sweep``): with
        ``replace_previous`` False, the manifest lists the files the previous manifest listed
        that are still there as well as those written now.

    Yields
    ------
    OutputFolder
        The folder (``.path``); the command sets ``.status`` to its exit status if not 0.

    Raises
    ------
    OutputError
        ``path`` is a file, cannot be created or written, or another command holds its lock.
    """
    folder, created = _prepare(path)
    lock = _acquire_lock(folder, command)
    try:
        if replace_previous:
            _remove_files(folder, _listed(folder))
        kept = _listed(folder) if resume else []
        started = time.time()
        handle = OutputFolder(folder)
        outcome: tuple[str, int] | None = ("failed", _EXIT_ERROR)
        written: list[str] = []
        try:
            with recording_writes(folder) as files:
                try:
                    yield handle
                    outcome = ("complete" if handle.status == 0 else "failed", handle.status)
                except KeyboardInterrupt as exc:
                    outcome = ("interrupted", exit_status(exc))
                    raise
                except refusals:
                    # Bad input found after the folder was prepared: leave nothing behind.
                    _remove_files(folder, _relative(folder, files))
                    if replace_previous:  # the previous run's files are gone: its manifest too
                        (folder / MANIFEST_NAME).unlink(missing_ok=True)
                    outcome = None
                    raise
                except BaseException:  # an error the command did not handle here
                    outcome = ("failed", handle.status or _EXIT_ERROR)
                    raise
                finally:
                    written = _relative(folder, files) if outcome is not None else []
        finally:
            if outcome is not None:
                _write_manifest(folder, command, argv, started, outcome, written, kept)
    finally:
        lock.unlink(missing_ok=True)
        if created and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()
