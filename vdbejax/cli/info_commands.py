"""Commands that read only: ``list`` (what there is to run)."""
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
