"""The rule every command keeps: no output may be, hold or overwrite one of its inputs.

A command names its outputs (``--out`` as a folder or a file, ``--mcap``, ``--figures``, ...) and
its inputs (``--config`` with every file of its ``base:`` chain, ``--waypoints``, ``--plan``,
``--samples``, the run logs, the run folder being exported) and calls :func:`refuse_overwrite`
before any work. An output is refused (:class:`~capsule_mpc.errors.OutputError`: exit status 2,
one line naming both paths) when

* an output file is an input file (the same path, or another name for the same file: a
  symbolic or hard link);
* an output folder is an input, or holds one (the command writes and replaces files there);
* a path cannot be resolved (a symbolic link loop).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

import yaml

from .config._yaml import packaged_config_path
from .errors import OutputError

__all__ = ["config_files", "refuse_overwrite", "resolved", "shown_path"]

#: Deepest ``base:`` chain followed (the loader refuses deeper ones).
_MAX_BASE_DEPTH = 9

Given = str | Path | None


def shown_path(path: str | Path) -> str:
    """``path`` for a one-line message: ``''`` for an empty one, a very long one shortened."""
    text = str(path)
    if not text:
        return "''"
    return text if len(text) <= 100 else f"{text[:60]}...{text[-20:]} ({len(text)} characters)"


def resolved(path: str | Path, option: str) -> Path:
    """``path`` made absolute with its symbolic links followed.

    Raises
    ------
    OutputError
        ``<option>: <path> cannot be resolved: ...`` when the path cannot be resolved (a symbolic link loop).
    """
    try:
        return Path(path).resolve()
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symbolic link loop (Python < 3.13)
        reason = getattr(exc, "strerror", None) or "a symbolic link loop"
        raise OutputError(f"{option}: {shown_path(path)} cannot be resolved: {reason}") from None


def config_files(config: Given) -> list[Path]:
    """The scenario file ``config`` and every file of its ``base:`` chain (the packaged ``paper``
    base included); what cannot be read is left to the loader to report."""
    if config is None or not str(config):
        return []
    files: list[Path] = []
    path = Path(config)
    for _ in range(_MAX_BASE_DEPTH):
        files.append(path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8-sig"))
        except (OSError, ValueError, yaml.YAMLError):
            break
        base = data.get("base") if isinstance(data, dict) else None
        if not isinstance(base, str) or not base:
            break
        path = packaged_config_path(base) if base == "paper" else path.parent / base
    return files


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` (resolved) are one file: one path, or links to one inode."""
    if a == b:
        return True
    try:
        return a.samefile(b)
    except OSError:  # one of them does not exist
        return False


def _expanded(inputs: Mapping[str, Given | Iterable[Given]]) -> list[tuple[str, Path]]:
    """(how a message names it, resolved path) of every input file or folder; ``--config`` with
    its ``base:`` chain."""
    found: list[tuple[str, Path]] = []
    for option, given in inputs.items():
        many = [given] if given is None or isinstance(given, str | Path) else list(given)
        for one in many:
            if one is None or not str(one):
                continue
            paths = config_files(one) if option == "--config" else [Path(one)]
            for i, path in enumerate(paths):
                label = f"{option} {one}" if i == 0 else f"{path}, the base: of {option} {one}"
                found.append((label, resolved(path, option)))
    return found


def _clash(out: Path, is_folder: bool, source: Path) -> bool:
    """Whether writing the output ``out`` (resolved) may overwrite the input ``source`` (resolved)."""
    if is_folder:
        return out == source or out in source.parents or _same_file(out, source)
    return _same_file(out, source) or (source.is_dir() and source == out)


def refuse_overwrite(
    outputs: Mapping[str, tuple[Given, bool]], inputs: Mapping[str, Given | Iterable[Given]]
) -> None:
    """Refuse outputs that are, hold or would overwrite an input (module docstring).

    Parameters
    ----------
    outputs : mapping of str to (path, bool)
        The outputs by option: (the path or None when not given, whether it is a folder).
    inputs : mapping of str to path or paths
        The input files (or folders) by option; None for one not given. ``--config`` stands for
        the file and its whole ``base:`` chain.

    Raises
    ------
    OutputError
        ``<output option>: <path> is (or holds) <input option> <path>, an input of this
        command, which it would overwrite ...``.
    """
    sources = _expanded(inputs)
    for option, (given, is_folder) in outputs.items():
        if given is None or not str(given):
            continue
        out = resolved(given, option)
        for label, source in sources:
            if not _clash(out, is_folder, source):
                continue
            verb = "holds" if is_folder and out != source else "is"
            harm = "could remove or overwrite" if is_folder else "would overwrite"
            raise OutputError(
                f"{option}: {shown_path(given)} {verb} {label}, an input of this command, "
                f"which it {harm}; give another {'folder' if is_folder else 'file'}"
            )
