"""Output folders of the commands: one run per folder at a time, and a manifest of what it wrote.

A command that writes into ``--out`` enters :func:`output_folder`, which

1. refuses, before it writes anything (:class:`OutputError`, exit 2, one line saying why):

   * a path that is a file, or that cannot be created or written (e.g. a name too long);
   * the working directory (``--out .`` or ``--out ''``) or a folder holding it, and a folder in
     the ``capsule_mpc`` package: outputs belong in a folder of their own;
   * a folder that is or holds one of the command's inputs, or another output of the command
     that is one (:func:`capsule_mpc.overwrite.refuse_overwrite`: ``--config`` and its ``base:``
     chain, ``--waypoints``, ``--plan``; ``--mcap``): the command would remove or overwrite its
     own input;
   * a folder holding files named like the package's outputs (:data:`OUTPUT_NAMES`: an older
     run's ``predictions.npz``, a ``config.yaml`` of one's own) that no manifest there lists:
     they are not the package's to remove, and the new run would overwrite them or leave them
     mixed with its own files (a sweep resuming its own work and the caching commands,
     ``demonstrate`` and ``demo``, are not refused);

2. takes a lock file (``.capsule-mpc.lock``, created exclusively): a second command into the same
   folder is refused while the first runs; a lock left by a process that no longer exists on
   this host is taken over, and what that killed process left is cleaned up
   (:func:`capsule_mpc.previous_run.recover`), with a one-line warning on stderr;
3. sets aside what the previous command there produced, as listed in its manifest
   (:func:`capsule_mpc.previous_run.set_aside`; refused before any work if a file cannot be
   moved), so a folder never mixes the outputs of two runs (files the user put there are never
   touched); the previous run is dropped once the new one has written something, and put back
   exactly as it was otherwise (nothing written, bad input found late, a file that could not be
   written, a crash);
4. on exit writes ``manifest.json``: the command, its arguments, the start and end times, how it
   ended (``status``: ``complete`` when its exit status is 0, else ``failed`` or
   ``interrupted``), its exit status (``exit_status``: the one the command set on the
   :class:`OutputFolder`, 1 for an error it did not handle, 128 + N for signal N) and the files it
   wrote: those renamed into place by :mod:`capsule_mpc.atomic` while it ran, so a file someone
   else creates in the folder meanwhile is never claimed, nor removed by the next command (a
   command that failed or was interrupted before writing anything leaves no manifest);
5. if the command refused its input (:class:`~capsule_mpc.config.ConfigError`, or the command's
   own refusals) after the folder was prepared, or a file could not be written (an ``OSError``,
   e.g. a full disk), removes what it wrote and the folder too if it created it: bad input leaves
   no output, and a failed write no half-written folder.

Single files are written atomically (:mod:`capsule_mpc.atomic`), so an interrupted command leaves
complete files only, and the manifest says it was interrupted.
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import socket
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

from .atomic import ENCODING, recording_writes, write_text_atomic
from .errors import ConfigError, OutputError
from .interrupt import exit_status
from .overwrite import refuse_overwrite, resolved, shown_path
from .previous_run import JOURNAL_NAME, Backup, pid_alive, recover, set_aside

__all__ = [
    "LOCK_NAME",
    "MANIFEST_NAME",
    "OUTPUT_NAMES",
    "OutputError",
    "OutputFolder",
    "output_file_problem",
    "output_folder",
    "read_manifest",
    "shown_path",
    "write_report_file",
]

#: The manifest a command leaves in its output folder.
MANIFEST_NAME = "manifest.json"
#: The lock file present while a command writes into the folder.
LOCK_NAME = ".capsule-mpc.lock"
#: The names (``fnmatch`` patterns) of the files the commands write into their folders, at any
#: depth: such a file that no manifest lists makes a folder refused (module docstring).
OUTPUT_NAMES = (
    # simulate, and every run of compare
    "log.csv",
    "config.yaml",
    "run.json",
    "predictions.npz",
    "trajectories.png",
    "errors.png",
    "mpc_prediction.png",
    "run.mcap",
    # the arm export of arm-export, plan and simulate
    "epm_trajectory.csv",
    "joint_trajectory.csv",
    "joint_trajectory.yaml",
    "joint_trajectory.png",
    "arm_summary.json",
    # plan
    "epm_plan.csv",
    "plan.json",
    "plan.png",
    # compare and sweep
    "summary.json",
    "summary.md",
    "metrics.png",
    "distribution_*.png",
    "sweep.json",
    "seed_*.json",
    # demonstrate and demo
    "demonstrations.json",
    "demonstration.json",
    "learned_friction.yaml",
    "scenario.yaml",
    "friction_*.png",
)
#: How deep below the folder :data:`OUTPUT_NAMES` are looked for (compare --runs writes
#: ``runs/seed_<S>/<controller>/log.csv``).
_OUTPUT_DEPTH = 3
#: Exit status of a command stopped by an error it did not handle (as Python's own).
_EXIT_ERROR = 1


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

    return True


def _acquire_lock(folder: Path, command: str) -> tuple[Path, int | None]:
    """Take the folder's lock: (the lock file, the process that held it and no longer runs, or
    None)."""
    lock = folder / LOCK_NAME
    stale: int | None = None
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
            if host == socket.gethostname() and pid > 0 and not pid_alive(pid):
                stale = pid
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
        return lock, stale
    raise OutputError(f"--out: could not take the lock {lock}")  # pragma: no cover - a race lost twice


def _say_recovered(command: str, folder: Path, stale: int | None, done: str) -> None:
    """One line on stderr for a lock taken over from a process that no longer runs, and what was
    cleaned up after a killed command (``done``)."""
    if stale is not None:
        text = f"{folder} was locked by process {stale}, which no longer runs; taking the lock"
    elif done:
        text = f"{folder}: a command was killed while writing here"
    else:
        return
    done = f"; {done}" if done else ""
    print(f"capsule-mpc {command}: warning: --out: {text}{done}", file=sys.stderr)


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


def _holds(folder: Path, path: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies inside it (both resolved)."""
    return path == folder or folder in path.parents


def _misplaced(folder: Path, shown: str) -> str | None:
    """Why ``folder`` (resolved) must not take a command's outputs, or None (its inputs aside)."""
    cwd = Path.cwd().resolve()
    if folder == cwd:
        return f"--out: {shown} is the working directory; give the outputs a folder of their own"
    if folder in cwd.parents:
        return f"--out: {shown} holds the working directory ({cwd}); give the outputs a folder of their own"
    package = Path(__file__).resolve().parent  # this package's own folder
    if _holds(package, folder):
        return f"--out: {shown} is in the capsule_mpc package ({package}); write the outputs elsewhere"
    return None


def _check_unlisted(folder: Path, shown: str) -> None:
    """Refuse a folder holding files named like :data:`OUTPUT_NAMES` that its manifest does not list."""
    unlisted = _unlisted_outputs(folder, _listed(folder))
    if unlisted:
        more = f" and {len(unlisted) - 1} more" if len(unlisted) > 1 else ""
        raise OutputError(
            f"--out: {shown} holds {unlisted[0]}{more}, named like this package's outputs but listed in "
            "no manifest there; they would be overwritten or mixed with the new files: move them away "
            "or give another folder"
        )


def _unlisted_outputs(folder: Path, listed: Sequence[str]) -> list[str]:
    """The files under ``folder`` named like :data:`OUTPUT_NAMES` that ``listed`` does not hold."""
    known = set(listed)
    found: list[str] = []
    root_depth = len(folder.parts)
    for here, dirs, files in os.walk(folder):
        depth = len(Path(here).parts) - root_depth
        if depth >= _OUTPUT_DEPTH:
            dirs.clear()
        dirs.sort()
        for name in sorted(files):
            rel = (Path(here) / name).relative_to(folder).as_posix()
            if rel not in known and any(fnmatch.fnmatchcase(name, p) for p in OUTPUT_NAMES):
                found.append(rel)
    return found


def _prepare(
    path: str | Path,
    inputs: Mapping[str, str | Path | None],
    files: Mapping[str, str | Path | None],
) -> tuple[Path, bool]:
    """Check the folder and the command's other output ``files`` against its ``inputs``
    (:func:`capsule_mpc.overwrite.refuse_overwrite`) and create the folder; (the folder, whether
    this call created it).

    Raises
    ------
    OutputError
        See :func:`output_folder`.
    """
    folder, shown = Path(path), shown_path(path)
    try:
        real = resolved(folder, "--out")
        if folder.exists() and not folder.is_dir():
            raise OutputError(f"--out: {shown} exists and is not a folder")
        problem = _misplaced(real, shown)
        if problem:
            raise OutputError(problem)
        outputs = {"--out": (path, True), **{o: (f, False) for o, f in files.items()}}
        refuse_overwrite(outputs, inputs)
        created = not folder.exists()
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"--out: cannot create {shown}: {exc.strerror or exc}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        if created:
            folder.rmdir()
        raise OutputError(f"--out: {shown} is not writable")
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
    inputs: Mapping[str, str | Path | None] | None = None,
    files: Mapping[str, str | Path | None] | None = None,
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
    inputs : mapping of str to path, optional
        The command's input files by option (``{"--config": ..., "--waypoints": ...}``; None
        for an option not given, ``--config`` standing for its whole ``base:`` chain): a folder
        holding one is refused, as is one of ``files`` that is one.
    files : mapping of str to path, optional
        The command's output files outside the folder by option (``{"--mcap": ...}``), checked
        against ``inputs`` with the folder before anything is written.

    Yields
    ------
    OutputFolder
        The folder (``.path``); the command sets ``.status`` to its exit status if not 0.

    Raises
    ------
    OutputError
        ``path`` cannot or must not be used (module docstring), or another command holds its lock.
    """
    folder, created = _prepare(path, inputs or {}, files or {})
    lock, stale = _acquire_lock(folder, command)
    try:
        shown = shown_path(path)
        _say_recovered(command, folder, stale, recover(folder))
        if replace_previous and not resume and not created:
            _check_unlisted(folder, shown)
        kept = _listed(folder) if resume else []
        backup = set_aside(folder, _listed(folder), shown) if replace_previous else None
        yield from _run_in(folder, command, argv, refusals, backup, kept)
    finally:
        (folder / JOURNAL_NAME).unlink(missing_ok=True)
        lock.unlink(missing_ok=True)
        if created:
            _remove_empty(folder)


def _remove_empty(folder: Path) -> None:
    """Remove ``folder`` (which this command created) if it holds only empty folders."""
    for here, _dirs, _files in sorted(os.walk(folder), key=lambda w: len(w[0]), reverse=True):
        with contextlib.suppress(OSError):  # not empty
            Path(here).rmdir()


def _run_in(
    folder: Path,
    command: str,
    argv: Sequence[str] | None,
    refusals: tuple[type[BaseException], ...],
    backup: Backup | None,
    kept: list[str],
) -> Iterator[OutputFolder]:
    """Yield the folder to the command and record how it ended: a manifest, and the previous run
    (``backup``) dropped when the new one replaces it, else put back (module docstring)."""
    started = time.time()
    handle = OutputFolder(folder)
    stopped_by: tuple[type[BaseException], ...] = (*refusals, OSError)
    outcome: tuple[str, int] | None = None  # None: refused, or a file could not be written
    crashed = False
    written: list[str] = []
    try:
        with recording_writes(folder, journal=folder / JOURNAL_NAME) as files:
            try:
                yield handle
                outcome = ("complete" if handle.status == 0 else "failed", handle.status)
            except KeyboardInterrupt as exc:
                outcome = ("interrupted", exit_status(exc))
                raise
            except stopped_by:
                # Bad input found after the folder was prepared, or a file that could not be
                # written (a full disk): leave nothing of this run behind.
                raise
            except BaseException:  # an error the command did not handle here
                outcome, crashed = ("failed", handle.status or _EXIT_ERROR), True
                raise
            finally:
                written = _relative(folder, files)
    finally:
        record = (started, outcome, written, kept)
        _settle(folder, command, argv, record, backup, crashed)


def _settle(
    folder: Path,
    command: str,
    argv: Sequence[str] | None,
    record: tuple[float, tuple[str, int] | None, list[str], list[str]],
    backup: Backup | None,
    crashed: bool,
) -> None:
    """Keep the new run (its manifest written, the previous run dropped), or put the previous run
    back and remove the new run's files: after bad input, a write that failed, a crash, or a stop
    before anything was written (a crash in a folder without a previous run keeps its files)."""
    started, outcome, written, kept = record
    if outcome is None or not (outcome[0] == "complete" or written) or (crashed and backup is not None):
        if backup is not None:
            backup.restore(written)
        elif outcome is None:
            _remove_files(folder, written)
        return
    try:
        _write_manifest(folder, command, argv, started, outcome, written, kept)
    except OSError:
        if backup is not None:
            backup.restore(written)
        else:
            _remove_files(folder, written)
        raise
    if backup is not None:
        backup.discard()
