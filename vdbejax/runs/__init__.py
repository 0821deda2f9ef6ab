"""The one run path: every command that trains goes through it.

* :mod:`~vdbejax.runs.options` — :class:`RunOptions`, the engine's knobs in one frozen
  object, checked when made;
* :mod:`~vdbejax.runs.stop` — stop policies: :class:`FixedBudget`, :class:`UntilSolved`;
* :mod:`~vdbejax.runs.plan` — :class:`RunPlan`: devices, processes, batches, strategy
  (stated in ``meta.json``);
* :mod:`~vdbejax.runs.run_state` — :class:`RunState`, the one resume state (what a checkpoint
  stores);
* :mod:`~vdbejax.runs.driver` — :func:`drive`, the loop over batches and chunks and its
  stages (record, stop, checkpoint, progress);
* :mod:`~vdbejax.runs.evaluation` — the exact value of every agent's greedy policy every
  ``evaluate_every`` episodes;
* :mod:`~vdbejax.runs.optimal_record` — the per-episode fraction of optimal actions
  (``record_optimal``);
* :mod:`~vdbejax.runs.grid` — :func:`run_grid` = :func:`prepare_grid` + :func:`run_prepared`.
"""
from vdbejax.runs.driver import Drive, drive
from vdbejax.runs.grid import PreparedGrid, grid_agents, prepare_grid, run_grid, run_prepared
from vdbejax.runs.options import RunOptions
from vdbejax.runs.plan import RunPlan, make_plan
from vdbejax.runs.run_state import RunState
from vdbejax.runs.stop import FixedBudget, StopPolicy, UntilSolved

__all__ = [
    "Drive",
    "FixedBudget",
    "PreparedGrid",
    "RunOptions",
    "RunPlan",
    "RunState",
    "StopPolicy",
    "UntilSolved",
    "drive",
    "grid_agents",
    "make_plan",
    "prepare_grid",
    "run_grid",
    "run_prepared",
]
