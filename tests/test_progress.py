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
    assert len(lines) == 11 and lines[-1].startswith("[" + "#" * 24 + "] 100.0%")


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
