"""Command line: ``vdbejax reproduce --out DIR`` and friends (one module per group of
commands: :mod:`~vdbejax.cli.paper_commands`, :mod:`~vdbejax.cli.study_commands`).

Bad input prints one ``error: …`` line and exits with status 2 (no traceback).
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence

from vdbejax import __version__
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
    add_run,
    add_scale,
    add_sweep_file,
    bench_command,
    run_command,
    scale_command,
    sweep_file_command,
)

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
    # caller's handler is not replaced), and the previous handler comes back at the end.
    previous = (signal.signal(signal.SIGTERM, _terminate)
                if args.own_process and threading.current_thread() is threading.main_thread()
                else None)
    try:
        COMMANDS[args.command][1](args)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, _Terminated) as stop:
        hint = (": rerun with --resume to continue from the last checkpoint"
                if args.command in ("reproduce", "run", "scale", "ablate", "bench") else "")
        print(f"interrupted{hint}", file=sys.stderr)
        return 143 if isinstance(stop, _Terminated) else 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


class _Terminated(BaseException):
    """SIGTERM, raised where the process is, so that pending writes clean up after
    themselves (a temporary file is removed, a checkpoint is whole or absent)."""


def _terminate(signum: int, frame: object) -> None:
    raise _Terminated()

