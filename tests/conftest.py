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


#: The test files that take longest on an empty JAX cache (``.ci/run``'s ``--file-durations``
#: report), slowest first. Under pytest-xdist they are handed out first (``.ci/run`` passes
#: ``--dist loadfile --no-loadscope-reorder``: files in the order collected, each to the
#: next free worker), so a run does not end with one worker on a long file while the other
#: idles: the files handed out last are the short ones.
SLOW_FIRST = ("tests/test_canon.py", "tests/test_examples_run.py", "tests/test_notebooks.py",
              "tests/test_builtin_methods.py", "tests/test_sharding.py",
              "tests/test_task_instances.py", "tests/test_engine_perf_invariants.py",
              "tests/test_lockstep_loop.py", "tests/test_ablation.py",
              "tests/test_mixed_kinds.py")


def slow_files_first(nodeids: list[str]) -> list[int]:
    """The order of the test ids ``nodeids`` that starts with the files of
    :data:`SLOW_FIRST` (in its order), then every other file as collected; a file's tests
    keep their order (a stable sort)."""
    rank = {path: i for i, path in enumerate(SLOW_FIRST)}
    return sorted(range(len(nodeids)),
                  key=lambda i: rank.get(nodeids[i].split("::", 1)[0], len(rank)))


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config,
                                  items: list[pytest.Item]) -> None:
    if hasattr(config, "workerinput"):  # a pytest-xdist worker: its collection is the queue
        items[:] = [items[i] for i in slow_files_first([item.nodeid for item in items])]


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
