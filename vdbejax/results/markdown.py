"""Markdown tables: the one writer of every table the package prints (``report.md``,
``REPRODUCTION.md``, ``bench.md``, ``depth.md``, ``scaling.md``, ``vdbejax compare`` and
:func:`vdbejax.results.analysis.markdown_table`).

A table is a header line, an alignment line of ``---`` per column, then one line per row;
every line is ``| cell | cell |``. Cells are written as given: the callers format them.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence


def table_lines(header: Sequence[str], rows: Iterable[Sequence[str]] = ()) -> list[str]:
    """A markdown table as lines (without a trailing newline).

    Args:
      header: the column titles.
      rows: the rows, each a sequence of cell texts (as many as ``header``).

    Returns:
      the header line, the alignment line and one line per row.
    """
    return [_line(header), _line(["---"] * len(header)), *(_line(row) for row in rows)]


def _line(cells: Iterable[str]) -> str:
    return "| " + " | ".join(cells) + " |"


__all__ = ["table_lines"]
