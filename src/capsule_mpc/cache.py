"""The disk cache of computed artefacts (force maps, compiled MPC code): its folder and its entries.

The folder is a configured one (``force_map.cache_dir``), else ``$CAPSULE_MPC_CACHE``, else
``~/.cache/capsule_mpc``. One that cannot be written (a file, ``/proc``, no permission) is
replaced, for the process, by a temporary folder, said in one line on stderr; the temporary
folder is removed when the process exits (or, if it was killed, when another needs one).

An entry is a file with a checksum file beside it, ``<entry>.sha256`` (``sha256sum`` format),
put in place after the entry. An entry is used only if it matches its checksum and loads; one
that is truncated, modified, holds the wrong content or has no checksum is said in one line on
stderr, removed and built again. An entry is built in a temporary folder inside the cache
(``.build.<host>.<pid>.*``), removed whatever ends the build; the folders of processes that were
killed are removed the next time a process on the same host uses the cache folder. A process
holds a lock on an entry while it checks, builds or loads it, so concurrent processes build it
once.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import socket
import sys
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

__all__ = ["ENV_VAR", "cache_folder", "load_or_build", "usable_folder", "warn"]

T = TypeVar("T")

#: Environment variable naming the cache folder.
ENV_VAR = "CAPSULE_MPC_CACHE"
#: Name prefix of the temporary folders entries are built in (inside the cache folder).
_BUILD_PREFIX = ".build."
#: Name prefix of the temporary cache folders that replace an unwritable one (in the system's
#: temporary folder).
_FALLBACK_PREFIX = "capsule_mpc-cache."
#: What loading an entry may raise when its content is not what was cached (a foreign file).
_UNUSABLE = (OSError, ValueError, KeyError, EOFError, RuntimeError, zipfile.BadZipFile)
#: Longest reason quoted from an exception in a warning, characters.
_MAX_REASON = 160
#: Most bytes of a checksum file read (its line is ~100).
_MAX_CHECKSUM = 1024

#: Unwritable folders and the temporary folders used instead of them (removed at exit).
_fallbacks: dict[Path, tempfile.TemporaryDirectory[str]] = {}
#: Folders whose leftover build folders have been removed by this process.
_swept: set[Path] = set()


def warn(message: str) -> None:
    """Say ``message`` as one line on stderr (``capsule-mpc: warning: ...``)."""
    print(f"capsule-mpc: warning: {message}", file=sys.stderr, flush=True)


def cache_folder(configured: Path | None = None) -> Path:
    """The cache folder, created: ``configured``, else ``$CAPSULE_MPC_CACHE``, else
    ``~/.cache/capsule_mpc`` (see :func:`usable_folder`).

    Parameters
    ----------
    configured : Path, optional
        A folder given by the config (``force_map.cache_dir``).
    """
    if configured is not None:
        return usable_folder(Path(configured), "force_map.cache_dir")
    env = os.environ.get(ENV_VAR)
    if env:
        return usable_folder(Path(env), f"${ENV_VAR}")
    return usable_folder(Path.home() / ".cache" / "capsule_mpc")


def usable_folder(folder: Path, source: str | None = None) -> Path:
    """``folder``, created, if files can be written in it; else a temporary folder.

    The temporary folder serves the process from then on and is removed when it exits; the first
    call says so on stderr, naming ``folder`` (and ``source``, where it was set) and the reason.
    The first call for a writable folder removes the build folders that processes of this host
    left there when they were killed.

    Parameters
    ----------
    folder : Path
        The folder wanted.
    source : str, optional
        Where ``folder`` was set (e.g. ``$CAPSULE_MPC_CACHE``), for the warning.
    """
    folder = Path(folder)
    fallback = _fallbacks.get(folder)
    if fallback is not None:
        return Path(fallback.name)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        reason = "it is a file" if folder.is_file() else (exc.strerror or type(exc).__name__)
        _sweep(Path(tempfile.gettempdir()), _FALLBACK_PREFIX)
        tmp = tempfile.TemporaryDirectory(prefix=_own_prefix(_FALLBACK_PREFIX), ignore_cleanup_errors=True)
        _fallbacks[folder] = tmp
        where = f" ({source})" if source else ""
        warn(f"cache folder {folder}{where} cannot be written ({reason}); using {tmp.name} for this run")
        return Path(tmp.name)
    if folder not in _swept:
        _swept.add(folder)
        _sweep(folder, _BUILD_PREFIX)
    return folder


def load_or_build(path: Path, build: Callable[[Path], None], load: Callable[[Path], T]) -> tuple[T, bool]:
    """The cache entry ``path``, loaded; built and stored first if it is missing or unusable.

    Parameters
    ----------
    path : Path
        The entry, in a folder from :func:`usable_folder`.
    build : callable
        ``build(out)`` writes the entry to ``out``, a file of the same name in a temporary folder
        (which ``build`` may use for other files too; it is removed afterwards).
    load : callable
        ``load(path)`` reads the entry; it raises ``ValueError`` (or what reading a foreign file
        raises: ``OSError``, ``KeyError``, ``RuntimeError``, ...) if the content is not usable.

    Returns
    -------
    tuple
        What ``load`` returned, and whether the entry came from the cache (False: built now).
        An entry that fails its check or its load is said on stderr, removed and built again.
        The exceptions of ``build``, and of ``load`` on an entry built now, are raised.
    """
    checksum = _checksum_path(path)
    with _locked(path):
        if path.exists():
            problem = _check(path, checksum)
            if problem is None:
                try:
                    return load(path), True
                except _UNUSABLE as exc:
                    problem = f"cannot be used ({_one_line(exc)})"
            warn(f"cache entry {path} {problem}; removed, building it again")
        _remove(path, checksum)
        with tempfile.TemporaryDirectory(
            prefix=_own_prefix(_BUILD_PREFIX), dir=path.parent, ignore_cleanup_errors=True
        ) as scratch:
            out = Path(scratch) / path.name
            build(out)
            staged = Path(scratch) / checksum.name
            staged.write_text(f"{_sha256(out)}  {path.name}\n", encoding="ascii")
            out.replace(path)
            staged.replace(checksum)  # after the entry: an entry without one is never trusted
        try:
            return load(path), False
        except _UNUSABLE:
            _remove(path, checksum)
            raise


def _checksum_path(path: Path) -> Path:
    return path.with_name(path.name + ".sha256")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check(path: Path, checksum: Path) -> str | None:
    """Why the entry ``path`` cannot be trusted, or None if it matches its checksum."""
    try:
        with checksum.open("rb") as fh:
            fields = fh.read(_MAX_CHECKSUM).decode("ascii").split()
    except FileNotFoundError:
        return f"has no checksum ({checksum.name} is missing)"
    except (OSError, UnicodeDecodeError) as exc:
        return f"has an unreadable checksum file ({_one_line(exc)})"
    if len(fields) != 2 or fields[1].lstrip("*") != path.name:
        return f"has a checksum file that is not its own ({checksum.name})"
    try:
        digest = _sha256(path)
    except OSError as exc:
        return f"cannot be read ({_one_line(exc)})"
    if digest != fields[0].lower():
        return "does not match its checksum (truncated or modified)"
    return None


def _remove(path: Path, checksum: Path) -> None:
    for stale in (path, checksum):
        if stale.is_dir() and not stale.is_symlink():
            shutil.rmtree(stale)
        else:
            stale.unlink(missing_ok=True)


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on the entry ``path`` (a lock file beside it); without one if the
    file system has no locks."""
    try:
        handle = path.with_name(f".{path.name}.lock").open("a", encoding="utf-8")
    except OSError:
        yield
        return
    with handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX)
        except OSError:  # e.g. a network file system without locks
            pass
        yield


def _own_prefix(prefix: str) -> str:
    """``prefix`` with this process's host and id: the name of a temporary folder it owns."""
    return f"{prefix}{socket.gethostname()}.{os.getpid()}."


def _sweep(parent: Path, prefix: str) -> None:
    """Remove the temporary folders ``prefix<host>.<pid>.*`` in ``parent`` of this host's ended processes."""
    mine = f"{prefix}{socket.gethostname()}."
    try:
        entries = [
            e for e in os.scandir(parent) if e.name.startswith(mine) and e.is_dir(follow_symlinks=False)
        ]
    except OSError:
        return
    for entry in entries:
        pid = entry.name[len(mine) :].partition(".")[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(entry.path, ignore_errors=True)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= _MAX_REASON else text[: _MAX_REASON - 3] + "..."
