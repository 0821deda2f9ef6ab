"""The paper's commands: ``reproduce``, ``plot`` and ``ablate``."""
from __future__ import annotations

import argparse

from vdbejax.cli.common import add_run_flags, freeze_imports, run_options, write_long_csv
from vdbejax.validation import parse_cli_number


def add_reproduce(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reproduce",
                       help="run the paper's full grid and write figure, summary, report")
    p.add_argument("--out", required=True, help="output folder")
    # Numbers are parsed leniently and checked by reproduce(): one clear error line.
    number = parse_cli_number
    p.add_argument("--seeds", type=number, default=20,
                   help="agents per setting and replicate (default 20)")
    p.add_argument("--replicates", type=number, default=5,
                   help="independent groups of SEEDS agents, each scored alone and pooled"
                        " (default 5; 1: a single run's files)")
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
    p.add_argument("--chunk-episodes", type=number, default=None,
                   help="episodes per jitted chunk (default: at least 100 and 20,000"
                        " agent-episodes, at most 10,000)")
    add_run_flags(p, "continue from OUT/checkpoint.npz (or reuse OUT's whole result)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-figures", action="store_true",
                   help="no fig3.png / sensitivity.png ('vdbejax plot' draws them later)")
    p.add_argument("--long-csv", action="store_true",
                   help="also write returns_long.csv: one row per agent-episode (setting,"
                        " hyperparameters, seed, episode, return, length)")


def reproduce_command(args: argparse.Namespace) -> None:
    from vdbejax.paper.reproduce import reading_options, reproduce

    if args.own_process:
        freeze_imports()
    rep = reproduce(
        args.out, reading=args.reading, seeds=args.seeds, episodes=args.episodes, seed=args.seed,
        replicates=args.replicates, max_steps=args.max_steps,
        invalid_action=args.invalid_action,
        options=reading_options(args.reading, args.tie_break, q_init=args.q_init),
        figures=not args.no_figures,
        run=run_options(args, chunk_episodes=args.chunk_episodes, progress=not args.quiet),
    )
    for claim in rep.claims:
        print(f"claim {claim.number}: {claim.verdict}")
    if args.long_csv:
        print(*write_long_csv(args.out, args.out), sep="\n")
    print(f"elapsed: {rep.elapsed_seconds:.1f} s"
          f" (training {rep.result.meta['elapsed_seconds']:.1f} s)")


def add_plot(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plot",
                       help="redraw figures, summary and report from saved results (no training)")
    p.add_argument("--results", required=True,
                   help="folder with returns.npz, configs.csv, meta.json")
    p.add_argument("--out", default=None, help="output folder (default: the results folder)")
    p.add_argument("--bands", action=argparse.BooleanOptionalAction, default=True,
                   help="95%% bootstrap bands on Figure 3 (default: on, the figure reproduce and"
                        " run draw)")
    p.add_argument("--long-csv", action="store_true",
                   help="also write returns_long.csv: one row per agent-episode")
    p.add_argument("--claims", default=None, metavar="FILE",
                   help="score the claims of FILE (TOML or JSON: claims = [...], docs/claims.md)"
                        " into claims.md and claims.csv (default: those the run stated)")


def plot_command(args: argparse.Namespace) -> None:
    from vdbejax.paper.reproduce import replot

    written = replot(args.results, args.out, bands=args.bands, claims=args.claims)
    if args.long_csv:
        written += write_long_csv(args.results, args.results if args.out is None else args.out)
    for path in written:
        print(path)


def add_ablate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("ablate",
                       help="claims scorecard across the spec's options; writes"
                            " ablation_scorecard.md")
    p.add_argument("--out", required=True,
                   help="document folder: ablation_scorecard.md and ablation/<variant>/")
    p.add_argument("--results", default=None,
                   help="folder for the raw results of every variant (default: OUT/ablation)")
    p.add_argument("--seeds", type=parse_cli_number, default=20,
                   help="agents per setting and replicate (default 20)")
    p.add_argument("--replicates", type=parse_cli_number, default=5,
                   help="independent groups of SEEDS agents per variant (default 5)")
    p.add_argument("--episodes", type=parse_cli_number, default=1000,
                   help="episodes per agent (default 1000)")
    p.add_argument("--seed", type=parse_cli_number, default=0, help="root random seed (default 0)")
    p.add_argument("--variants", default=None,
                   help="comma-separated variant names"
                        " (default: all; see vdbejax.paper.ablation_variants.VARIANTS)")
    p.add_argument("--notes", default=None,
                   help="a file of hand-written discussion appended to the document (this"
                        " repository's: docs/ablation_notes.md)")
    p.add_argument("--rerun", action="store_true",
                   help="ignore saved results of the same variant and size")
    p.add_argument("--mode", default="options",
                   help="options (default: the two readings and the spec's open details,"
                        " ablation_scorecard.md), attribution (each detail of the authors' code"
                        " switched alone from either reading, ATTRIBUTION.md) or factorial"
                        " (failure update x goal update x alpha x initial Q from each reading,"
                        " FACTORIAL.md)")
    p.add_argument("--sections", action="store_true",
                   help="(options) also run the attribution and factorial variants and add"
                        " their claims tables to ablation_scorecard.md")
    add_run_flags(p, "continue an interrupted variant from its checkpoint")
    p.add_argument("--quiet", action="store_true", help="no status lines")


def ablate_command(args: argparse.Namespace) -> None:
    from vdbejax.paper.ablation import ablate
    from vdbejax.paper.ablation_variants import select_variants

    results = ablate(args.out, results_dir=args.results,
                     variants=select_variants(args.variants, args.mode), mode=args.mode,
                     sections=args.sections,
                     seeds=args.seeds, episodes=args.episodes, seed=args.seed,
                     replicates=args.replicates, notes=args.notes,
                     reuse=not args.rerun, run=run_options(args, progress=not args.quiet))
    for result in results:
        print(f"{result.variant.name}: "
              + ", ".join(f"{c.number} {c.verdict}" for c in result.claims))
