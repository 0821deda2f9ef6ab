"""Stop requests that must not be lost.

A signal handler raises its exception wherever the main thread is. Inside a garbage
collector callback (JAX installs one) Python prints "Exception ignored" and goes on, so a
Ctrl-C in the first seconds of a run could be swallowed and the run finish as if nothing
happened (Python's "Exception ignored" message with a traceback on stderr). The command
line's handler therefore records the request here (:func:`request`) and raises only outside
such a callback (:func:`in_gc_callback`); the driver raises a recorded request after every
chunk (:func:`raise_pending`), once the chunk's checkpoint is written, and the command line
once the command returns: an interrupt during a collection stops the run one chunk later.

A handler runs only once the main thread is back in Python, and a compilation or a chunk
is one native call that can last minutes. So the command line also starts a
:class:`Watchdog`: Python's own C-level handler writes each signal to a wake-up file
descriptor at once, a thread waits on it, and if the process still runs ``grace``
seconds after a stop it ends the process itself — as a ``kill -9`` would, after releasing
the folder locks this process holds (:func:`hold`). What a kill leaves behind is already
safe: checkpoints and result files are written atomically, a dead writer's temporaries
are removed by the next writer, and ``--resume`` continues from the last checkpoint.
"""
from __future__ import annotations

import _weakrefset  # CPython's; read only by the CPython-specific checks below
import contextlib
import gc
import os
import signal
import sys
import threading
import weakref
from collections.abc import Callable, Iterator
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


_deferring = [0]


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Inside, a stop is only recorded (:func:`deferring`): a few steps that must not be
    cut in two (a lock file made and registered for release) run whole; the caller
    raises the request after them (:func:`raise_pending`)."""
    _deferring[0] += 1
    try:
        yield
    finally:
        _deferring[0] -= 1


def deferring() -> bool:
    """Whether the main thread is inside :func:`deferred`."""
    return _deferring[0] > 0


# --- CPython-specific ----------------------------------------------------------------------
# Where CPython drops an exception that a signal handler raises, or cannot take one: the
# three checks below read interpreter frames (``f_code``, ``f_back``), ``gc.callbacks``, the
# private module ``_weakrefset`` and importlib's frozen file names. These are details of
# CPython, not of the language: they are all here, and another interpreter
# needs its own versions of :func:`in_gc_callback`, :func:`in_dropping_callback` and
# :func:`in_import`. Everything else in this module is plain Python.


def in_gc_callback(frame: Any) -> bool:
    """Whether ``frame`` (a signal handler's) runs inside a garbage-collector callback."""
    codes = {getattr(callback, "__code__", None) for callback in gc.callbacks}
    codes.discard(None)
    while frame is not None:
        if frame.f_code in codes:
            return True
        frame = frame.f_back
    return False


#: Python prints and drops an exception raised in a weak reference's callback (the
#: weakref module's dictionaries and sets remove their dead entries in one) or in a
#: ``__del__``, as in a gc callback.
_WEAKREF_FILES = {weakref.__file__, _weakrefset.__file__}


def in_dropping_callback(frame: Any) -> bool:
    """Whether ``frame`` (a signal handler's) runs where Python drops an exception: a
    garbage-collector callback, a weak reference's callback, a ``__del__``."""
    if in_gc_callback(frame):
        return True
    while frame is not None:
        code = frame.f_code
        if code.co_filename in _WEAKREF_FILES or code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def in_import(frame: Any) -> bool:
    """Whether ``frame`` (a signal handler's) runs inside an import. An exception raised
    there can cross a native module's initialisation (jaxlib's), which aborts the process
    (rc −6) instead of raising: the request is recorded, and the watchdog or the next
    chunk acts on it."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


# --- end of the CPython-specific part -----------------------------------------------------


#: Releases of what this process holds (folder locks): run before a watchdog's exit.
_held: dict[int, Callable[[], object]] = {}


def hold(key: int, release: Callable[[], object]) -> None:
    """Register ``release`` (under ``key``, e.g. ``id(lock)``) to run if a watchdog ends
    the process."""
    _held[key] = release


def let_go(key: int) -> None:
    """Forget a registration of :func:`hold` (the thing was released normally)."""
    _held.pop(key, None)


class Watchdog:
    """Ends the process ``grace`` seconds after SIGINT or SIGTERM if it is still running
    (see the module docstring). Start it in the main thread; :meth:`stop` undoes it.

    Args:
      message: printed to stderr before the exit (or a function that says it then: what
        is true when the process ends).
      grace: seconds the main thread has to stop on its own.
    """

    def __init__(self, message: str | Callable[[], str], grace: float = 1.0) -> None:
        self.message, self.grace = message, grace
        self._done = threading.Event()
        self._exiting = threading.Lock()  # the exit, or the main thread's own stop: one
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)
        self._previous = signal.set_wakeup_fd(self._write, warn_on_full_buffer=False)
        self._thread = threading.Thread(target=self._watch, name="vdbejax-stop-watchdog",
                                        daemon=True)
        self._thread.start()

    def _watch(self) -> None:
        while True:
            try:
                data = os.read(self._read, 1)
            except OSError:
                return
            if not data or self._done.is_set():
                return
            if data[0] not in (signal.SIGINT, signal.SIGTERM):
                continue
            if self._done.wait(self.grace):  # stopped (or finished) on its own
                return
            self._exit(143 if data[0] == signal.SIGTERM else 130)

    def _exit(self, code: int) -> None:
        self._exiting.acquire()  # kept: the process ends here
        if self._done.is_set():  # the main thread got there first
            self._exiting.release()
            return
        for release in list(_held.values()):
            with contextlib.suppress(Exception):  # the exit goes on
                release()
        try:
            message = self.message
            if callable(message):
                try:
                    message = message()
                except Exception:  # the exit goes on: what it says is secondary
                    message = "interrupted"
            sys.stderr.write(message + "\n")
            sys.stderr.flush()
            sys.stdout.flush()
        finally:
            os._exit(code)

    def disarm(self) -> None:
        """The main thread stops on its own from here on (it waits for an exit that has
        begun)."""
        with self._exiting:
            self._done.set()

    def stop(self) -> None:
        """The command is over: no exit from here on."""
        self.disarm()
        signal.set_wakeup_fd(self._previous)
        os.close(self._write)  # the thread reads the end of the pipe and returns
        self._thread.join(timeout=1.0)
        os.close(self._read)

