"""What the commands share: the flags of every command that trains, the long CSV, and
the garbage collector's freeze of the command line's own process."""
from __future__ import annotations

import argparse
import gc
from pathlib import Path
from typing import Any

from vdbejax.validation import parse_cli_number


def add_run_flags(p: argparse.ArgumentParser, resume: str) -> None:
    """The flags of every command that trains: --resume, --overwrite, --devices,
    --memory-budget."""
    p.add_argument("--resume", action="store_true", help=resume)
    p.add_argument("--overwrite", action="store_true",
                   help="replace the finished results (or an interrupted run's checkpoint) the"
                        " output folder holds; without it that is refused")
    p.add_argument("--devices", type=parse_cli_number, default=None,
                   help="devices to shard the agents over (default: all)")
    p.add_argument("--memory-budget", default=None,
                   help="device memory per device for the agents, e.g. 512M, 2G (default: half"
                        " the free memory); agents that do not fit run in sequential batches")


def add_evaluate_flag(p: argparse.ArgumentParser, where: str) -> None:
    """``--evaluate-every K``: the exact value of each agent's greedy policy every K
    episodes (vdbejax.runs.evaluation); ``where``: what the command reports of it."""
    p.add_argument("--evaluate-every", type=parse_cli_number, default=None, metavar="K",
                   help="every K episodes, the exact expected return of each agent's greedy"
                        f" policy ({where}); the returns are the same")


def run_options(args: argparse.Namespace, **fields: Any) -> Any:
    """The :class:`~vdbejax.runs.RunOptions` of the run flags (``add_run_flags``) and
    ``fields``."""
    from vdbejax.runs.options import RunOptions  # here: building the parser imports no JAX

    return RunOptions(resume=args.resume, overwrite=args.overwrite, devices=args.devices,
                      memory_budget_bytes=args.memory_budget, **fields)


def write_long_csv(folder: str, out: str) -> list[Path]:
    """``--long-csv``: the returns table of the runs in ``folder`` as ``returns_long.csv``
    in ``out`` (:func:`vdbejax.results.export.export_results`, replacing an earlier one)."""
    from vdbejax.results.export import export_results

    return export_results(folder, out, tables=["returns"], overwrite=True)


def refuse_sizes_with_quick(quick: bool, given: list[str], what: str) -> None:
    """``--quick`` sets the study's size: refuse a size flag beside it (it would be
    overridden without a word). ``given``: the size options set, as attribute names."""
    if quick and given:
        raise ValueError(f"--quick sets the {what}'s size: leave out"
                         f" --{given[0].replace('_', '-')} (or --quick)")


def freeze_imports() -> None:
    """Leave what the imports made (≈ a million objects, JAX's) out of the garbage
    collector's full passes: a command's run then spends no time re-scanning them
    (≈ 0.05 s per pass). Only when the command line is the process's own (``main()``
    without ``argv``): a caller's process, e.g. a test run, keeps its collector as it is."""
    gc.freeze()


def size_values(args: argparse.Namespace, names: list[str], defaults: dict[str, Any],
                what: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """A study's size options: those given (refused beside ``--quick``) and their values,
    defaults filled in."""
    given = {name: getattr(args, name) for name in names}
    refuse_sizes_with_quick(args.quick, [k for k, v in given.items() if v is not None], what)
    return given, {k: (defaults.get(k) if v is None else v) for k, v in given.items()}
