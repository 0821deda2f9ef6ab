"""Stop requests that must not be lost.

A signal handler raises its exception wherever the main thread is. Inside a garbage
collector callback (JAX installs one) Python prints "Exception ignored" and goes on, so a
Ctrl-C in the first seconds of a run could be swallowed and the run finish as if nothing
happened (Python's "Exception ignored" message with a traceback on stderr). The command
line's handler therefore records the request here (:func:`request`) and raises only outside
such a callback (:func:`in_gc_callback`); the driver raises a recorded request after every
chunk (:func:`raise_pending`), once the chunk's checkpoint is written, and the command line
once the command returns: an interrupt during a collection stops the run one chunk later.
"""
from __future__ import annotations

import gc
from typing import Any


class Terminated(BaseException):
    """SIGTERM, raised where the process is, so that pending writes clean up after
    themselves (a temporary file is removed, a checkpoint is whole or absent)."""


_pending: list[type[BaseException]] = []


def request(kind: type[BaseException]) -> None:
    """Record that the process was asked to stop with ``kind`` (KeyboardInterrupt,
    :class:`Terminated`)."""
    _pending[:] = [kind]


def clear() -> None:
    """Forget a recorded request (a command that starts, or one that has stopped)."""
    _pending.clear()


def raise_pending() -> None:
    """Raise a recorded request whose own exception was swallowed, if any."""
    if _pending:
        kind = _pending.pop()
        raise kind()


def in_gc_callback(frame: Any) -> bool:
    """Whether ``frame`` (a signal handler's) runs inside a garbage-collector callback."""
    codes = {getattr(callback, "__code__", None) for callback in gc.callbacks}
    codes.discard(None)
    while frame is not None:
        if frame.f_code in codes:
            return True
        frame = frame.f_back
    return False
