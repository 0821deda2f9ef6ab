"""Progress display: rate and ETA; in place on a terminal, plain lines in a pipe, one
updating line in a notebook."""
from __future__ import annotations

import io
import sys
import types

from vdbejax.engine import progress


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_format_shows_rate_eta_and_counts():
    line = progress.format_progress(250, 1000, 2.0)
    assert "25.0%" in line and "250/1,000 agent-episodes" in line and "125/s" in line
    assert "ETA 0:06" in line
    assert "in 0:04" in progress.format_progress(1000, 1000, 4.0)
    assert "1.5M/s" in progress.format_progress(3_000_000, 9_000_000, 2.0)


def test_a_pipe_gets_plain_lines_one_per_tenth():
    stream, clock = io.StringIO(), FakeClock()
    show = progress.text_progress(stream, clock=clock)
    for done in range(0, 1001, 10):  # 101 chunks
        clock.now += 0.01
        show(done, 1000, clock.now)
    text = stream.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    # The start (compiling), the first chunk (warm-up), then one line per tenth.
    assert len(lines) == 12 and lines[-1].startswith("[" + "#" * 24 + "] 100.0%")
    assert "compiling" in lines[0] and "first chunk in" in lines[1]


def test_a_pipe_gets_a_line_every_half_minute_of_a_slow_run():
    stream, clock = io.StringIO(), FakeClock()
    show = progress.text_progress(stream, clock=clock)
    for done in range(0, 50):  # never crosses a tenth after the first
        clock.now += 10.0
        show(done, 1000, clock.now)
    assert 15 <= len(stream.getvalue().splitlines()) <= 18


def test_a_terminal_redraws_in_place_at_most_ten_times_a_second():
    stream, clock = Terminal(), FakeClock()
    show = progress.text_progress(stream, clock=clock)
    for done in range(0, 1001):
        clock.now += 0.001  # 1000 calls in one second
        show(done, 1000, clock.now)
    text = stream.getvalue()
    assert text.count("\n") == 1 and text.endswith("\n")
    assert 9 <= text.count("\r") <= 12


def test_the_eta_is_measured_after_the_first_chunk_which_includes_compiling():
    stream, clock = io.StringIO(), FakeClock()
    show = progress.text_progress(stream, clock=clock)
    show(0, 1000, 0.0)
    clock.now = 20.0  # 20 s compiling, then 1 s per tenth of the run
    for done in range(100, 1001, 100):
        show(done, 1000, clock.now)
        clock.now += 1.0
    lines = stream.getvalue().splitlines()
    assert "compiling the programs" in lines[0] and "ETA" not in lines[0]
    assert "first chunk in 0:20 (compiling included)  ETA ?" in lines[1]
    # At 20 %: 800 agent-episodes left at 100/s, not at the 200 / 21 s of the whole run.
    assert lines[2].startswith("[" + "#" * 4) and "100/s  ETA 0:08" in lines[2]
    assert "ETA 0:01" in lines[-2] and lines[-1].endswith("in 0:29")


def test_a_resumed_run_says_compiling_until_its_first_chunk():
    stream, clock = io.StringIO(), FakeClock()
    show = progress.text_progress(stream, clock=clock)
    show(500, 1000, 0.0)  # resumed halfway: still to compile
    clock.now = 5.0
    show(600, 1000, 5.0)
    clock.now = 6.0
    show(700, 1000, 6.0)
    lines = stream.getvalue().splitlines()
    assert "50.0%" in lines[0] and "compiling" in lines[0]
    assert "first chunk in 0:05" in lines[1] and "100/s  ETA 0:03" in lines[2]


def test_a_notebook_gets_one_line_updated_in_place(monkeypatch):
    shown = []

    class Handle:
        def update(self, obj):
            shown.append(("update", repr(obj)))

    def display(obj, display_id=False):
        shown.append(("display", repr(obj)))
        return Handle()

    fake = types.ModuleType("IPython.display")
    fake.display = display
    monkeypatch.setitem(sys.modules, "IPython.display", fake)
    monkeypatch.setitem(sys.modules, "IPython", types.ModuleType("IPython"))
    monkeypatch.setitem(sys.modules, "ipykernel", types.ModuleType("ipykernel"))
    show = progress.text_progress()
    show(0, 10, 0.0)
    show(10, 10, 1.0)
    assert [kind for kind, _ in shown] == ["display", "update"]
    assert "100.0%" in shown[-1][1]
