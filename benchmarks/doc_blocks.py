"""Tables of the docs pages, copied from the results files: no measured number by hand.

    python -m benchmarks.doc_blocks            # rewrite every block of docs/*.md
    python -m benchmarks.doc_blocks --check    # exit 1 if a block is out of date

A page marks where a table of a results file goes (the file relative to the repository
root, then the start of a section's heading, of any level)::

    <!-- results: benchmarks/RESULTS.md | Full paper grid -->
    <!-- results:end -->

(``| table 2`` after the section: its second table) and this module writes between the
two lines the first table of that section, verbatim, after one line naming the file and
the section and saying when and where it was measured: the section's own ``- Date:``,
``- Commit:`` and ``- Machine:`` lines, or else the file's header lines (those before its
first section) where the heading has no date of its own. ``tests/test_docs.py`` fails
when a block differs from what the results files give.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"

MARK = re.compile(r"^<!-- results: (?P<file>[^|]+?) \| (?P<section>[^|]+?)"
                  r"(?: \| table (?P<number>\d+))? -->$")
END = "<!-- results:end -->"
_YEAR = re.compile(r"\b20\d\d\b")


def _header_value(lines: list[str], key: str) -> str | None:
    prefix = f"- {key}: "
    return next((line[len(prefix):].rstrip(".").strip() for line in lines
                 if line.startswith(prefix)), None)


def table(results: str, section: str, name: str = "the results file", number: int = 1) -> str:
    """The block for table ``number`` of ``section`` of a results file's text (without the
    marker lines).

    Raises:
      ValueError: no heading starts with ``section``, or its section has fewer tables.
    """
    lines = results.splitlines()
    headings = [i for i, line in enumerate(lines) if line.startswith("#")]
    try:
        start = next(i for i in headings if lines[i].lstrip("#").strip().startswith(section))
    except StopIteration:
        raise ValueError(f"{name}: no section whose heading starts with {section!r}") from None
    level = len(lines[start]) - len(lines[start].lstrip("#"))
    end = next((i for i in headings if i > start
                and len(lines[i]) - len(lines[i].lstrip("#")) <= level), len(lines))
    tables: list[list[str]] = []
    previous = ""
    for line in lines[start + 1:end]:
        if line.startswith("|"):
            if not previous.startswith("|"):
                tables.append([])
            tables[-1].append(line.rstrip())
        previous = line
    tables = [rows for rows in tables if len(rows) >= 3]
    if len(tables) < number:
        raise ValueError(f"{name}: section {section!r} has {len(tables)} table(s), not"
                         f" {number}")
    rows = tables[number - 1]
    heading = lines[start].lstrip("#").strip()
    source = f"From `{name}`, “{heading}”"
    facts = {key: value for key in ("Date", "Commit", "Machine")
             if (value := _header_value(lines[start + 1:end], key)) is not None}
    if not facts and not _YEAR.search(heading):
        header = lines[:next((i for i in headings if lines[i].startswith("## ")), start)]
        facts = {key: value for key in ("Date", "Machine")
                 if (value := _header_value(header, key)) is not None}
    if "Commit" in facts:
        facts["Commit"] = f"commit {facts['Commit']}"
    if facts.get("Machine", "").startswith(("Linux", "macOS", "Windows")):
        # the machine without its platform string (kernel and libc), as the README's table
        facts["Machine"] = "; ".join(facts["Machine"].split("; ")[1:])
    if facts:
        source += f" ({'; '.join(facts.values())})"
    return "\n".join([source + ":", "", *rows])


def render(page: str, root: Path = ROOT) -> str:
    """``page``'s text with every block rewritten from its results file."""
    out: list[str] = []
    lines = page.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        out.append(line)
        match = MARK.match(line.strip())
        i += 1
        if not match:
            continue
        try:
            close = next(j for j in range(i, len(lines)) if lines[j].strip() == END)
        except StopIteration:
            raise ValueError(f"a block {line.strip()!r} has no {END!r} line") from None
        name = match["file"].strip()
        text = (root / name).read_text(encoding="utf-8")
        out += [table(text, match["section"].strip(), name, int(match["number"] or 1)), END]
        i = close + 1
    return "\n".join(out) + ("\n" if page.endswith("\n") else "")


def pages(docs: Path = DOCS) -> list[Path]:
    """The docs pages holding at least one block."""
    return sorted(p for p in docs.rglob("*.md")
                  if any(MARK.match(line.strip()) for line in p.read_text("utf-8").splitlines()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 if a block is out of date")
    args = parser.parse_args(argv)
    stale = []
    try:
        for path in pages():
            old = path.read_text(encoding="utf-8")
            new = render(old)
            if new != old:
                stale.append(path.relative_to(ROOT).as_posix())
                if not args.check:
                    path.write_text(new, encoding="utf-8")
    except (OSError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    verb = "out of date" if args.check else "rewritten"
    print(f"{verb}: {', '.join(stale)}" if stale else "every results block is up to date")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
