"""Checks, on loading, of the optional records a run keeps beside its returns in
``returns.npz``: the policy evaluations (``policy_values``), the fractions of optimal
actions (``optimal_actions``) and the episodes the step limit cut (``truncated``). Each
problem is one line naming the file."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.results import io


def check_policy_values(path: Path, meta: dict[str, Any], returns: np.ndarray,
                        policy_values: np.ndarray | None) -> None:
    """One-line errors for policy evaluations that cannot belong to the saved run."""
    if policy_values is None:
        return
    every = meta.get("evaluate_every")
    if not isinstance(every, int) or every < 1 or not isinstance(
            meta.get("optimal_return"), (int, float)) or not isinstance(
            meta.get("optimal_tolerance"), (int, float)):
        raise ValueError(f"results file {str(path)!r} does not match {io.META_FILE}: it holds"
                         " policy_values, meta.json lacks evaluate_every, optimal_return or"
                         " optimal_tolerance")
    wanted = (*returns.shape[:2], returns.shape[2] // every)
    if policy_values.shape != wanted or not np.issubdtype(policy_values.dtype, np.floating):
        raise ValueError(f"results file {str(path)!r} is damaged: policy_values must be float"
                         f" {list(wanted)}, not {policy_values.dtype} {list(policy_values.shape)}")


def check_optimal_actions(path: Path, returns: np.ndarray, lengths: np.ndarray,
                          optimal_actions: np.ndarray | None) -> None:
    """One-line errors for fractions of optimal actions that cannot belong to the saved
    run: float like ``returns``, in [0, 1] for every episode run, NaN for the others."""
    if optimal_actions is None:
        return
    if optimal_actions.shape != returns.shape or not np.issubdtype(optimal_actions.dtype,
                                                                   np.floating):
        raise ValueError(f"results file {str(path)!r} is damaged: optimal_actions must be float"
                         f" {list(returns.shape)}, not {optimal_actions.dtype}"
                         f" {list(optimal_actions.shape)}")
    ran = lengths > 0
    values = optimal_actions[ran]
    if not (np.isfinite(values) & (values >= 0) & (values <= 1)).all() or not np.isnan(
            optimal_actions[~ran]).all():
        raise ValueError(f"results file {str(path)!r} is damaged: optimal_actions must lie in"
                         " [0, 1] for every episode run and be NaN for the others")


def check_truncated(path: Path, meta: dict[str, Any], lengths: np.ndarray,
                    truncated: np.ndarray | None) -> None:
    """One-line errors for cut flags that cannot belong to the saved run: bool like
    ``lengths``, set only on episodes of ``meta["max_steps"]`` steps (where recorded)."""
    if truncated is None:
        return
    if truncated.shape != lengths.shape or truncated.dtype != np.bool_:
        raise ValueError(f"results file {str(path)!r} is damaged: truncated must be bool"
                         f" {list(lengths.shape)}, not {truncated.dtype} {list(truncated.shape)}")
    max_steps = meta.get("max_steps")
    limit = max_steps if isinstance(max_steps, int) else None
    if truncated.any() and ((lengths[truncated] < 1).any() or (
            limit is not None and (lengths[truncated] != limit).any())):
        raise ValueError(f"results file {str(path)!r} is damaged: truncated marks an episode"
                         f" that did not last max_steps={limit} steps")
