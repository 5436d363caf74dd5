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

A long CasADi call that never returns to Python (building an expanded ``nlpsol``: 30-100 s for the
pipe's plan at 5 mm/s on this machine) would hold Ctrl-C until it ends: :func:`run_interruptibly`
runs it in a worker thread while the main thread waits, ready for the signal.

Leaving an :func:`interruptible` block after SIGINT always raises ``KeyboardInterrupt``, chained
to any exception the interrupt caused inside it. Blocks nest; only the outermost one installs
and restores the handler: ``capsule-mpc``'s ``main`` wraps a whole command. Outside any block
(library use) Python's own handler is left in place, and CasADi may swallow Ctrl-C as above.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any, TypeVar

__all__ = ["interrupted", "interruptible", "raise_if_interrupted", "run_interruptibly", "solver_call"]

T = TypeVar("T")
#: How often the main thread wakes while :func:`run_interruptibly` waits, s (the reaction time to Ctrl-C).
_WAIT_S = 0.05

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


def run_interruptibly(fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``fn(*args, **kwargs)``, in a worker thread when Ctrl-C could otherwise not stop it.

    Inside :func:`interruptible` (in the main thread, outside :func:`solver_call`) the call runs
    in a daemon thread and the main thread waits for it, waking every :data:`_WAIT_S` so that
    SIGINT raises ``KeyboardInterrupt`` at once; the worker is then abandoned (a C++ call cannot
    be cancelled; the ``capsule-mpc`` process exits without waiting for it). Elsewhere ``fn`` is
    simply called. For long calls that release the GIL, such as building a CasADi solver; not
    for calls whose result other threads use meanwhile.

    Returns
    -------
    The result of ``fn``; its exception is raised here, and ``KeyboardInterrupt`` if Ctrl-C was
    pressed meanwhile (also when CasADi caught it in a Python callback that ``fn`` called).
    """
    if not _installed or _deferred or threading.current_thread() is not threading.main_thread():
        value = fn(*args, **kwargs)
        raise_if_interrupted()  # a KeyboardInterrupt that C++ caught in a Python callback of fn
        return value
    result: list[T] = []
    error: list[BaseException] = []

    def work() -> None:
        try:
            result.append(fn(*args, **kwargs))
        except BaseException as exc:  # handed to the waiting thread
            error.append(exc)

    worker = threading.Thread(target=work, name="capsule-mpc interruptible call", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(_WAIT_S)
    if error:
        raise error[0]
    raise_if_interrupted()
    return result[0]


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
