"""Stop requests that must not be lost.

A signal handler raises its exception wherever the main thread is. Inside a garbage
collector callback (JAX installs one) Python prints "Exception ignored" and goes on, so a
Ctrl-C in the first seconds of a run could be swallowed and the run finish as if nothing
happened. The command line's handler therefore also records the request here
(:func:`request`), and the driver raises it after every chunk (:func:`raise_pending`),
once the chunk's checkpoint is written: a swallowed interrupt stops the run one chunk later.
"""
from __future__ import annotations


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
