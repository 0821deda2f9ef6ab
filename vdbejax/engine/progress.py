"""Progress of a run as users expect it: a rate and an ETA; on a terminal one bar redrawn
in place; in a pipe or log plain lines (no carriage returns), one per tenth of the run or
per half minute; in a Jupyter notebook one line updated in place (no stderr block per
chunk). No dependency: the conventions of ``tqdm.auto``, in a few lines.

The run's first report comes before anything is compiled and says so ("compiling"); the
first chunk's time includes compiling the programs (seconds to tens of seconds in a cold
process), so the rate and the ETA are measured from the end of the first chunk on (the
warm-up), never from the start.
"""
from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any

#: ``progress(done, total, elapsed_seconds)``, ``done`` and ``total`` in agent-episodes.
ProgressCallback = Callable[[int, int, float], None]
#: Shortest time between two redraws of a bar (terminal, notebook).
REDRAW_SECONDS = 0.1
#: Longest time between two lines in a pipe or log.
LOG_SECONDS = 30.0


def format_progress(done: int, total: int, elapsed: float, width: int = 24, *,
                    rate: float | None = None, status: str | None = None) -> str:
    """``[#####.......]  42.0%  386,400/920,000 agent-episodes  210k/s  ETA 0:02``.

    Args:
      done, total: agent-episodes.
      elapsed: seconds since the start.
      width: the bar's characters.
      rate: agent-episodes per second for the ETA (default: ``done / elapsed``).
      status: shown instead of the rate and ETA (``compiling …``, ``warming up …``).
    """
    fraction = done / total if total > 0 else 1.0
    filled = int(width * min(max(fraction, 0.0), 1.0))
    head = (f"[{'#' * filled}{'.' * (width - filled)}] {100 * fraction:5.1f}%  "
            f"{done:,}/{total:,} agent-episodes")
    if done >= total:
        overall = done / elapsed if elapsed > 0 else 0.0
        return f"{head}  {_rate(overall)}/s  in {_clock(elapsed)}"
    if status is not None:
        return f"{head}  {status}"
    rate = (done / elapsed if elapsed > 0 else 0.0) if rate is None else rate
    eta = f"ETA {_clock((total - done) / rate)}" if rate > 0 else "ETA ?"
    return f"{head}  {_rate(rate)}/s  {eta}"


class _Meter:
    """What a display shows at each report: "compiling" before the first chunk, then the
    rate and ETA measured from the end of the first chunk (which includes compiling)."""

    def __init__(self) -> None:
        self.start: int | None = None                 # done at the first report (resumed)
        self.warm: tuple[int, float] | None = None    # done and elapsed at the first chunk

    def text(self, done: int, total: int, elapsed: float) -> str:
        if self.start is None:
            self.start = done
        if self.warm is None and done == self.start:
            return format_progress(done, total, elapsed,
                                   status="compiling the programs (first chunk) …")
        if self.warm is None:
            self.warm = (done, elapsed)
            return format_progress(done, total, elapsed, status=(
                f"first chunk in {_clock(elapsed)} (compiling included)  ETA ?"))
        ran, seconds = done - self.warm[0], elapsed - self.warm[1]
        return format_progress(done, total, elapsed,
                               rate=ran / seconds if seconds > 0 and ran > 0 else 0.0)


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))  # noqa: RUF046  (a NumPy float's round is a float in NumPy 1)
    hours, rest = divmod(seconds, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"


def _rate(rate: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if rate >= scale:
            return f"{rate / scale:.1f}{unit}"
    return f"{rate:.0f}"


def text_progress(stream: Any = None, *, clock: Callable[[], float] = time.monotonic
                  ) -> ProgressCallback:
    """A progress display for :func:`~vdbejax.runs.grid.run_grid` and the engine.

    Args:
      stream: where to write (default: a notebook's display when running in Jupyter,
        else ``sys.stderr``). A terminal gets one bar redrawn in place, anything else
        plain lines.
      clock: the time source that paces the redraws (tests pass their own).

    Returns:
      the :data:`ProgressCallback`.
    """
    if stream is None and "ipykernel" in sys.modules:
        notebook = _notebook_display()
        if notebook is not None:
            return notebook
    stream = sys.stderr if stream is None else stream
    interactive = bool(getattr(stream, "isatty", lambda: False)())
    last = {"time": -float("inf"), "tenth": -1}
    meter = _Meter()

    def show(done: int, total: int, elapsed: float) -> None:
        now = clock()
        finished = done >= total
        phase_changes = meter.warm is None  # the compile status and the first chunk: shown
        text = meter.text(done, total, elapsed)
        if interactive:
            if finished or phase_changes or now - last["time"] >= REDRAW_SECONDS:
                stream.write("\r\033[K" + text + ("\n" if finished else ""))
                stream.flush()
                last["time"] = now
            return
        tenth = int(10 * done / total) if total > 0 else 10
        if (finished or phase_changes or tenth > last["tenth"]
                or now - last["time"] >= LOG_SECONDS):
            stream.write(text + "\n")
            stream.flush()
            last["time"], last["tenth"] = now, tenth

    return show


def _notebook_display() -> ProgressCallback | None:
    """One output line of the running notebook cell, updated in place."""
    try:
        from IPython.display import display
    except ImportError:
        return None
    handle: dict[str, Any] = {"display": None, "time": -float("inf")}
    meter = _Meter()

    def show(done: int, total: int, elapsed: float) -> None:
        now = time.monotonic()
        phase_changes = meter.warm is None
        line = meter.text(done, total, elapsed)
        if done < total and not phase_changes and now - handle["time"] < REDRAW_SECONDS:
            return
        text = _PlainText(line)
        if handle["display"] is None:
            handle["display"] = display(text, display_id=True)
        else:
            handle["display"].update(text)
        handle["time"] = now

    return show


class _PlainText:
    """An object IPython shows as plain text (no quotes, as a ``str`` would get)."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text
