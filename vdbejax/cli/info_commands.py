"""Commands that read only: ``list`` (what there is to run) and ``compare`` (two result
folders side by side)."""
from __future__ import annotations

import argparse
import json


def add_list(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("list", help="list the learners, explorers and tasks with their"
                                    " parameters and defaults")
    p.add_argument("kinds", nargs="*", metavar="KIND",
                   help="what to list: learners, explorers, tasks (default: all)")
    p.add_argument("--plugin", action="append", default=[],
                   help="a plug-in file or module to import first (its methods are listed too)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")


def list_command(args: argparse.Namespace) -> None:
    from vdbejax.studies.catalog import KINDS, catalog, render_catalog
    from vdbejax.studies.task_names import load_plugins

    load_plugins(args.plugin)
    entries = catalog(args.kinds or KINDS)
    print(json.dumps(entries, indent=2, default=repr) if args.json else render_catalog(entries),
          end="\n" if args.json else "")


def add_compare(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="two result folders' settings side by side, with"
                                       " intervals")
    p.add_argument("a", metavar="A", help="a result folder")
    p.add_argument("b", metavar="B", help="another result folder")
    p.add_argument("--csv", default=None, help="also write the comparison as CSV to this file")
    p.add_argument("--different-tasks", action="store_true",
                   help="compare folders of different tasks (or instance families); without"
                        " it that is refused")


def compare_command(args: argparse.Namespace) -> None:
    from vdbejax.results import io
    from vdbejax.results.compare import compare_folders, render_comparison

    table = compare_folders(args.a, args.b, different_tasks=args.different_tasks)
    print(render_comparison(table, args.a, args.b), end="")
    if args.csv:
        try:
            io.write_csv(args.csv, table, list(table[0]) if table else ["setting"])
        except OSError as error:
            raise ValueError(f"cannot write {args.csv!r}: {error.strerror or error}") from None


def add_export(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export", help="any result folder's returns, summaries, policy evaluations and claims"
                       " as long tables (CSV, or Parquet with pyarrow)",
        description="Every run in FOLDER (and below it) as returns_long, summaries_long,"
                    " evaluations_long and claims_long tables: one row per setting × agent ×"
                    " episode, per setting, per setting × agent × evaluation, per claim ×"
                    " check (docs/analysis.md).")
    p.add_argument("folder", metavar="FOLDER",
                   help="a result folder: what run, reproduce, bench, depth, scale or ablate wrote")
    p.add_argument("--format", default="csv", help="csv (default) or parquet (needs pyarrow)")
    p.add_argument("--out", default=None, help="the folder to write into (default: FOLDER)")
    p.add_argument("--tables", default=None,
                   help="comma-separated: returns, summaries, evaluations, claims (default: all)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the tables an earlier export wrote there")


def export_command(args: argparse.Namespace) -> None:
    from vdbejax.results.export import TABLE_FILES, export_results

    tables = (tuple(TABLE_FILES) if args.tables is None
              else [name for name in args.tables.split(",") if name])
    for path in export_results(args.folder, args.out, format=args.format, tables=tables,
                               overwrite=args.overwrite):
        print(path)
