"""The package's exceptions: one base, :class:`CapsuleMPCError`, and a subclass per kind of failure.

Catch :class:`CapsuleMPCError` to handle any error the package raises on purpose (bad input, a plan
that cannot be made, an arm that cannot follow); anything else is a bug. Each subclass also derives
from the built-in exception it refines (``ValueError`` for bad input, ``RuntimeError`` for a failed
computation), so code that catches those keeps working.

The arm's errors (:mod:`capsule_mpc.arm.errors`) derive from :class:`CapsuleMPCError` too; they
carry the time and EPM position they happened at.
"""

from __future__ import annotations

import re

__all__ = [
    "CapsuleMPCError",
    "ConfigError",
    "LearningDataError",
    "OutputError",
    "PlanError",
    "library_error",
]

#: Longest line of a :class:`ConfigError` message, and most lines, characters.
MAX_LINE, MAX_LINES = 500, 20


def cut(text: str, limit: int) -> str:
    """``text``, ending in "..." after ``limit`` - 3 characters if it is longer than ``limit``."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


class CapsuleMPCError(Exception):
    """Base of every error the package raises on purpose."""


class ConfigError(CapsuleMPCError, ValueError):
    """A scenario file or value is invalid; the message names the field and the allowed range.

    The message is bounded: a line longer than 500 characters ends in "...", and lines past the
    20th are replaced by their count.
    """

    def __init__(self, message: str) -> None:
        lines = [cut(line, MAX_LINE) for line in str(message).splitlines() or [""]]
        if len(lines) > MAX_LINES:
            lines = [*lines[: MAX_LINES - 1], f"  ... and {len(lines) - MAX_LINES + 1} more"]
        super().__init__("\n".join(lines))


class OutputError(ConfigError):
    """An output folder that cannot be used (a file, not writable, in use by another command, or
    a folder the command must not write into)."""


class LearningDataError(CapsuleMPCError, ValueError):
    """A samples or log file is unusable; the message names the file, the column or row, and the rule."""


class PlanError(CapsuleMPCError, RuntimeError):
    """A plan was needed (e.g. by the ``plan`` controller) but its solve failed; the message says how."""


#: A native library's note of where in its own sources an error arose (`` at /path/file.rs:61.``).
_SOURCE_NOTE = re.compile(r"\s+at /\S+?\.rs:\d+\.?")


def library_error(exc: BaseException) -> str:
    """A native library's error as one line for a user: its source-file notes removed, the
    innermost reason kept (``Address already in use (os error 98)``)."""
    text = " ".join(_SOURCE_NOTE.sub("", str(exc)).split())
    reasons = re.findall(r"[^\[\]:]*\(os error \d+\)", text)
    return reasons[-1].strip() if reasons else text
