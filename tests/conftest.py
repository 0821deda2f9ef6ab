"""Settings of the test session itself."""
from __future__ import annotations

import signal

import pytest


def pytest_configure(config: pytest.Config) -> None:
    # A launcher that ignores SIGINT (a background job of a non-interactive shell, nohup)
    # hands that on to every process it starts, and Python keeps it ignored: the tests that
    # stop a command with Ctrl-C would watch it run to its end. The session's own
    # processes start as a terminal's would, Ctrl-C at its default (a caught signal is
    # reset to the default in a started program).
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
