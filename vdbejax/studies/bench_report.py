"""The report of ``vdbejax bench``: ranking tables, regret figures and the aggregate.

Files (in the benchmark's folder): ``ranking.csv`` (one row per task and method),
``aggregate.csv`` (one row per method, across tasks), ``bench.md`` (both as tables, with the
rule and the budget), ``meta.json`` (everything needed to rerun it), ``regret_<task>.png``
(cumulative regret per method, 95 % bootstrap bands) and ``aggregate.png`` (IQM of the
normalised scores with stratified bootstrap intervals, and the performance profiles).

A method left out of some tasks (the cost rule of :mod:`vdbejax.studies.bench_methods`)
is aggregated over the tasks it ran, says how many in its row, and is listed after the
methods that ran everywhere; its probability of improvement counts the tasks both ran.
"""
from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.results import io
from vdbejax.results.grid_result import GridResult
from vdbejax.results.markdown import table_lines
from vdbejax.results.optimal_actions import OPTIMAL_ACTION_COLUMNS
from vdbejax.results.policy import POLICY_COLUMNS, policy_gap_figure
from vdbejax.results.regret import (
    aggregate_iqm,
    cumulative_regret,
    performance_profile,
    task_probability_of_improvement,
)

RANKING_CSV, AGGREGATE_CSV, MARKDOWN_FILE = "ranking.csv", "aggregate.csv", "bench.md"
AGGREGATE_FIGURE = "aggregate.png"
ROW_COLUMNS = ["task", "rank", "method", "title", "family", "tuned", "value", "score",
               "score_low", "score_high", "regret", "regret_low", "regret_high", "final_return",
               "best_return", "random_return", "fraction_solved", "median_episodes",
               "median_text", "nonfinite_agents"]
#: The ranking's columns of runs with policy evaluations (:mod:`vdbejax.results.policy`).
RANKING_POLICY_COLUMNS = POLICY_COLUMNS
#: The ranking's columns of runs that record optimal actions (the ``bandits`` group;
#: :mod:`vdbejax.results.optimal_actions`, over the last tenth of the episodes).
RANKING_OPTIMAL_COLUMNS = OPTIMAL_ACTION_COLUMNS
AGGREGATE_COLUMNS = ["method", "title", "family", "iqm", "iqm_low", "iqm_high", "mean_rank",
                     "p_vs_reference", "p_low", "p_high", "tasks"]
#: The reference of the probability of improvement: the paper's undirected baseline.
REFERENCE = "egreedy"


def regret_figure_file(task: str) -> str:
    """``regret_<task>.png`` (``:`` of a parametrised task name as ``-``)."""
    return f"regret_{task.replace(':', '-')}.png"


def policy_figure_file(task: str) -> str:
    """``policy_gap_<task>.png``: the greedy policies' gap (runs with evaluations)."""
    return f"policy_gap_{task.replace(':', '-')}.png"


def output_files(task_names: Sequence[str], figures: bool, evaluated: bool = False) -> list[str]:
    """Every file the report writes (``evaluated``: the runs evaluate their policies)."""
    files = [RANKING_CSV, AGGREGATE_CSV, MARKDOWN_FILE, io.META_FILE]
    if figures:
        files += [AGGREGATE_FIGURE, *(regret_figure_file(t) for t in task_names)]
        if evaluated:
            files += [policy_figure_file(t) for t in task_names]
    return files


def _ran_everywhere(tasks: Sequence[Any], methods: Sequence[Any]) -> dict[str, list[str]]:
    return {t.name: [m.name for m in methods] for t in tasks}


def _scores_of(method: str, tasks: Sequence[Any], scores: dict[str, np.ndarray],
               ran: dict[str, list[str]]) -> dict[str, np.ndarray]:
    """The method's ``[seeds]`` scores per task it ran (``scores``: per task, ``[methods
    that ran, seeds]`` in the order of ``ran``)."""
    return {t.name: scores[t.name][ran[t.name].index(method)] for t in tasks
            if method in ran[t.name]}


def aggregate_rows(tasks: Sequence[Any], methods: Sequence[Any],
                   scores: dict[str, np.ndarray], rows: Sequence[dict[str, Any]],
                   ran: dict[str, list[str]] | None = None) -> list[dict[str, Any]]:
    """One row per method that ran somewhere: IQM of its normalised scores over every
    (task it ran, agent), its mean rank over those tasks, and its probability of improving
    on :data:`REFERENCE` over the tasks both ran (``scores``: per task, ``[methods that
    ran, seeds]``; ``ran``: per task the names of the methods that ran, by default all)."""
    ran = ran or _ran_everywhere(tasks, methods)
    reference = _scores_of(REFERENCE, tasks, scores, ran)
    out = []
    for m in methods:
        mine = _scores_of(m.name, tasks, scores, ran)
        if not mine:
            continue
        iqm = aggregate_iqm(list(mine.values()))
        ranks = [r["rank"] for r in rows if r["method"] == m.name]
        shared = [name for name in mine if name in reference]
        p = (task_probability_of_improvement([mine[t] for t in shared],
                                             [reference[t] for t in shared])
             if shared else None)
        out.append({"method": m.name, "title": m.title, "family": m.family, "iqm": iqm.value,
                    "iqm_low": iqm.low, "iqm_high": iqm.high,
                    "mean_rank": float(np.mean(ranks)),
                    "p_vs_reference": p.value if p else math.nan,
                    "p_low": p.low if p else math.nan, "p_high": p.high if p else math.nan,
                    "tasks": len(mine)})
    return sorted(out, key=lambda r: (r["tasks"] < len(tasks), -r["iqm"]))


def write_report(out: Path, tasks: Sequence[Any], methods: Sequence[Any],
                 runs: dict[str, GridResult], scores: dict[str, np.ndarray],
                 rows: list[dict[str, Any]], meta: dict[str, Any],
                 *, ran: dict[str, list[str]] | None = None,
                 figures: bool = True) -> list[dict[str, Any]]:
    """Write every file of the report (module docstring); returns the aggregate rows.
    ``scores``: per task, the agents' normalised scores ``[methods that ran, seeds]``;
    ``ran``: per task the names of the methods that ran there (by default all)."""
    ran = ran or _ran_everywhere(tasks, methods)
    aggregate = aggregate_rows(tasks, methods, scores, rows, ran)
    ordered = sorted(rows, key=lambda r: ([t.name for t in tasks].index(r["task"]), r["rank"]))
    evaluated = "policy_gap" in ordered[0] if ordered else False
    recorded = "optimal_actions" in ordered[0] if ordered else False
    io.write_csv(out / RANKING_CSV, ordered,
                 ROW_COLUMNS + (RANKING_POLICY_COLUMNS if evaluated else [])
                 + (RANKING_OPTIMAL_COLUMNS if recorded else []))
    io.write_csv(out / AGGREGATE_CSV, aggregate, AGGREGATE_COLUMNS)
    io.save_json(out / io.META_FILE, meta)
    io.atomic_write_text(out / MARKDOWN_FILE, markdown(ordered, aggregate, meta))
    for stale in [*out.glob("regret_*.png"), *out.glob("policy_gap_*.png"),
                  out / AGGREGATE_FIGURE]:
        stale.unlink(missing_ok=True)  # no figure of an earlier run outlives it
    if figures:
        import matplotlib.pyplot as plt

        for task in tasks:
            fig = regret_figure(task, [m for m in methods if m.name in ran[task.name]],
                                runs[task.name])
            fig.savefig(out / regret_figure_file(task.name), dpi=110)
            plt.close(fig)
            if runs[task.name].policy_values is not None:
                fig = policy_gap_figure(runs[task.name])
                fig.savefig(out / policy_figure_file(task.name), dpi=110)
                plt.close(fig)
        fig = aggregate_figure(tasks, methods, scores, aggregate, ran)
        fig.savefig(out / AGGREGATE_FIGURE, dpi=110)
        plt.close(fig)
    return aggregate


def _interval(value: float, low: float, high: float, digits: int = 3) -> str:
    return f"{value:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def markdown(rows: Sequence[dict[str, Any]], aggregate: Sequence[dict[str, Any]],
             meta: dict[str, Any]) -> str:
    """``bench.md``: the aggregate table, then one ranking table per task."""
    options, budget = meta["options"], meta["tuning_budget"]
    evaluated = bool(options.get("evaluate_every"))
    recorded = bool(rows) and "optimal_actions" in rows[0]
    lines = ["# Exploration benchmark", ""]
    if meta.get("command"):
        lines += [f"Command: `{meta['command']}`", ""]
    tuning = (f"one knob per method, its candidates on {options['tune_seeds']} agents each"
              f" with root seed {options['seed'] + 1}" if options["tune"]
              else "none (each method at its middle candidate)")
    total = len(meta["tasks"])
    lines += [
        f"{total} tasks, {len(meta['methods'])} methods, {options['seeds']} agents"
        f" per method and task, {options['episodes']} episodes each (root seed"
        f" {options['seed']}). Tuning: {tuning}; tuning budget"
        f" {budget['agent_episodes']:,} agent-episodes ({budget['agent_steps']:,}"
        f" agent-steps). Elapsed {meta['elapsed_seconds']:.0f} s.",
        "",
        "**Score**: mean normalised return over all episodes (0 = uniformly random policy,"
        " 1 = the exact optimum from the first episode on), 95 % bootstrap interval over"
        " agents. **Realized regret**: cumulative regret of the episodes' returns against the"
        " exact optimum after the last episode, 95 % bootstrap interval (returns sampled with"
        " exploration: it can fall below 0 by luck). **Solved**: the share of agents whose"
        " 20-episode moving average reached 0.9 on the normalised scale.", "",
        *(policy_note(options["evaluate_every"]) if options.get("evaluate_every") else []),
        *(["**% optimal action**: the share of the steps of each agent's last tenth of the"
           " episodes whose action maximises the task's exact Q* (on a bandit, an arm of the"
           " largest mean), mean over agents; **reward per step**: their return over their"
           " steps; 95 % bootstrap intervals over agents.", ""] if recorded else []),
        "## Across tasks", "",
        *table_lines(
            ["method", "family", "IQM score [95 % CI]", "mean rank", "P(better than ε-greedy)",
             "tasks"],
            ([a["title"], a["family"], _interval(a["iqm"], a["iqm_low"], a["iqm_high"]),
              f"{a['mean_rank']:.1f}",
              "-" if math.isnan(a["p_vs_reference"])
              else _interval(a["p_vs_reference"], a["p_low"], a["p_high"], 2),
              f"{a['tasks']} of {total}"] for a in aggregate))]
    left_out = meta.get("left_out", [])
    titles = {m["name"]: m["title"] for m in meta["methods"]}
    if left_out:
        lines += ["", f"**Left out by the cost rule** (a dense-model method costs S (S + t) A"
                      f" (H + 1) products per agent-episode, t = 1 on a task with terminal"
                      f" outcomes, else 0; limit"
                      f" {meta['options']['cost_limit']:.3g}): "
                  + "; ".join(f"{titles[x['method']]} on {x['task']} ({x['cost']:.3g})"
                              for x in left_out)
                  + ". A method left out somewhere is aggregated over the tasks it ran"
                    " (listed last)."]
    for task in meta["tasks"]:
        mine = [r for r in rows if r["task"] == task["name"]]
        lines += ["", f"## {task['name']}", "",
                  f"{task['states']} states, {task['actions']} actions, horizon"
                  f" {task['horizon']}; best return {task['best_return']:.4g}, random policy"
                  f" {task['random_return']:.4g}.", "",
                  *table_lines(
                      ["rank", "method", "tuned", "score [95 % CI]",
                       "realized regret [95 % CI]", "final return", "solved", "median episodes",
                       *(["policy gap [95 % CI]", "optimal policies"] if evaluated else []),
                       *(["% optimal action [95 % CI]", "reward per step [95 % CI]"]
                         if recorded else [])],
                      ([str(r["rank"]), r["title"],
                        f"{r['tuned']} = {r['value']:.3g}" if r["tuned"] else "-",
                        _interval(r["score"], r["score_low"], r["score_high"]),
                        f"{r['regret']:.4g} [{r['regret_low']:.4g}, {r['regret_high']:.4g}]",
                        f"{r['final_return']:.4g}", f"{r['fraction_solved']:.0%}",
                        r["median_text"], *(policy_cells(r) if evaluated else []),
                        *(optimal_cells(r) if recorded else [])] for r in mine))]
        skipped = [titles[x["method"]] for x in left_out if x["task"] == task["name"]]
        if skipped:
            lines += ["", f"Not run here (cost rule): {', '.join(skipped)}."]
    return "\n".join(lines) + "\n"


def policy_note(every: int) -> list[str]:
    """``bench.md``'s lines on the greedy policies' values (runs with evaluations)."""
    return ["**Policy gap**: V* − V^π of each agent's greedy policy after its last evaluation"
            f" (every {every} episodes; exact, by policy evaluation on the known task under"
            " its step limit), mean over agents with its 95 % bootstrap interval; **optimal"
            " policies**: the share of agents whose greedy policy is optimal (Wilson 95 %"
            " interval).", ""]


def _rounded(gap: float) -> str:
    """A policy gap to 4 decimals: float32 evaluation leaves an optimal policy's gap at
    ±1e-7, shown as 0, not as a negative gap."""
    return f"{round(gap, 4) + 0.0:.4f}"


def policy_cells(row: dict[str, Any]) -> list[str]:
    """The policy gap and optimal share of a ranking row, as two table cells."""
    gap = [_rounded(row[k]) for k in ("policy_gap", "policy_gap_ci_low", "policy_gap_ci_high")]
    return [f"{gap[0]} [{gap[1]}, {gap[2]}]", f"{row['optimal_fraction']:.0%}"
            f" [{row['optimal_ci_low']:.0%}, {row['optimal_ci_high']:.0%}]"]


def optimal_cells(row: dict[str, Any]) -> list[str]:
    """The % optimal action and reward per step of a ranking row, as two table cells."""
    reward = _interval(row["reward_per_step"], row["reward_per_step_ci_low"],
                       row["reward_per_step_ci_high"])
    return [f"{row['optimal_actions']:.0%} [{row['optimal_actions_ci_low']:.0%},"
            f" {row['optimal_actions_ci_high']:.0%}]", reward]


def bench_meta(command: str | None, tasks: Sequence[Any], methods: Sequence[Any],
               chosen: dict[str, dict[str, Any]], budget: dict[str, Any],
               timing: dict[str, dict[str, float]], elapsed: float, versions: dict[str, Any],
               **options: Any) -> dict[str, Any]:
    """``meta.json`` of a benchmark: its command and options, tasks, methods, choices,
    tuning budget, timing and versions."""
    import dataclasses

    import jax

    return {
        "command": command, "options": options,
        "tasks": [{"name": t.name, "states": t.mdp.num_states, "actions": t.mdp.num_actions,
                   "horizon": int(t.mdp.max_steps), "best_return": t.best,
                   "random_return": t.baseline, "r_max": t.scale.r_max} for t in tasks],
        "methods": [dataclasses.asdict(m) for m in methods],
        "chosen": chosen, "tuning_budget": budget, "timing": timing,
        "elapsed_seconds": elapsed,
        "jax_version": jax.__version__, "backend": jax.default_backend(), **versions,
    }


def _pyplot() -> Any:
    import matplotlib

    if "ipykernel" not in sys.modules:  # headless, as results.plotting; a notebook keeps its own
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _colors(plt: Any, methods: Sequence[Any]) -> dict[str, Any]:
    cmap = plt.get_cmap("tab20")
    return {m.name: cmap(i % 20) for i, m in enumerate(methods)}


def regret_figure(task: Any, methods: Sequence[Any], result: GridResult) -> Any:
    """Cumulative regret per method against episodes, with 95 % bootstrap bands."""
    from vdbejax.results.stats import mean_curve_ci

    plt = _pyplot()
    colors = _colors(plt, methods)
    fig, ax = plt.subplots(figsize=(9, 5.2), layout="constrained")
    regret = cumulative_regret(result.returns, task.best)
    episodes = np.arange(1, result.num_episodes + 1)
    for c, m in enumerate(methods):
        mean, low, high = mean_curve_ci(regret[c], window=1, num_resamples=500)
        ax.plot(episodes, mean, color=colors[m.name], label=m.title,
                linestyle="-" if m.family == "paper" else "--" if c % 2 else ":")
        ax.fill_between(episodes, low, high, color=colors[m.name], alpha=0.15, linewidth=0)
    ax.set(xlabel="episode", ylabel="cumulative regret",
           title=f"{task.name}: cumulative regret ({result.num_seeds} agents per method)")
    ax.legend(fontsize=7, ncol=2, loc="upper left", frameon=False)
    return fig


def aggregate_figure(tasks: Sequence[Any], methods: Sequence[Any],
                     scores: dict[str, np.ndarray], aggregate: Sequence[dict[str, Any]],
                     ran: dict[str, list[str]] | None = None) -> Any:
    """The IQM of the normalised scores per method with its stratified bootstrap interval
    (the :func:`aggregate_rows`), beside the performance profiles (fraction of runs scoring
    above each threshold), each over the tasks the method ran."""
    plt = _pyplot()
    ran = ran or _ran_everywhere(tasks, methods)
    by_method = {a["method"]: a for a in aggregate}
    methods = [m for m in methods if m.name in by_method]
    colors = _colors(plt, methods)
    fig, (ax_iqm, ax_profile) = plt.subplots(1, 2, figsize=(13, 0.32 * len(methods) + 2.5),
                                             layout="constrained")
    thresholds = np.linspace(-0.5, 1.0, 61)
    for m in methods:
        mine = list(_scores_of(m.name, tasks, scores, ran).values())
        fraction, low, high = performance_profile(mine, thresholds, num_resamples=500)
        ax_profile.plot(thresholds, fraction, color=colors[m.name], label=m.title)
        ax_profile.fill_between(thresholds, low, high, color=colors[m.name], alpha=0.12,
                                linewidth=0)
    iqms = [by_method[m.name] for m in methods]
    order = np.argsort([i["iqm"] for i in iqms])
    for y, c in enumerate(order):
        i = iqms[c]
        ax_iqm.errorbar(i["iqm"], y, xerr=[[i["iqm"] - i["iqm_low"]], [i["iqm_high"] - i["iqm"]]],
                        fmt="o", color=colors[methods[c].name], capsize=3)
    ax_iqm.set_yticks(range(len(methods)), [
        methods[c].title + (f" ({iqms[c]['tasks']} tasks)" if iqms[c]["tasks"] < len(tasks)
                            else "") for c in order], fontsize=8)
    ax_iqm.set(xlabel="IQM of normalised score (95 % CI)",
               title=f"Across {len(tasks)} tasks")
    ax_profile.set(xlabel="normalised score τ", ylabel="fraction of runs with score > τ",
                   title="Performance profiles")
    ax_profile.legend(fontsize=7, ncol=2, frameon=False)
    return fig


__all__ = ["AGGREGATE_CSV", "AGGREGATE_FIGURE", "MARKDOWN_FILE", "RANKING_CSV",
           "aggregate_figure", "aggregate_rows", "markdown", "output_files", "regret_figure",
           "regret_figure_file", "write_report"]
