"""Ctrl-C (and SIGTERM, SIGHUP) that survives CasADi: a signal flag, checked after every solver call.

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
and restores the handler: ``capsule-mpc``'s ``main`` wraps a whole command, and there SIGTERM and
SIGHUP (:data:`TERMINATING_SIGNALS`) are handled as SIGINT is, so that a command that is asked to
stop ends as an interrupted one: complete files, its manifest saying ``interrupted``, its folder
unlocked, its worker processes stopped, exit status 128 + the signal's number
(:func:`exit_status`). The ``KeyboardInterrupt`` raised is an :class:`Interrupted`, which names the
signal. Outside any block (library use) Python's own handlers are left in place, and CasADi may
swallow Ctrl-C as above.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from types import FrameType
from typing import Any, TypeVar

__all__ = [
    "TERMINATING_SIGNALS",
    "Interrupted",
    "exit_status",
    "interrupted",
    "interruptible",
    "raise_if_interrupted",
    "run_interruptibly",
    "solver_call",
]

T = TypeVar("T")
#: How often the main thread wakes while :func:`run_interruptibly` waits, s (the reaction time to Ctrl-C).
_WAIT_S = 0.05

#: The signals that stop a ``capsule-mpc`` command as Ctrl-C does (those the platform has).
TERMINATING_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)

#: Whether a signal arrived inside the outermost :func:`interruptible` block.
_pending = False
#: The first signal that arrived there (what :class:`Interrupted` reports).
_signum: int = signal.SIGINT
#: Whether a block has installed :func:`_on_signal` (the outermost one restores the old handlers).
_installed = False
#: The handlers the outermost block replaced, to restore on leaving it.
_replaced: dict[int, Any] = {}
#: Whether a :func:`solver_call` is running (a signal is then recorded, not raised).
_deferred = False


class Interrupted(KeyboardInterrupt):
    """The ``KeyboardInterrupt`` of this module: says which signal stopped the work (``signum``)."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    def __reduce__(self) -> tuple[type[Interrupted], tuple[int]]:
        return type(self), (self.signum,)


def exit_status(exc: BaseException) -> int:
    """The exit status of a process stopped by ``exc``: 128 + its signal's number (130 for a
    ``KeyboardInterrupt`` that names none), as a shell reports a command a signal ended."""
    return 128 + int(getattr(exc, "signum", signal.SIGINT))


def _on_signal(signum: int, frame: FrameType | None) -> None:
    """Record the signal; raise :class:`Interrupted` unless a solver call runs (the first time)."""
    global _pending, _signum
    again = _pending
    if not again:
        _signum = signum
    _pending = True
    if again or not _deferred:
        raise Interrupted(_signum)


def interrupted() -> bool:
    """Whether Ctrl-C (or another handled signal) arrived in the :func:`interruptible` block running now."""
    return _pending


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` if Ctrl-C was pressed (or a handled signal arrived), e.g. during a
    solver call that swallowed it.

    Raises
    ------
    Interrupted
        If :func:`interrupted`.
    """
    if _pending:
        raise Interrupted(_signum)


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
    Interrupted
        If a handled signal arrived before the call returned (inside :func:`interruptible`).
    """
    global _deferred
    outer = _deferred
    _deferred = True
    try:
        yield
    finally:
        _deferred = outer
    raise_if_interrupted()


def _replaceable(signum: int) -> bool:
    """Whether ``signum`` has Python's default disposition (a handler the caller installed, or an
    ignored signal such as SIGHUP under ``nohup``, is left alone)."""
    handler = signal.getsignal(signum)
    if signum == signal.SIGINT:
        return handler is signal.default_int_handler
    return handler == signal.SIG_DFL


@contextmanager
def interruptible(signals: Sequence[int] = (signal.SIGINT,)) -> Iterator[None]:
    """A block in which Ctrl-C always ends in ``KeyboardInterrupt``, even if a solver swallowed it.

    The outermost block installs this module's handler for ``signals`` (only in the main thread,
    and only over Python's default handling of each: a handler the caller installed, or an
    ignored signal, is left alone) and restores them on exit. On leaving the block with a signal
    recorded, :class:`Interrupted` is raised: from an exception the block raised (the
    interrupt's consequence, e.g. a ``SystemError`` from CasADi) or instead of a normal exit.

    Parameters
    ----------
    signals : sequence of int
        The signals handled (default SIGINT only; ``capsule-mpc`` passes
        :data:`TERMINATING_SIGNALS`). Ignored in a nested block.

    Raises
    ------
    Interrupted
        If one of the signals arrived inside the block.
    """
    global _installed, _pending, _signum
    outermost = not _installed and threading.current_thread() is threading.main_thread()
    if outermost:
        _pending, _signum = False, signal.SIGINT
        for signum in signals:
            if _replaceable(signum):
                _replaced[signum] = signal.signal(signum, _on_signal)
        _installed = bool(_replaced)
        outermost = _installed
    try:
        yield
    except Exception as exc:
        if _pending:
            raise Interrupted(_signum) from exc
        raise
    else:
        if _pending:
            raise Interrupted(_signum)
    finally:
        if outermost:
            for signum, handler in _replaced.items():
                signal.signal(signum, handler)
            _replaced.clear()
            _installed = False
            _pending, _signum = False, signal.SIGINT
