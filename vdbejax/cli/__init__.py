"""Command line: ``vdbejax reproduce --out DIR`` and friends (one module per group of
commands: :mod:`~vdbejax.cli.paper_commands`, :mod:`~vdbejax.cli.study_commands`).

Bad input prints one ``error: …`` line and exits with status 2 (no traceback).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vdbejax import __version__
from vdbejax import _interrupts as interrupts
from vdbejax.cli.info_commands import (
    add_compare,
    add_export,
    add_list,
    compare_command,
    export_command,
    list_command,
)
from vdbejax.cli.paper_commands import (
    ablate_command,
    add_ablate,
    add_plot,
    add_reproduce,
    plot_command,
    reproduce_command,
)
from vdbejax.cli.study_commands import (
    add_bench,
    add_depth,
    add_run,
    add_scale,
    add_sweep_file,
    bench_command,
    depth_command,
    run_command,
    scale_command,
    sweep_file_command,
)
from vdbejax.results.io import CHECKPOINT_FILE, RETURNS_FILE

#: ``vdbejax --help``'s description (plain text: argparse prints it as is).
DESCRIPTION = ("Exploration strategies in tabular RL: 'vdbejax reproduce --out DIR' reproduces"
               " Cruz et al. (2018), 'vdbejax run' runs any sweep.")


COMMANDS = {
    "reproduce": (add_reproduce, reproduce_command),
    "run": (add_run, run_command),
    "sweep-file": (add_sweep_file, sweep_file_command),
    "plot": (add_plot, plot_command),
    "ablate": (add_ablate, ablate_command),
    "scale": (add_scale, scale_command),
    "bench": (add_bench, bench_command),
    "depth": (add_depth, depth_command),
    "list": (add_list, list_command),
    "compare": (add_compare, compare_command),
    "export": (add_export, export_command),
}


class _OneLineErrors(argparse.ArgumentParser):
    """argparse, but a usage error is one ``error: …`` line (exit 2), like a bad value."""

    def error(self, message: str) -> None:  # type: ignore[override]
        hint = " (a value that starts with '-' is written --option=VALUE)" if (
            "expected one argument" in message) else ""
        self.exit(2, f"error: {self.prog}: {message}{hint}\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``vdbejax`` parser: one subcommand per entry of :data:`COMMANDS`.

    Returns:
      a parser whose usage errors are one ``error: …`` line (exit 2).
    """
    parser = _OneLineErrors(prog="vdbejax", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"vdbejax {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineErrors)
    for add, _ in COMMANDS.values():
        add(sub)
    return parser




def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``vdbejax`` console script."""
    args = build_parser().parse_args(argv)
    args.own_process = argv is None
    # SIGTERM stops a command as Ctrl-C does, in the command line's own process only (a
    # caller's handlers are not replaced), and the previous handlers come back at the end.
    # Both are also recorded (vdbejax._interrupts), so that one swallowed inside a
    # garbage-collector callback still stops the run after its chunk.
    handled = args.own_process and threading.current_thread() is threading.main_thread()
    if not handled:  # a stop recorded before this command belongs to no command of it
        interrupts.clear()
    previous: dict[signal.Signals, Any] = {}
    watchdog = None
    shown = warnings.formatwarning
    warnings.formatwarning = _one_line_warning  # a warning is one line, as an error is
    try:  # from here on a stop is this command's: one line, exit 130 or 143
        if handled:
            # A stop during a long native call (a compilation, a chunk) would wait for it
            # to end: the watchdog ends the process a second after the signal instead.
            watchdog = interrupts.Watchdog(lambda: f"interrupted{_stop_hint(args)}")
            for number in (signal.SIGINT, signal.SIGTERM):
                if signal.getsignal(number) is not signal.SIG_IGN:  # ignored: kept so
                    previous[number] = signal.signal(number, _stop)
        interrupts.raise_pending()  # a stop while the command line imported (vdbejax._console)
        COMMANDS[args.command][1](args)
        interrupts.raise_pending()  # a stop that came after the last chunk
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, interrupts.Terminated) as stop:
        if watchdog is not None:
            watchdog.disarm()
        print(f"interrupted{_stop_hint(args)}", file=sys.stderr)
        code = 143 if isinstance(stop, interrupts.Terminated) else 130
        if handled:  # XLA's threads may still compile: tearing the interpreter down under
            sys.stdout.flush()  # them crashed it (rc −11) after the message
            sys.stderr.flush()
            os._exit(code)
        return code
    finally:
        if watchdog is not None:
            watchdog.stop()
        warnings.formatwarning = shown
        interrupts.clear()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str,
                      lineno: int, line: str | None = None) -> str:
    """A warning as the command line prints it: ``warning: …``, one line (no source)."""
    return f"warning: {' '.join(str(message).split())}\n"


def _stop_hint(args: argparse.Namespace) -> str:
    """What an interrupted command can still do (after "interrupted"): a rerun with
    ``--resume`` where its folder holds a checkpoint or a saved result, else nothing to
    resume."""
    if args.command not in ("reproduce", "run", "scale", "ablate", "bench", "depth"):
        return ""
    out = Path(args.out)
    if out.is_dir() and any(any(out.rglob(name)) for name in (CHECKPOINT_FILE, RETURNS_FILE)):
        return ": rerun with --resume to continue from the last checkpoint"
    return ": no checkpoint was written yet, a rerun starts from the beginning"


def _stop(signum: int, frame: Any) -> None:
    kind = interrupts.Terminated if signum == signal.SIGTERM else KeyboardInterrupt
    interrupts.request(kind)
    # In a gc or weakref callback Python would print it and go on; in an import it could
    # cross a native module's initialisation and abort the process; a folder lock being
    # taken would stay behind: recorded only, then.
    if not (interrupts.in_dropping_callback(frame) or interrupts.in_import(frame)
            or interrupts.deferring()):
        raise kind()
