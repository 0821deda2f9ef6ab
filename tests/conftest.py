"""Settings of the test session itself, and the per-file time report (``--file-durations``)."""
from __future__ import annotations

import signal
from collections import defaultdict

import pytest

#: Seconds per test file (setup, call and teardown of its tests, module fixtures included),
#: gathered where the reports arrive (the controller, under pytest-xdist).
_FILE_SECONDS: defaultdict[str, float] = defaultdict(float)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--file-durations", type=int, default=0, metavar="N",
                     help="print the N slowest test files (their tests' time summed; 0: none)")


def pytest_configure(config: pytest.Config) -> None:
    # A launcher that ignores SIGINT (a background job of a non-interactive shell, nohup)
    # hands that on to every process it starts, and Python keeps it ignored: the tests that
    # stop a command with Ctrl-C would watch it run to its end. The session's own
    # processes start as a terminal's would, Ctrl-C at its default (a caught signal is
    # reset to the default in a started program).
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _FILE_SECONDS[report.nodeid.split("::", 1)[0]] += report.duration


def slowest_files(seconds: dict[str, float], count: int) -> list[str]:
    """The report's lines: the ``count`` files with the most seconds, slowest first."""
    ranked = sorted(seconds.items(), key=lambda item: (-item[1], item[0]))[:count]
    return [f"{total:8.1f}s  {path}" for path, total in ranked]


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter,
                            config: pytest.Config) -> None:
    count = config.getoption("--file-durations")
    if count <= 0 or not _FILE_SECONDS:
        return
    terminalreporter.write_sep("=", f"slowest {count} test files")
    for line in slowest_files(_FILE_SECONDS, count):
        terminalreporter.write_line(line)
    terminalreporter.write_line(f"{sum(_FILE_SECONDS.values()):8.1f}s  all "
                                f"{len(_FILE_SECONDS)} files (summed over workers)")
