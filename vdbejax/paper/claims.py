"""The paper's six claims (spec, last section), as data: ``claims.toml`` beside this module,
in the format of every study's claims (:mod:`vdbejax.results.claim_spec`, ``docs/claims.md``),
scored by the same code (:mod:`vdbejax.results.claim_scoring`) and rules
(:mod:`vdbejax.results.verdicts`); :mod:`vdbejax.paper.report` writes them into
``report.md``.
"""
from __future__ import annotations

import functools
from pathlib import Path

from vdbejax.results.claim_spec import ClaimSpec, parse_claims
from vdbejax.studies.sweep_file import read_claims_file

#: The paper's claims file (package data).
CLAIMS_FILE = Path(__file__).with_name("claims.toml")


@functools.cache
def paper_claims() -> tuple[ClaimSpec, ...]:
    """The paper's six claims, read from :data:`CLAIMS_FILE`.

    Raises:
      ValueError: a malformed file (one line naming the claim and the field).
    """
    return parse_claims(read_claims_file(CLAIMS_FILE))


__all__ = ["CLAIMS_FILE", "paper_claims"]
