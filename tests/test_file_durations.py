"""The per-file time report that ``.ci/run`` prints at its end (``--file-durations N``,
tests/conftest.py): the N test files whose tests took longest, their seconds summed; and
the order in which pytest-xdist hands the files out (the slowest first)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).parent


def _pytest(folder: Path, *args: str) -> str:
    path = os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])
    env = dict(os.environ, PYTHONPATH=path)
    done = subprocess.run([sys.executable, "-m", "pytest", str(folder), "-p", "conftest",
                           "-p", "no:cacheprovider", "-q", "--rootdir", str(folder), *args],
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def test_the_slowest_files_are_printed_slowest_first_with_their_summed_seconds(tmp_path):
    (tmp_path / "test_slow.py").write_text(
        "import time\n\ndef test_a():\n    time.sleep(0.4)\n\ndef test_b():\n    time.sleep(0.4)\n")
    (tmp_path / "test_middle.py").write_text("import time\n\ndef test_c():\n    time.sleep(0.3)\n")
    (tmp_path / "test_fast.py").write_text("def test_d():\n    pass\n")
    out = _pytest(tmp_path, "--file-durations", "2")
    report = out[out.index("slowest 2 test files"):].splitlines()[1:4]
    assert [line.split()[1] for line in report] == ["test_slow.py", "test_middle.py", "all"]
    seconds = [float(line.split()[0].rstrip("s")) for line in report]
    assert seconds[0] >= 0.8 and 0.3 <= seconds[1] < seconds[0]  # both tests of the file
    assert "3 files" in report[2] and seconds[2] >= seconds[0] + seconds[1]
    assert "slowest" not in _pytest(tmp_path)  # off unless asked for


def test_the_slowest_files_are_handed_out_first():
    from conftest import SLOW_FIRST, slow_files_first

    root = TESTS.parent
    assert all((root / path).is_file() for path in SLOW_FIRST), SLOW_FIRST
    assert len(set(SLOW_FIRST)) == len(SLOW_FIRST)
    ids = ["tests/test_a.py::x", "tests/test_notebooks.py::n1", "tests/test_b.py::y",
           "tests/test_canon.py::c1", "tests/test_notebooks.py::n2", "tests/test_canon.py::c2"]
    order = [ids[i] for i in slow_files_first(ids)]
    assert order == ["tests/test_canon.py::c1", "tests/test_canon.py::c2",
                     "tests/test_notebooks.py::n1", "tests/test_notebooks.py::n2",
                     "tests/test_a.py::x", "tests/test_b.py::y"]


def test_xdist_workers_run_the_slowest_files_first(tmp_path):
    """Under ``-n 1 --dist loadfile --no-loadscope-reorder`` (.ci/run's options, one
    worker): a file of SLOW_FIRST runs before the files collected ahead of it."""
    tests = tmp_path / "tests"
    tests.mkdir()
    log = tmp_path / "order.txt"
    for name in ("test_a.py", "test_canon.py", "test_zz.py"):
        (tests / name).write_text(f"def test_it():\n    open({str(log)!r}, 'a').write("
                                  f"{name!r} + '\\n')\n")
    _pytest(tests, "--rootdir", str(tmp_path), "-n", "1", "--dist", "loadfile",
            "--no-loadscope-reorder")
    assert log.read_text().split() == ["test_canon.py", "test_a.py", "test_zz.py"]
