"""Ctrl-C between units of work, never inside a Dr.Jit kernel or loop.

Python raises ``KeyboardInterrupt`` wherever the interpreter happens to be. Inside
Dr.Jit's tracing of a symbolic loop that leaves Dr.Jit mid-recording and the
exception comes out as a ``RuntimeError`` (no checkpoint, a traceback). Work that
loops over units (render passes, rotations, iterations, frames) runs inside
:func:`deferred` and calls :func:`check` between units: the first SIGINT is only
noted and raised there; a second one raises at once, for the impatient.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

_received = 0       # SIGINTs since our handler was installed
_deferring = 0      # nesting depth of deferred() blocks


class Interrupted(KeyboardInterrupt):
    """Ctrl-C ended a run at a clean point; the message says what was kept and how to go on."""


def _on_sigint(signum, frame):
    global _received
    _received += 1
    if _deferring and _received == 1:
        return
    raise KeyboardInterrupt


# How soon an interrupt that Python dropped is sent again (s): after the finalizer it landed in has returned.
RESEND_DELAY = 0.005


def _unraisable(previous):
    """A ``sys.unraisablehook`` for the block :func:`handling` guards. Our ``KeyboardInterrupt`` raised where Python
    cannot propagate it (a ``__del__`` or a weakref callback that the garbage collector ran) would be printed with
    a traceback and lost: it is sent again instead, once that code has returned, and counted once."""
    def hook(unraisable):
        if not isinstance(unraisable.exc_value, KeyboardInterrupt):
            previous(unraisable)
            return
        global _received
        _received -= 1
        threading.Timer(RESEND_DELAY, os.kill, (os.getpid(), signal.SIGINT)).start()
    return hook


@contextmanager
def handling() -> Iterator[None]:
    """Install the SIGINT handler for the block (restoring the previous one after), unless it is installed.

    Outside :func:`deferred` it raises ``KeyboardInterrupt`` as Python's does, and
    :func:`received` says afterwards that an error came from an interruption.
    """
    global _received
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is _on_sigint:
        yield
        return
    previous, previous_hook = signal.signal(signal.SIGINT, _on_sigint), sys.unraisablehook
    sys.unraisablehook = _unraisable(previous_hook)
    _received = 0
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        sys.unraisablehook = previous_hook


@contextmanager
def deferred() -> Iterator[None]:
    """Inside the block the first Ctrl-C waits for the next :func:`check` (or the end of the block).

    Only on the main thread, where Python runs signal handlers: a block on another thread (the viewer's
    renders) defers nothing, and must not make the main thread's Ctrl-C wait for a check it never makes.
    """
    global _deferring
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with handling():
        _deferring += 1
        try:
            yield
        finally:
            _deferring -= 1
        check()     # a Ctrl-C after the block's last check; not reached when the block raised


def check() -> None:
    """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed: call it between units of work."""
    if _received:
        raise KeyboardInterrupt


def received() -> bool:
    """Whether Ctrl-C was pressed since the handler was installed."""
    return _received > 0
