"""report.md's verdicts, counts and intervals under both readings, pinned: whatever scores
the paper's claims (today vdbejax.paper.claims on vdbejax.results.verdicts), the report
keeps every verdict, check count, replicate count and interval it had when pinned
(``paper_report_pinned.json``, written by the code before the claims became data; the
checks' wording may change, their numbers may not). A small grid: 4 agents × 3
replicates × 300 episodes per setting."""
from __future__ import annotations

import json
import re
from pathlib import Path

import jax
import pytest

import vdbejax
from vdbejax.runs import RunOptions

PINNED = json.loads((Path(__file__).parent / "paper_report_pinned.json").read_text())
INTERVAL = re.compile(r"\[[^\[\]]*?, [^\[\]]*?\]")


def scored(report: str) -> dict:
    """The verdicts, counts and intervals of a report.md, not its wording."""
    table = [line for line in report.splitlines() if re.match(r"^\| \d+ \|", line)]
    titles = re.findall(r"^## Claim (\d+): (.*)$", report, re.M)
    checks = [[m.group(1), INTERVAL.findall(m.group(2)), m.group(3) or ""]
              for m in re.finditer(r"^  - (\[.\]) (.*?)( — holds in .*)?$", report, re.M)]
    return {"table": table, "titles": [list(t) for t in titles], "checks": checks}


@pytest.mark.skipif(jax.default_backend() != "cpu",
                    reason="the pinned numbers are the CPU backend's")
@pytest.mark.parametrize("reading", sorted(PINNED))
def test_report_keeps_its_verdicts_counts_and_intervals(tmp_path, reading):
    vdbejax.reproduce(tmp_path, reading=reading, seeds=4, episodes=300, replicates=3,
                      figures=False, run=RunOptions(progress=False))
    now = scored((tmp_path / "report.md").read_text())
    assert now["table"] == PINNED[reading]["table"]
    assert now["titles"] == PINNED[reading]["titles"]
    assert now["checks"] == PINNED[reading]["checks"]
