"""Statistics of a grid (:class:`~vdbejax.results.grid_result.GridResult`): the summary table,
pairwise comparisons, truncation diagnostics and ε(s) snapshots.

The array-level statistics and their conventions (smoothing, final return, bootstrap
intervals, IQM, probability of improvement) live in :mod:`vdbejax.results.stats`,
:mod:`vdbejax.results.curves` and :mod:`vdbejax.results.bootstrap`; the convergence
episode (against the task's optimum, per agent, and its censored median per setting) in
:mod:`vdbejax.results.solving`.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from vdbejax.results.bootstrap import probability_of_improvement_ci
from vdbejax.results.curves import LAST, WINDOW, final_return
from vdbejax.results.grid_result import GridResult
from vdbejax.results.markdown import table_lines
from vdbejax.results.optimal_actions import OPTIMAL_ACTION_COLUMNS, optimal_action_summary
from vdbejax.results.policy import POLICY_COLUMNS, policy_summary
from vdbejax.results.regret import Scale, as_scale
from vdbejax.results.solving import episodes_to_converge, summarize_solving
from vdbejax.results.stats import CurveStatistics, curve_statistics
from vdbejax.results.summary import SUMMARY_COLUMNS, SummaryRow


def truncated_episodes(result: GridResult) -> np.ndarray | None:
    """bool ``[configs, seeds, episodes]``: the episodes the step limit cut (their
    ``max_steps``-th step was not terminal).

    The run's own record (:attr:`GridResult.truncated`, which the engine sets where a step
    is truncated). A folder written before that record: every episode of ``max_steps``
    steps (an upper bound where an episode can also end on its own at its last allowed
    step), none where its ``meta.json`` says the step limit never cuts
    (``"step_limit_cuts": "never"``, a one-pull bandit); ``None`` where ``meta.json``
    lacks ``max_steps``.
    """
    if result.truncated is not None:
        return np.asarray(result.truncated, bool)
    max_steps = result.meta.get("max_steps")
    if max_steps is None:
        return None
    if result.meta.get("step_limit_cuts") == "never":
        return np.zeros(result.lengths.shape, bool)
    return np.asarray(result.lengths) >= int(max_steps)


def truncated_fraction(result: GridResult, last: int = LAST) -> np.ndarray:
    """float64 ``[configs, seeds]``: the fraction of each agent's last ``last`` episodes
    the step limit cut (:func:`truncated_episodes`; NaN where that is unknown).

    An agent stuck in a loop (e.g. SARSA + VDBE with all actions valued ≈ −0.1) shows up
    as a fraction near 1.
    """
    cut = truncated_episodes(result)
    if cut is None:
        return np.full(result.lengths.shape[:2], np.nan)
    return cut[..., -last:].mean(-1)


def task_scale(result: GridResult, best: Scale | None = None,
               baseline: Scale | None = None) -> tuple[Scale, Scale]:
    """The task's exact best return and the uniformly random policy's expected return:
    those given, else ``meta.json``'s ``best_return`` and ``random_return`` — or, for a
    run that gave every agent its own task instance (:mod:`vdbejax.runs.task_family_run`), each
    agent's own instance's, float64 ``[seeds, 1]`` (``instance_best_returns``,
    ``instance_random_returns``; ``[configs, seeds, 1]`` where the configs' task values
    differ, :func:`config_scale` picks a config's): each agent is scored against its
    instance.

    Raises:
      ValueError: one of them is neither given nor recorded.
    """
    meta = result.meta
    if best is None and baseline is None and "instance_best_returns" in meta:
        return (np.asarray(meta["instance_best_returns"], np.float64)[..., None],
                np.asarray(meta["instance_random_returns"], np.float64)[..., None])
    best = meta.get("best_return") if best is None else best
    baseline = meta.get("random_return") if baseline is None else baseline
    if best is None or baseline is None:
        raise ValueError("the result's meta has no best_return and random_return: the"
                         " convergence episode needs the task's exact best return and the"
                         " random policy's (vdbejax.envs.solvers.best_return,"
                         " uniform_random_return); pass best= and baseline=")
    return as_scale(best), as_scale(baseline)


def config_scale(scale: Scale, config: int) -> Scale:
    """Config ``config``'s references of a :func:`task_scale` (one per config where the
    configs' task values differ, else the same for every config)."""
    return np.asarray(scale)[config] if np.ndim(scale) == 3 else scale


def summarize(
    result: GridResult, last: int = LAST, window: int = WINDOW,
    statistics: CurveStatistics | None = None, best: Scale | None = None,
    baseline: Scale | None = None,
) -> list[SummaryRow]:
    """One row per config: final return with its 95% bootstrap CI over agents, the
    convergence episode (:func:`~vdbejax.results.solving.episodes_to_converge`: the median
    over agents with censoring, and its interval) and diagnostics
    (:class:`~vdbejax.results.summary.SummaryRow`).

    Args:
      result: the grid.
      last: episodes defining the final return.
      window: moving-average window of the convergence criterion.
      statistics: :func:`curve_statistics` of ``result.returns`` already computed (with
        this ``last`` and ``window``), e.g. to share them with Figure 3.
      best, baseline: the task's exact best return and the random policy's expected
        return (default: :func:`task_scale`, from ``result.meta``).

    Returns:
      one :class:`~vdbejax.results.summary.SummaryRow` per setting, in config order (the columns
      of :data:`SUMMARY_COLUMNS`: ``config, learner, explorer, param, final_return,
      final_ci_low, final_ci_high, final_iqm, convergence_episode, convergence_ci_low,
      convergence_ci_high, agents_converged, convergence_budget, truncated_fraction,
      mean_length, nonfinite_agents``; with
      ``episodes_cut`` and ``agents_cut`` for a task whose step limit is only a safety cap;
      the policy columns of :func:`~vdbejax.results.policy.policy_summary` for a run with
      policy evaluations; the columns of
      :func:`~vdbejax.results.optimal_actions.optimal_action_summary` over the same
      ``last`` episodes for a run that records optimal actions).
    """
    last = min(last, result.num_episodes)
    if statistics is None:
        statistics = curve_statistics(result.returns, window, last)
    elif ((statistics.window, statistics.last) != (window, last)
          or len(statistics.final) != len(result.settings)):
        raise ValueError(f"statistics (window={statistics.window}, last={statistics.last}, "
                         f"{len(statistics.final)} settings) do not match window={window}, "
                         f"last={last} and the grid's {len(result.settings)} settings")
    best, baseline = task_scale(result, best, baseline)
    cut = truncated_episodes(result)
    fractions = truncated_fraction(result, last)
    policy = (policy_summary(result) if result.policy_values is not None
              else [{}] * len(result.settings))
    optimal = (optimal_action_summary(result, last) if result.optimal_actions is not None
               else [{}] * len(result.settings))
    rows = []
    for c, setting in enumerate(result.settings):
        episodes, solved = _convergence_times(result, c, config_scale(best, c),
                                              config_scale(baseline, c), window)
        convergence = summarize_solving(episodes, solved)
        episodes_cut = agents_cut = None
        if result.meta.get("step_cap") and cut is not None:  # no step limit: cut at its cap
            episodes_cut, agents_cut = int(cut[c].sum()), int(cut[c].any(-1).sum())
        rows.append(SummaryRow(
            config=c,
            learner=setting.learner,
            explorer=setting.explorer,
            param=setting.param,
            hyperparameters=setting.hyperparameters_json(),
            final_return=float(statistics.final[c]),
            final_ci_low=float(statistics.final_low[c]),
            final_ci_high=float(statistics.final_high[c]),
            final_iqm=float(statistics.final_iqm[c]),
            convergence_episode=convergence.median,
            convergence_ci_low=convergence.median_low,
            convergence_ci_high=convergence.median_high,
            agents_converged=convergence.solved,
            convergence_budget=(convergence.budget if convergence.solved < convergence.agents
                                else result.num_episodes),
            # Fraction over all seeds of the last episodes the step limit cut.
            truncated_fraction=float(fractions[c].mean()),
            mean_length=float(result.lengths[c].mean()),
            nonfinite_agents=int(result.nonfinite[c].sum()),
            episodes_cut=episodes_cut,
            agents_cut=agents_cut,
            **policy[c],
            **optimal[c],
        ))
    return rows


#: Agent-episodes converted to float64 at a time when finding convergence episodes (a
#: bound on the memory of a wide or long run's summary; the results do not depend on it).
CONVERGENCE_BLOCK = 1 << 22


def _convergence_times(result: GridResult, c: int, best: Scale, baseline: Scale,
                       window: int) -> tuple[np.ndarray, np.ndarray]:
    """Setting ``c``'s agents' convergence episodes and whether they converged, block of
    agents by block of agents (:func:`~vdbejax.results.solving.episodes_to_converge`)."""
    agents = result.returns.shape[1]
    step = max(1, CONVERGENCE_BLOCK // max(1, result.num_episodes))
    parts = [episodes_to_converge(
        result.returns[c, i:i + step], _agents(best, i, step), _agents(baseline, i, step),
        window=window,
        episodes_run=None if result.episodes_run is None else result.episodes_run[c, i:i + step])
        for i in range(0, agents, step)]
    return (np.concatenate([p.episodes for p in parts]),
            np.concatenate([p.solved for p in parts]))


def _agents(scale: Scale, first: int, count: int) -> Scale:
    """The references of agents ``first … first + count − 1`` (per agent, or one)."""
    return scale if np.ndim(scale) == 0 else np.asarray(scale)[first:first + count]


def summary_columns(result: GridResult) -> list[str]:
    """:data:`SUMMARY_COLUMNS`, ``hyperparameters`` when a setting of ``result`` has values
    besides its swept parameter, and ``episodes_cut`` / ``agents_cut`` for a task whose
    step limit is only a safety cap (``meta["step_cap"]``, the authors' reading), and
    :data:`~vdbejax.results.policy.POLICY_COLUMNS` for a run with policy evaluations, and
    :data:`~vdbejax.results.optimal_actions.OPTIMAL_ACTION_COLUMNS` for one that records
    optimal actions."""
    extra = ["hyperparameters"] if any(s.hyperparameters for s in result.settings) else []
    capped = ["episodes_cut", "agents_cut"] if result.meta.get("step_cap") else []
    policy = POLICY_COLUMNS if result.policy_values is not None else []
    optimal = OPTIMAL_ACTION_COLUMNS if result.optimal_actions is not None else []
    return SUMMARY_COLUMNS[:4] + extra + SUMMARY_COLUMNS[4:] + capped + policy + optimal


def probability_of_improvement_matrix(
    result: GridResult, configs: list[int] | None = None, last: int = LAST
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairwise probability that config i beats config j on final return, with CIs.

    Args:
      result: the grid.
      configs: config indices to compare (default all).
      last: episodes defining the final return.

    Returns:
      ``(p, low, high)``, each ``[k, k]`` for the ``k`` configs (diagonal 0.5).
    """
    configs = list(range(len(result.settings))) if configs is None else list(configs)
    finals = final_return(result.returns[configs], min(last, result.num_episodes))
    k = len(configs)
    p, low, high = (np.full((k, k), 0.5) for _ in range(3))
    for i in range(k):
        for j in range(k):
            if i != j:
                p[i, j], low[i, j], high[i, j] = probability_of_improvement_ci(finals[i], finals[j])
    return p, low, high


def action_probabilities(
    q: np.ndarray, explorer: str, param: float | None = None, state_epsilon: float = 1.0,
    tie_break: str = "random", tables: dict[str, Any] | None = None, episode: int = 0,
    **values: Any,
) -> np.ndarray:
    """Exact probability of each action under an explorer: its own ``probabilities``
    (what its ``select`` samples; e.g. ``p·softmax_τ(Q) + (1 − p)·greedy(Q)`` for the
    paper's four).

    Args:
      q: ``[num_actions]`` action values of one state.
      explorer: a registered explorer name (``egreedy``, ``softmax``, ``vdbe``, …).
      param: its swept parameter (ε, τ, σ, …), or ``None`` for its default.
      state_epsilon: ε(s) for VDBE and VDBE-Softmax (sets ``tables["epsilon"]``).
      tie_break: ``"random"`` or ``"first"`` (for explorers that have one).
      tables: the state's explorer tables (e.g. ``{"counts": [...]}`` for UCB-1).
      episode: the episode index (decaying schedules).
      **values: other hyperparameters of the explorer.

    Returns:
      float64 ``[num_actions]`` probabilities summing to 1.
    """
    import jax.numpy as jnp

    from vdbejax.methods.contract import Context
    from vdbejax.methods.explorers import explorer_class, make_explorer
    from vdbejax.methods.registry import field_names

    if "tie_break" in field_names(explorer_class(explorer)):
        values.setdefault("tie_break", tie_break)
    chosen = make_explorer(explorer, param, **values)
    q_row = jnp.asarray(q, jnp.float32)
    defaults = {name: jnp.full(() if spec.per == "state" else q_row.shape, spec.init, jnp.float32)
                for name, spec in chosen.tables().items()}
    if "epsilon" in defaults:
        defaults["epsilon"] = jnp.asarray(state_epsilon, jnp.float32)
    defaults.update({k: jnp.asarray(v, jnp.float32) for k, v in (tables or {}).items()})
    context = Context(jnp.int32(episode), jnp.int32(0), jnp.bool_(False))
    return np.asarray(chosen.probabilities(q_row, defaults, context), np.float64)


def markdown_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str],
                   digits: int = 3) -> str:
    """Rows as a markdown table (floats rounded to ``digits``), e.g. for notebooks
    (written by :func:`vdbejax.results.markdown.table_lines`).

    Args:
      rows: mappings holding at least ``columns`` (dicts, or
        :class:`~vdbejax.results.summary.SummaryRow`).
      columns: the columns, in order.
      digits: decimals of float cells.

    Returns:
      markdown text.
    """
    def cell(value: Any) -> str:
        if not isinstance(value, (float, np.floating)):
            return str(value)
        # Tiny parameters (τ = 0.0001) would round to 0: show them in full.
        return f"{value:g}" if 0 < np.abs(value) < 10.0 ** -digits else f"{value:.{digits}f}"

    return "\n".join(table_lines(columns, ([cell(r[c]) for c in columns] for r in rows)))
