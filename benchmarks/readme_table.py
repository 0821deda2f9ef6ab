"""The README's performance table, generated from the benchmark harness's output.

    python -m benchmarks.readme_table            # rewrite README.md's table block
    python -m benchmarks.readme_table --check    # exit 1 if the block is out of date

``python -m benchmarks.compare --out benchmarks/RESULTS.md`` writes the harness's results;
this script copies their headline into README.md, between the markers
``<!-- benchmark-table:start -->`` and ``<!-- benchmark-table:end -->``, so that the README
states no performance number by hand: the full-grid section's title, the run's date and
machine, the warm rows of vdbejax and of the Numba peers (``numba-2t``, ``numba-1t``) with
their wall, compile and run times, and the ratio lines (peer wall / vdbejax wall); then
the table of the section ``## Par with numba-2t`` (``python -m benchmarks.par``: a call
repeated in one process) with its date, commit and machine. Every cell and line is copied
as the results file has it; only columns are left out.
``tests/test_docs.py`` checks that README.md's block is what this module generates.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "RESULTS.md"
README = ROOT / "README.md"

START = "<!-- benchmark-table:start -->"
END = "<!-- benchmark-table:end -->"

#: The columns of the harness's full-grid table that the README shows, in this order.
COLUMNS = ("peer", "threads", "wall s", "compile s", "run s", "M steps/s", "curves agree")

_SECTION = "## Full paper grid"
_PAR = "## Par with numba-2t"
_RATIOS = "Ratios ("
_NUMBA_WARM = re.compile(r"^numba-\d+t \(warm\b")


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def _header_value(lines: list[str], key: str) -> str:
    prefix = f"- {key}: "
    for line in lines:
        if line.startswith(prefix):
            return line[len(prefix):].rstrip(".").strip()
    raise ValueError(f"benchmarks/RESULTS.md: no '{prefix.strip()}' line in its header")


def _section(lines: list[str], heading: str) -> tuple[int, int]:
    """Where the section whose heading starts with ``heading`` begins (its heading line)
    and ends (the next ``## `` heading, or the end)."""
    try:
        start = next(i for i, line in enumerate(lines) if line.startswith(heading))
    except StopIteration:
        raise ValueError(f"benchmarks/RESULTS.md: no '{heading}' section") from None
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")),
               len(lines))
    return start, end


def headline(results: str) -> str:
    """The README block's content (without the markers) from the text of RESULTS.md.

    Raises ``ValueError`` naming what is missing when the text is not the harness's output
    (no full-grid section, table, vdbejax warm row or ratio lines).
    """
    lines = results.splitlines()
    start, end = _section(lines, _SECTION)
    section = lines[start:end]
    title = section[0].removeprefix("## ").strip()
    date = _header_value(lines[:start], "Date")
    # the machine without its platform string (kernel and libc): CPU, cores, memory, GPU
    fields = _header_value(lines[:start], "Machine").split("; ")
    machine = "; ".join(fields[1:] or fields)

    table = [line for line in section if line.startswith("|")]
    if len(table) < 3:
        raise ValueError("benchmarks/RESULTS.md: the full-grid section has no table")
    header = _cells(table[0])
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise ValueError(f"benchmarks/RESULTS.md: the full-grid table has no column {missing}")
    index = [header.index(c) for c in COLUMNS]
    rows = [_cells(line) for line in table[2:]]
    vdbejax = [r for r in rows if r[0].startswith("vdbejax ") and "(warm" in r[0]]
    if not vdbejax:
        raise ValueError("benchmarks/RESULTS.md: the full-grid table has no vdbejax warm row")
    chosen = [vdbejax[0], *(r for r in rows if _NUMBA_WARM.match(r[0]))]

    try:
        at = next(i for i, line in enumerate(section) if line.startswith(_RATIOS))
    except StopIteration:
        raise ValueError("benchmarks/RESULTS.md: the full-grid section has no ratio lines") \
            from None
    bullets = []
    for line in section[at + 1:]:
        if line.startswith("- "):
            bullets.append(line)
        elif bullets and not line.strip():
            break
    ratios = [line for line in bullets if "/ vdbejax" in line]

    out = [f"{title}, from [`benchmarks/RESULTS.md`](benchmarks/RESULTS.md) "
           f"({date}; {machine}). Fresh process against fresh process: each peer in a "
           "subprocess of its own, caches warm, interpreter start and imports excluded:", "",
           "| " + " | ".join(COLUMNS) + " |",
           "| " + " | ".join("---" for _ in COLUMNS) + " |"]
    out += ["| " + " | ".join(row[i] for i in index) + " |" for row in chosen]
    out += ["", section[at].strip(), "", *ratios]
    return "\n".join([*out, "", *_par(lines)])


def _par(lines: list[str]) -> list[str]:
    """The par section's table, after a line saying when, where and what it compares."""
    start, end = _section(lines, _PAR)
    section = lines[start + 1:end]
    table = []
    for line in section:
        if line.startswith("|"):
            table.append(line)
        elif table:
            break
    if len(table) < 3:
        raise ValueError("benchmarks/RESULTS.md: the par section has no table")
    facts = "; ".join([_header_value(section, "Date"), "commit " + _header_value(section,
                       "Commit"), _header_value(section, "Machine")])
    return [f"A call repeated in one process, `python -m benchmarks.par` ({facts}): the first "
            "row is vdbejax's second `run_grid` call in one process against numba-2t's "
            "harness worker (one call in a fresh process, loading its compiled loop from "
            "Numba's cache included); the third, fresh process against fresh process:", "",
            *table]


def block(results_path: Path = RESULTS) -> str:
    """The whole block, markers included, generated from ``results_path``."""
    text = Path(results_path).read_text(encoding="utf-8")
    return "\n".join([START, "<!-- generated by `python -m benchmarks.readme_table` from "
                      "benchmarks/RESULTS.md: do not edit by hand -->",
                      headline(text), "", END])


def current_block(readme: str) -> str:
    """The block between the markers (markers included) of a README's text."""
    start, end = readme.find(START), readme.find(END)
    if start < 0 or end < start:
        raise ValueError(f"README.md: no '{START}' … '{END}' block")
    return readme[start:end + len(END)]


def update_readme(readme_path: Path = README, results_path: Path = RESULTS) -> bool:
    """Rewrite the block of ``readme_path`` from ``results_path``; ``True`` if it changed."""
    readme_path = Path(readme_path)
    text = readme_path.read_text(encoding="utf-8")
    old = current_block(text)
    new = block(results_path)
    if old == new:
        return False
    readme_path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=RESULTS,
                        help="the harness's output (default: benchmarks/RESULTS.md)")
    parser.add_argument("--readme", type=Path, default=README,
                        help="the file whose block to rewrite (default: README.md)")
    parser.add_argument("--check", action="store_true",
                        help="change nothing; exit 1 if the block is out of date")
    args = parser.parse_args(argv)
    try:
        if args.check:
            stale = current_block(args.readme.read_text(encoding="utf-8")) != block(args.results)
            print(f"{args.readme}: benchmark table {'out of date' if stale else 'up to date'}")
            return 1 if stale else 0
        changed = update_readme(args.readme, args.results)
    except (OSError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"{args.readme}: benchmark table {'updated' if changed else 'already up to date'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
