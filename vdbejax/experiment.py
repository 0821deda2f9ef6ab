"""Grid runs and their results: the names most scripts import.

:func:`run_grid` lives in :mod:`vdbejax.runs.grid` (the one run path: options, plan,
driver, stop policies, checkpoints; the versions it records: :mod:`vdbejax.runs.provenance`)
and :class:`GridResult` in :mod:`vdbejax.results.grid_result`; both, and the helpers below,
are importable from here as before.
"""
from __future__ import annotations

from vdbejax.results.grid_result import GridResult
from vdbejax.runs.grid import (
    PreparedGrid,
    grid_agents,
    prepare_grid,
    run_grid,
    run_prepared,
)
from vdbejax.runs.options import RunOptions
from vdbejax.runs.provenance import git_commit, version_info
from vdbejax.runs.state import nonfinite_message

__all__ = [
    "GridResult",
    "PreparedGrid",
    "RunOptions",
    "git_commit",
    "grid_agents",
    "nonfinite_message",
    "prepare_grid",
    "run_grid",
    "run_prepared",
    "version_info",
]
