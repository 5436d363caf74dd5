"""Ctrl-C that survives CasADi: a SIGINT flag, checked after every solver call.

CasADi polls for signals inside its solvers (IPOPT's intermediate callback, ``sqpmethod``).
When Python reports a pending ``KeyboardInterrupt`` there, CasADi catches it in C++, prints
a ``KeyboardInterruptException`` warning and returns a failure status
(``NonIpopt_Exception_Thrown``): the interrupt would be recorded as a failed solve, and the
run would go on. The exception may also be left pending and surface later from an unrelated
call as ``SystemError: ... returned a result with an exception set``.

So inside :func:`interruptible` SIGINT is handled by this module:

* in Python code it raises ``KeyboardInterrupt`` at once, as Python's default handler does;
* inside :func:`solver_call` (around every CasADi solver call) it is only recorded: CasADi never
  sees it, and the call raises ``KeyboardInterrupt`` when it returns. A long solve can stop
  early from its iteration callback by checking :func:`interrupted` (the planner's does). A
  second Ctrl-C raises at once, whatever CasADi then makes of it: the call still ends in
  ``KeyboardInterrupt``.

Leaving an :func:`interruptible` block after SIGINT always raises ``KeyboardInterrupt``, chained
to any exception the interrupt caused inside it. Blocks nest; only the outermost one installs
and restores the handler: ``capsule-mpc``'s ``main`` wraps a whole command. Outside any block
(library use) Python's own handler is left in place, and CasADi may swallow Ctrl-C as above.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

__all__ = ["interrupted", "interruptible", "raise_if_interrupted", "solver_call"]

#: Whether a SIGINT arrived inside the outermost :func:`interruptible` block.
_pending = False
#: Whether a block has installed :func:`_on_sigint` (the outermost one restores the old handler).
_installed = False
#: Whether a :func:`solver_call` is running (SIGINT is then recorded, not raised).
_deferred = False


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    """Record the interrupt; raise ``KeyboardInterrupt`` unless a solver call runs (the first time)."""
    global _pending
    again = _pending
    _pending = True
    if again or not _deferred:
        raise KeyboardInterrupt


def interrupted() -> bool:
    """Whether Ctrl-C (SIGINT) was pressed inside the :func:`interruptible` block running now."""
    return _pending


def raise_if_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed, e.g. during a solver call that swallowed it.

    Raises
    ------
    KeyboardInterrupt
        If :func:`interrupted`.
    """
    if _pending:
        raise KeyboardInterrupt


@contextmanager
def solver_call() -> Iterator[None]:
    """Around a CasADi solver call: Ctrl-C during it is recorded, then raised when it returns.

    Raises
    ------
    KeyboardInterrupt
        If SIGINT arrived before the call returned (inside :func:`interruptible`).
    """
    global _deferred
    outer = _deferred
    _deferred = True
    try:
        yield
    finally:
        _deferred = outer
    raise_if_interrupted()


@contextmanager
def interruptible() -> Iterator[None]:
    """A block in which Ctrl-C always ends in ``KeyboardInterrupt``, even if a solver swallowed it.

    The outermost block installs this module's SIGINT handler (only in the main thread, and
    only over Python's default handler: a handler the caller installed is left alone) and
    restores the default on exit. On leaving the block with the interrupt recorded,
    ``KeyboardInterrupt`` is raised: from an exception the block raised (the interrupt's
    consequence, e.g. a ``SystemError`` from CasADi) or instead of a normal exit.

    Raises
    ------
    KeyboardInterrupt
        If SIGINT arrived inside the block.
    """
    global _installed, _pending
    outermost = (
        not _installed
        and threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    )
    if outermost:
        _pending = False
        signal.signal(signal.SIGINT, _on_sigint)
        _installed = True
    try:
        yield
    except Exception as exc:
        if _pending:
            raise KeyboardInterrupt from exc
        raise
    else:
        if _pending:
            raise KeyboardInterrupt
    finally:
        if outermost:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            _installed = False
            _pending = False
