"""Command line: ``vdbejax reproduce --out DIR`` and friends.

Bad input prints one ``error: …`` line and exits with status 2 (no traceback).
"""
from __future__ import annotations

import argparse
import gc
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from vdbejax import __version__
from vdbejax.validation import parse_cli_number

if TYPE_CHECKING:
    from vdbejax.experiment import GridResult

#: ``vdbejax --help``'s description (plain text: argparse prints it as is).
DESCRIPTION = ("Exploration strategies in tabular RL: 'vdbejax reproduce --out DIR' reproduces"
               " Cruz et al. (2018), 'vdbejax run' runs any sweep.")


def _add_reproduce(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reproduce",
                       help="run the paper's full grid and write figure, summary, report")
    p.add_argument("--out", required=True, help="output folder")
    # Numbers are parsed leniently and checked by reproduce(): one clear error line.
    number = parse_cli_number
    p.add_argument("--seeds", type=number, default=20, help="agents per setting (default 20)")
    p.add_argument("--episodes", type=number, default=1000,
                   help="episodes per agent (default 1000)")
    p.add_argument("--seed", type=number, default=0, help="root random seed (default 0)")
    p.add_argument("--reading", default="textbook",
                   help="textbook (default: the paper's text, docs/task.md) or authors (the"
                        " first author's published code: its task table and agent details)")
    p.add_argument("--max-steps", type=number, default=None,
                   help="episode truncation length (default 100; authors: a safety cap of 10000)")
    p.add_argument("--invalid-action", default="noop", help="noop (default) or fail")
    p.add_argument("--tie-break", default=None,
                   help="random (default) or first (the authors' reading's default)")
    p.add_argument("--q-init", type=number, default=0.0, help="initial Q value (default 0)")
    p.add_argument("--chunk-episodes", type=number, default=100,
                   help="episodes per jitted chunk (default 100)")
    _add_run_flags(p, "continue from OUT/checkpoint.npz (or reuse OUT's whole result)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-figures", action="store_true",
                   help="no fig3.png / sensitivity.png ('vdbejax plot' draws them later)")
    p.add_argument("--long-csv", action="store_true",
                   help="also write returns_long.csv: one row per agent-episode (setting,"
                        " hyperparameters, seed, episode, return, length)")


def _add_run_flags(p: argparse.ArgumentParser, resume: str) -> None:
    """The flags of every command that trains: --resume, --devices, --memory-budget."""
    p.add_argument("--resume", action="store_true", help=resume)
    p.add_argument("--devices", type=parse_cli_number, default=None,
                   help="devices to shard the agents over (default: all)")
    p.add_argument("--memory-budget", default=None,
                   help="device memory per device for the agents, e.g. 512M, 2G (default: half"
                        " the free memory); agents that do not fit run in sequential batches")


def _run_flags(args: argparse.Namespace) -> dict[str, Any]:
    return {"resume": args.resume, "devices": args.devices,
            "memory_budget_bytes": args.memory_budget}


def _reproduce(args: argparse.Namespace) -> None:
    from vdbejax.paper.reproduce import reproduce

    if args.own_process:
        _freeze_imports()
    rep = reproduce(
        args.out, reading=args.reading, seeds=args.seeds, episodes=args.episodes, seed=args.seed,
        max_steps=args.max_steps, invalid_action=args.invalid_action, tie_break=args.tie_break,
        q_init=args.q_init, chunk_episodes=args.chunk_episodes, progress=not args.quiet,
        figures=not args.no_figures, **_run_flags(args),
    )
    for claim in rep.claims:
        print(f"claim {claim.number}: {claim.verdict}")
    if args.long_csv:
        print(_write_long_csv(rep.result, args.out))
    print(f"elapsed: {rep.elapsed_seconds:.1f} s"
          f" (training {rep.result.meta['elapsed_seconds']:.1f} s)")


def _add_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run", help="run any sweep (learners × explorers × hyperparameter axes) and write its"
                    " results, summary and figures",
        description="Flags override the sweep file's keys (vdbejax.sweeps lists them).")
    number = parse_cli_number
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--config", default=None, help="sweep file, TOML (.toml) or JSON")
    p.add_argument("--task", default=None,
                   help="table_cleaning (default), cruz2018 (the authors' published table) or"
                        " variant:NxK (N sections, K goblets)")
    p.add_argument("--learners", default=None, help="comma-separated, e.g. qlearning,sarsa")
    p.add_argument("--explorers", default=None, help="comma-separated, e.g. vdbe,ucb1")
    p.add_argument("--axis", action="append", default=[], metavar="NAME=V1,V2,...",
                   help="a sweep axis, e.g. --axis alpha=0.1,0.3,0.8 (repeatable)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a value shared by every setting that has it, e.g. --set gamma=0.95")
    p.add_argument("--plugin", action="append", default=[], metavar="FILE_OR_MODULE",
                   help="import this file or module first (it registers plug-ins)")
    p.add_argument("--seeds", type=number, default=None, help="agents per setting (default 20)")
    p.add_argument("--episodes", type=number, default=None,
                   help="episodes per agent (default 1000)")
    p.add_argument("--seed", type=number, default=None, help="root random seed (default 0)")
    p.add_argument("--max-steps", type=number, default=None,
                   help="episode truncation (default 100)")
    p.add_argument("--invalid-action", default=None, help="noop (default) or fail")
    p.add_argument("--chunk-episodes", type=number, default=None, help="episodes per jitted chunk")
    _add_run_flags(p, "continue from OUT/checkpoint.npz (or reuse OUT's whole result)")
    p.add_argument("--no-figures", action="store_true", help="no fig3.png / sensitivity.png")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--long-csv", action="store_true",
                   help="also write returns_long.csv: one row per agent-episode (setting,"
                        " hyperparameters, seed, episode, return, length)")


def _pairs(texts: list[str], flag: str) -> list[tuple[str, str]]:
    pairs = []
    for text in texts:
        name, sep, value = text.partition("=")
        if not sep or not name or not value:
            raise ValueError(f"{flag}={text!r} is invalid: must be NAME=VALUE")
        pairs.append((name, value))
    return pairs


def _value(text: str) -> object:
    if text in ("random", "first"):
        return text
    return parse_cli_number(text)


def _run(args: argparse.Namespace) -> None:
    from vdbejax.sweeps import read_sweep_file, run_sweep

    spec = read_sweep_file(args.config) if args.config else {}
    for key in ("task", "seeds", "episodes", "seed", "max_steps", "invalid_action",
                "chunk_episodes"):
        if getattr(args, key) is not None:
            spec[key] = getattr(args, key)
    for key in ("learners", "explorers"):
        if getattr(args, key) is not None:
            spec[key] = [name for name in getattr(args, key).split(",") if name]
    axes = dict(spec.get("axes", {}))
    axes.update({name: [_value(v) for v in values.split(",")]
                 for name, values in _pairs(args.axis, "--axis")})
    shared = dict(spec.get("shared", {}))
    shared.update({name: _value(value) for name, value in _pairs(args.set, "--set")})
    both = sorted(set(axes) & set(shared))
    if both:  # one would override the other without a word
        raise ValueError(f"{both[0]} is both a sweep axis and a shared value (--axis, --set or"
                         " the sweep file's [axes] and [shared]): give it once")
    spec["axes"], spec["shared"] = axes, shared
    spec["plugins"] = list(spec.get("plugins", [])) + args.plugin
    for key in ("learners", "explorers"):
        if key not in spec:
            raise ValueError(f"{key} is missing: give --{key} or a sweep file with {key} = [...]")
    result = run_sweep(args.out, progress=not args.quiet, figures=not args.no_figures,
                       **_run_flags(args), **spec)
    from vdbejax.summary import read_summary
    from vdbejax.sweeps import SUMMARY_FILE

    # summary.csv: one row per setting of this result, written by run_sweep above.
    rows = read_summary(Path(args.out) / SUMMARY_FILE)
    for row, setting in zip(rows, result.settings, strict=True):
        print(f"{setting.label}: final return {row.final_return:.3f}"
              f" [{row.final_ci_low:.3f}, {row.final_ci_high:.3f}]")
    print(f"training {result.meta['elapsed_seconds']:.1f} s → {args.out}")
    if args.long_csv:
        print(_write_long_csv(result, args.out))


def _add_plot(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plot",
                       help="redraw figures, summary and report from saved results (no training)")
    p.add_argument("--results", required=True,
                   help="folder with returns.npz, configs.csv, meta.json")
    p.add_argument("--out", default=None, help="output folder (default: the results folder)")
    p.add_argument("--bands", action="store_true", help="95%% bootstrap bands on Figure 3")
    p.add_argument("--long-csv", action="store_true",
                   help="also write returns_long.csv: one row per agent-episode")


def _plot(args: argparse.Namespace) -> None:
    from vdbejax.paper.reproduce import replot

    written = replot(args.results, args.out, bands=args.bands)
    if args.long_csv:
        from vdbejax.experiment import GridResult

        written.append(_write_long_csv(GridResult.load(args.results),
                                       args.results if args.out is None else args.out))
    for path in written:
        print(path)


def _write_long_csv(result: GridResult, out: str) -> Path:
    """``returns_long.csv`` of a result (GridResult.to_records) into ``out``."""
    from vdbejax import io

    path = Path(out) / io.LONG_CSV_FILE
    try:
        io.write_columns_csv(path, result.to_records())
    except OSError as error:
        raise ValueError(f"cannot write {str(path)!r}: {error.strerror or error}") from None
    return path


def _add_ablate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ablate",
                       help="claims scorecard across the spec's options; writes REPRODUCTION.md")
    p.add_argument("--out", required=True,
                   help="document folder: REPRODUCTION.md and ablation/<variant>/")
    p.add_argument("--results", default=None,
                   help="folder for the raw results of every variant (default: OUT/ablation)")
    p.add_argument("--seeds", type=parse_cli_number, default=20,
                   help="agents per setting (default 20)")
    p.add_argument("--episodes", type=parse_cli_number, default=1000,
                   help="episodes per agent (default 1000)")
    p.add_argument("--seed", type=parse_cli_number, default=0, help="root random seed (default 0)")
    p.add_argument("--variants", default=None,
                   help="comma-separated variant names"
                        " (default: all; see vdbejax.paper.ablation.VARIANTS)")
    p.add_argument("--notes", default=None,
                   help="a file of hand-written discussion appended to the document (this"
                        " repository's: docs/reproduction_notes.md)")
    p.add_argument("--rerun", action="store_true",
                   help="ignore saved results of the same variant and size")
    p.add_argument("--mode", default="options",
                   help="options (default: the two readings and the spec's open details,"
                        " REPRODUCTION.md), attribution (each detail of the authors' code"
                        " switched alone from either reading, ATTRIBUTION.md) or factorial"
                        " (failure update x goal update x alpha x initial Q from each reading,"
                        " FACTORIAL.md)")
    p.add_argument("--sections", action="store_true",
                   help="(options) also run the attribution and factorial variants and add"
                        " their claims tables to REPRODUCTION.md")
    _add_run_flags(p, "continue an interrupted variant from its checkpoint")
    p.add_argument("--quiet", action="store_true", help="no status lines")


def _ablate(args: argparse.Namespace) -> None:
    from vdbejax.paper.ablation import ablate, select_variants

    results = ablate(args.out, results_dir=args.results,
                     variants=select_variants(args.variants, args.mode), mode=args.mode,
                     sections=args.sections,
                     seeds=args.seeds, episodes=args.episodes, seed=args.seed, notes=args.notes,
                     reuse=not args.rerun, progress=not args.quiet, **_run_flags(args))
    for result in results:
        print(f"{result.variant.name}: "
              + ", ".join(f"{c.number} {c.verdict}" for c in result.claims))


def _add_scale(sub: argparse._SubParsersAction) -> None:
    # Nothing of vdbejax.scaling here: building the parser (--help, --version) must not
    # import JAX.
    p = sub.add_parser(
        "scale", help="episodes to solve of every exploration method on growing task variants;"
                      " writes scaling.csv, scaling.md, scaling.png",
        description="Each variant trains until every agent has solved it (20-episode moving"
                    " average >= fraction x the exact best return) or the budget is spent;"
                    " solved agents leave the batch.")
    number = parse_cli_number
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--sizes", default=None,
                   help="variants NxK (N sections, K goblets), comma-separated"
                        " (default: the study's, vdbejax.scaling.SIZES)")
    p.add_argument("--seeds", type=number, default=None, help="agents per setting (default 10)")
    p.add_argument("--episodes", type=number, default=None,
                   help="smallest episode budget per agent and variant (default 2000)")
    p.add_argument("--episodes-per-state", type=number, default=None,
                   help="budget per variant: max(EPISODES, this x reachable states)"
                        " (default 3; 0: EPISODES for every variant)")
    p.add_argument("--seconds", type=number, default=None,
                   help="wall-clock budget per variant (default none; machine-dependent)")
    p.add_argument("--seed", type=number, default=0, help="root random seed (default 0)")
    p.add_argument("--learners", default="qlearning,sarsa",
                   help="comma-separated (default qlearning,sarsa)")
    p.add_argument("--methods", default=None,
                   help="comma-separated explorers of vdbejax.scaling.METHODS (default all)")
    p.add_argument("--fraction", type=number, default=0.9,
                   help="solved = moving average >= fraction x best return (default 0.9)")
    p.add_argument("--window", type=number, default=20, help="moving-average window (default 20)")
    p.add_argument("--chunk-episodes", type=number, default=None,
                   help="episodes between stop checks (default max(100, budget/100))")
    p.add_argument("--max-steps", type=number, default=None,
                   help="episode truncation (default 100)")
    p.add_argument("--drop-unsolved", action="store_true",
                   help="skip a setting on larger variants once none of its agents solved one")
    p.add_argument("--quick", action="store_true", help="2x1 and 3x1, 3 seeds, 1000 episodes")
    p.add_argument("--no-figure", action="store_true", help="no scaling.png")
    p.add_argument("--no-runs", action="store_true",
                   help="do not keep the variants' result folders (runs/NxK/)")
    _add_run_flags(p, "continue an interrupted study: whole variants are loaded, the"
                      " interrupted one continues from runs/NxK/checkpoint.npz")
    p.add_argument("--quiet", action="store_true", help="no status lines")


#: ``vdbejax scale``'s sizes of the study, which ``--quick`` sets (flag: default).
SCALE_SIZE_FLAGS = {"sizes": None, "seeds": 10, "episodes": 2000, "episodes_per_state": 3.0}


def _scale(args: argparse.Namespace) -> None:
    from vdbejax.scaling import SIZES, run_scaling

    given = [name for name in SCALE_SIZE_FLAGS if getattr(args, name) is not None]
    if args.quick and given:  # --quick would override them without a word
        raise ValueError(f"--quick sets the study's size: leave out --{given[0].replace('_', '-')}"
                         " (or --quick)")
    for name, default in SCALE_SIZE_FLAGS.items():
        if getattr(args, name) is None:
            setattr(args, name, ",".join(SIZES) if name == "sizes" else default)

    learners = [n for n in args.learners.split(",") if n]
    methods = None if args.methods is None else args.methods.split(",")
    command = (f"vdbejax scale --out {args.out}" + (" --quick" if args.quick else
               f" --sizes {args.sizes} --seeds {args.seeds} --episodes {args.episodes}"
               f" --episodes-per-state {args.episodes_per_state}")
               + "".join(f" --{flag} {value}" for flag, value in (
                   ("seconds", args.seconds), ("seed", args.seed), ("learners", args.learners),
                   ("methods", args.methods), ("fraction", args.fraction), ("window", args.window),
                   ("chunk-episodes", args.chunk_episodes), ("max-steps", args.max_steps))
                   if value is not None)
               + (" --drop-unsolved" if args.drop_unsolved else ""))
    result = run_scaling(
        args.out, sizes=args.sizes, seeds=args.seeds, episodes=args.episodes,
        episodes_per_state=None if args.episodes_per_state == 0 else args.episodes_per_state,
        seconds=args.seconds,
        seed=args.seed, fraction=args.fraction, window=args.window,
        chunk_episodes=args.chunk_episodes, max_steps=args.max_steps,
        drop_unsolved=args.drop_unsolved, quick=args.quick, progress=not args.quiet,
        figure=not args.no_figure, save_runs=not args.no_runs, command=command,
        learners=learners, methods=methods, **_run_flags(args))
    for row in result.rows:
        print(f"{row['size']} {row['method']}: {row['median_text']}"
              f" ({row['solved']}/{row['agents']} solved)")
    print(f"elapsed: {result.meta['elapsed_seconds']:.1f} s → {args.out}")


COMMANDS = {
    "reproduce": (_add_reproduce, _reproduce),
    "run": (_add_run, _run),
    "plot": (_add_plot, _plot),
    "ablate": (_add_ablate, _ablate),
    "scale": (_add_scale, _scale),
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


def _freeze_imports() -> None:
    """Leave what the imports made (≈ a million objects, JAX's) out of the garbage
    collector's full passes: a command's run then spends no time re-scanning them
    (≈ 0.05 s per pass). Only when the command line is the process's own (``main()``
    without ``argv``): a caller's process, e.g. a test run, keeps its collector as it is."""
    gc.freeze()


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
                if args.command in ("reproduce", "run", "scale", "ablate") else "")
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


if __name__ == "__main__":
    sys.exit(main())
