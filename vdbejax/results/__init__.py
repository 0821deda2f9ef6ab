"""Results: what a run produced, its files and its statistics (numpy; nothing here trains).

* :mod:`~vdbejax.results.grid_result` — :class:`GridResult`, a grid's returns, lengths and
  settings, saved to and loaded from a result folder;
* :mod:`~vdbejax.results.io` — the result files (atomic writes, ``returns.npz``,
  ``configs.csv``, ``meta.json``);
* :mod:`~vdbejax.results.folder_lock` — one run's files per folder: writer lock, run marker,
  leftover cleanup;
* :mod:`~vdbejax.results.stats`, :mod:`~vdbejax.results.curves`,
  :mod:`~vdbejax.results.bootstrap` — curve statistics and bootstrap intervals over seeds;
* :mod:`~vdbejax.results.solving` — episodes to solve (a censored measure);
* :mod:`~vdbejax.results.summary`, :mod:`~vdbejax.results.analysis` — the summary table
  and comparisons of a grid;
* :mod:`~vdbejax.results.verdicts`, :mod:`~vdbejax.results.claim_spec`,
  :mod:`~vdbejax.results.claim_scoring`, :mod:`~vdbejax.results.claim_report` — claims
  as data, decided by intervals, and their reports;
* :mod:`~vdbejax.results.plotting` — figures.
"""

#: The public names: the modules of a grid's result, its statistics, tables and figures
#: (each imported when first named: ``from vdbejax.results import plotting``).
__all__ = [
    "analysis",
    "bootstrap",
    "claim_report",
    "claim_scoring",
    "claim_spec",
    "compare",
    "curves",
    "export",
    "grid_result",
    "markdown",
    "optimal_actions",
    "plotting",
    "policy",
    "regret",
    "solving",
    "stats",
    "summary",
    "verdicts",
]
