"""Checks of the values an experiment is given, before any work: a list with a value given twice,
an output path that cannot be written. Each names the command-line option the value came from."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from ..errors import ConfigError
from ..outputs import shown_path

__all__ = ["output_problem", "refuse_repeats"]


def refuse_repeats(option: str, values: Sequence[object]) -> None:
    """Refuse a value given twice to a list option (it would be counted twice).

    Raises
    ------
    ConfigError
        ``"<option>: <value> is given more than once"``.
    """
    seen: set[object] = set()
    for value in values:
        if value in seen:
            raise ConfigError(f"{option}: {value!r} is given more than once")
        seen.add(value)


def _nearest_existing(path: Path) -> Path:
    """``path`` or its closest ancestor that exists."""
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def output_problem(option: str, path: Path, folder: bool) -> str | None:
    """Why ``path`` cannot be written as a file (``folder`` False) or created as a folder of
    figures or runs (``folder`` True), or None.

    Parameters
    ----------
    option : str
        The option that gave ``path`` (``--out``, ``--figures``, ...): the message starts with it.
    path : Path
        The output.
    folder : bool
        Whether ``path`` is a folder.
    """
    try:
        return _output_problem(option, path, folder)
    except OSError as exc:  # e.g. a name longer than the file system allows
        return f"{option} {shown_path(path)}: cannot be used: {exc.strerror or exc}"


def _output_problem(option: str, path: Path, folder: bool) -> str | None:
    if folder and path.exists() and not path.is_dir():
        return f"{option} {path}: is a file; give a folder for the figures"
    if not folder and path.is_dir():
        return f"{option} {path}: is a folder; give the file to write, e.g. {path / 'learned_friction.yaml'}"
    base = _nearest_existing(path if folder else path.parent)
    if not base.is_dir():
        return f"{option} {path}: cannot be created: {base} is a file, not a folder"
    if not os.access(base, os.W_OK | os.X_OK):
        return f"{option} {path}: folder {base} is not writable"
    return None
