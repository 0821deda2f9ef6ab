"""What the agents have learned: statistics of their greedy policies' exact values.

A run with ``evaluate_every=K`` (:mod:`vdbejax.runs.evaluation`) keeps, beside the
returns, the exact expected return ``V^π`` of every agent's greedy policy after every
K-th episode (``GridResult.policy_values``). From them:

* the **policy gap** ``V* − V^π`` of every agent and evaluation (0: the greedy policy is
  as good as the optimum; :func:`policy_gaps`), and per setting its mean over the
  agents with a 95 % bootstrap interval (:func:`policy_summary`);
* the **fraction of agents whose greedy policy is optimal** (gap within
  ``meta["optimal_tolerance"]``), with its Wilson interval.

A setting's numbers are those of each agent's last evaluation (an agent stopped early by
a stop policy: its last evaluation before the stop). Unlike the regret of realized
returns (:mod:`vdbejax.results.regret`), which samples the behaviour policy, exploration
included, and can be negative by luck, the gap is exact and never negative (up to
float32 rounding): it measures the policy an agent would exploit, not what its
exploring episodes earned.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from vdbejax.results.bootstrap import bootstrap_ci
from vdbejax.results.grid_result import GridResult
from vdbejax.results.stats import wilson_interval

#: ``summary.csv``'s columns of a run with policy evaluations.
POLICY_COLUMNS = ["policy_gap", "policy_gap_ci_low", "policy_gap_ci_high", "optimal_fraction",
                  "optimal_ci_low", "optimal_ci_high"]


def policy_gaps(result: GridResult) -> np.ndarray:
    """float64 ``[configs, seeds, evaluations]``: ``V* − V^π`` of every agent's greedy
    policy at every evaluation (NaN where none was taken).

    Raises:
      ValueError: the result has no policy evaluations (``evaluate_every``).
    """
    if result.policy_values is None:
        raise ValueError("this result has no policy evaluations: run it with"
                         " evaluate_every=K (CLI --evaluate-every K)")
    return float(result.meta["optimal_return"]) - result.policy_values.astype(np.float64)


def optimal_agents(result: GridResult) -> np.ndarray:
    """float64 ``[configs, seeds, evaluations]``: 1 where the agent's greedy policy is
    optimal (gap ≤ ``meta["optimal_tolerance"]``), 0 where not, NaN where not evaluated."""
    gaps = policy_gaps(result)
    optimal = (gaps <= float(result.meta["optimal_tolerance"])).astype(np.float64)
    return np.where(np.isnan(gaps), np.nan, optimal)


def last_evaluations(result: GridResult, values: np.ndarray) -> np.ndarray:
    """``[configs, seeds]``: each agent's entry of ``values`` (``[configs, seeds,
    evaluations]``) at its last evaluation (before its stop, for an agent a stop policy
    stopped; NaN where it has none)."""
    episodes = result.evaluation_episodes
    ran = (np.full(values.shape[:2], result.num_episodes) if result.episodes_run is None
           else result.episodes_run)
    last = np.searchsorted(episodes, ran, side="right") - 1  # index of the last ≤ ran
    taken = np.take_along_axis(values, np.maximum(last, 0)[..., None], axis=-1)[..., 0]
    return np.where(last >= 0, taken, np.nan)


def policy_summary(result: GridResult) -> list[dict[str, Any]]:
    """Per setting, from every agent's last evaluation: ``policy_gap`` (mean ``V* − V^π``)
    with its 95 % bootstrap interval over the agents, and ``optimal_fraction`` (agents
    whose greedy policy is optimal) with its Wilson interval (columns
    :data:`POLICY_COLUMNS`; NaN where no agent was evaluated).

    Raises:
      ValueError: the result has no policy evaluations.
    """
    gaps = last_evaluations(result, policy_gaps(result))
    optimal = last_evaluations(result, optimal_agents(result))
    rows = []
    for c in range(len(result.settings)):
        evaluated = ~np.isnan(gaps[c])
        row = dict.fromkeys(POLICY_COLUMNS, float("nan"))
        if evaluated.any():
            low, high = (bootstrap_ci(gaps[c, evaluated]) if evaluated.sum() > 1
                         else (float(gaps[c, evaluated][0]),) * 2)
            count = int(optimal[c, evaluated].sum())
            row.update(policy_gap=float(gaps[c, evaluated].mean()), policy_gap_ci_low=low,
                       policy_gap_ci_high=high, optimal_fraction=count / int(evaluated.sum()))
            row["optimal_ci_low"], row["optimal_ci_high"] = wilson_interval(
                count, int(evaluated.sum()))
        rows.append(row)
    return rows


def policy_gap_figure(result: GridResult) -> Any:
    """Mean policy gap ``V* − V^π`` of each setting's agents at every evaluation, with the
    range of the middle half of its agents (a matplotlib ``Figure``)."""
    import matplotlib.pyplot as plt

    episodes = result.evaluation_episodes
    gaps = policy_gaps(result)
    figure, axes = plt.subplots(figsize=(7, 4.5))
    for c, setting in enumerate(result.settings):
        evaluated = ~np.isnan(gaps[c])  # agents stopped early are not evaluated after
        count = evaluated.sum(0)
        mean = np.where(count > 0, np.where(evaluated, gaps[c], 0.0).sum(0)
                        / np.maximum(count, 1), np.nan)
        line, = axes.plot(episodes, mean, marker="o", markersize=3, label=setting.label)
        if result.num_seeds > 1 and evaluated.all():
            low, high = np.percentile(gaps[c], [25, 75], axis=0)
            axes.fill_between(episodes, low, high, color=line.get_color(), alpha=0.15)
    axes.axhline(0.0, color="black", linewidth=0.8)
    axes.set_xlabel("episode")
    axes.set_ylabel("V* − V^π of the greedy policy")
    optimum = float(result.meta["optimal_return"])
    axes.set_title(f"Learned policy's gap to the optimum (V* = {optimum:.4g})")
    axes.legend(fontsize=7)
    figure.tight_layout()
    return figure
