"""The ``vdbejax`` console script (and ``python -m vdbejax``).

It records Ctrl-C and SIGTERM from its first line (:mod:`vdbejax._interrupts`), before the
command line and its imports load, so that a stop while they import ends the command with
"interrupted" (exit 130 or 143) rather than Python's KeyboardInterrupt traceback; the
command line's own handlers take over once it runs (:func:`vdbejax.cli.main`). Only this
module and :mod:`vdbejax`'s light package module run before the handlers are in place.
"""
from __future__ import annotations

import signal
from typing import Any

from vdbejax import _interrupts


def _record(signum: int, frame: Any) -> None:
    _interrupts.request(_interrupts.Terminated if signum == signal.SIGTERM
                        else KeyboardInterrupt)


def main() -> int:
    """Run the command line of this process (``sys.argv``); returns its exit code."""
    for number in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(number) is not signal.SIG_IGN:  # ignored by the parent: kept so
            signal.signal(number, _record)  # (a background job of a script, nohup)
    from vdbejax import cli  # a stop while this imports is recorded, and ends the command

    return cli.main()
