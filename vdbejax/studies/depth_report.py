"""The depth study's report: ``depth.md``, ``depth.png`` and, for a run with policy
evaluations, ``depth_policy_gap.png`` (:mod:`vdbejax.studies.depth`).

It imports nothing of the runner's training: the data flow one way, runner → report.
"""
from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.results import io
from vdbejax.results.markdown import table_lines

MARKDOWN_FILE, FIGURE_FILE = "depth.md", "depth.png"
#: The greedy policies' gap against depth (a run with ``--evaluate-every``).
POLICY_FIGURE_FILE = "depth_policy_gap.png"
FAMILY_TITLES = {"deepsea": "DeepSea of size N (N steps an episode)",
                 "chain": "deterministic chain of N states (horizon 2N)"}


def write_reports(out: Path, rows: Sequence[dict[str, Any]], slopes: Sequence[dict[str, Any]],
                  meta: dict[str, Any], *, figure: bool = True) -> None:
    """Write ``depth.md`` and, with ``figure``, ``depth.png`` (and ``depth_policy_gap.png``
    when the run evaluated its policies) into ``out``."""
    io.atomic_write_text(out / MARKDOWN_FILE, depth_markdown(rows, slopes, meta))
    if figure:
        io.save_figure(depth_figure(rows), out / FIGURE_FILE)
        if meta["options"].get("evaluate_every"):
            io.save_figure(depth_policy_figure(rows), out / POLICY_FIGURE_FILE)


def interval_text(row: dict[str, Any], name: str, digits: int = 2) -> str:
    """``"0.86 [0.85, 0.87]"`` for ``row[name]`` and its ``_low``/``_high``; ``"-"`` for NaN
    (no slope: too few solved depths)."""
    value = row[name]
    if not math.isfinite(value):
        return "-"
    return (f"{value:.{digits}f} [{row[f'{name}_low']:.{digits}f},"
            f" {row[f'{name}_high']:.{digits}f}]")


def policy_table(rows: Sequence[dict[str, Any]], slopes: Sequence[dict[str, Any]],
                 family: str, sizes: Sequence[int]) -> list[str]:
    """A family's table of the greedy policies at each agent's last evaluation: mean gap
    ``V* − V^π`` [95 % bootstrap interval] and the share of optimal greedy policies."""
    lines = ["Greedy policies at each agent's last evaluation (exact, vdbejax.runs.evaluation):"
             " mean V* − V^π [95 % interval], share of optimal ones.", ""]

    def cell(row: dict[str, Any]) -> str:
        if not math.isfinite(row["policy_gap"]):
            return "-"
        return (f"{row['policy_gap']:.3g} [{row['policy_gap_ci_low']:.3g},"
                f" {row['policy_gap_ci_high']:.3g}], {row['optimal_fraction']:.0%}")

    lines += table_lines(["method", *(f"N = {n}" for n in sizes)],
                         ([slope["title"], *depth_cells(rows, slope, family, sizes, cell)]
                          for slope in slopes if slope["family"] == family))
    return [*lines, ""]


def depth_cells(rows: Sequence[dict[str, Any]], slope: dict[str, Any], family: str,
                sizes: Sequence[int], cell: Callable[[dict[str, Any]], str]) -> list[str]:
    """``cell`` of a method's row of ``family`` at each depth of ``sizes`` (``-`` where it
    did not run)."""
    cells = []
    for n in sizes:
        row = next((r for r in rows if r["family"] == family and r["size"] == n
                    and r["method"] == slope["method"]), None)
        cells.append("-" if row is None else cell(row))
    return cells


def depth_markdown(rows: Sequence[dict[str, Any]], slopes: Sequence[dict[str, Any]],
                   meta: dict[str, Any]) -> str:
    """Per family: one row per method with its median episodes to solve at each depth
    (95 % interval, solved/agents) and its two growth slopes."""
    options = meta["options"]
    lines = ["# Depth scaling", ""]
    if meta.get("command"):
        lines += [f"`{meta['command']}`", ""]
    lines += [
        f"{options['seeds']} agents per method and task, each until solved or"
        f" {options['episodes']} episodes (root seed {options['seed']}); every method at its"
        " untuned middle candidate (`vdbejax bench --no-tune`). **Solved**: the"
        f" {options['window']}-episode moving average of the normalised return (0 = uniformly"
        f" random policy, 1 = optimum) reaches {options['solved']}. Cells: median episodes to"
        " solve [95 % bootstrap interval], solved/agents (`> B`: fewer than half solved"
        " within B episodes). **Exponent**: slope of log(median) against log(N), the degree"
        " of a polynomial growth; **doubling**: slope of log2(median) against N, the rate"
        " of an exponential one; both over the depths with a finite median, with 95 %"
        f" bootstrap intervals ({options['resamples']} resamples; a censored resample counts"
        " at the budget).", ""]
    for family in options["families"]:
        sizes = options["sizes"]
        lines += [f"## {FAMILY_TITLES.get(family, family)}", "", *table_lines(
            ["method", "family", *(f"N = {n}" for n in sizes), "exponent", "doubling"],
            ([slope["title"], slope["method_family"],
              *depth_cells(rows, slope, family, sizes,
                           lambda row: f"{row['median_text']}, {row['solved']}/{row['agents']}"),
              interval_text(slope, "exponent"), interval_text(slope, "doubling", 3)]
             for slope in slopes if slope["family"] == family)), ""]
        if options.get("evaluate_every"):
            lines += policy_table(rows, slopes, family, sizes)
    tasks = meta["tasks"]
    steps = sum(t["agent_steps"] for t in tasks.values())
    seconds = sum(t["seconds"] for t in tasks.values())
    lines += [f"Training: {steps:,} agent-steps in {seconds:.1f} s"
              f" ({meta['elapsed_seconds']:.1f} s in all).", ""]
    return "\n".join(lines)


def depth_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """One panel per family: median episodes to solve against N (log-log, 95 % intervals);
    a censored median is an open triangle at its budget."""
    def draw(ax: Any, mine: list[dict[str, Any]], x: np.ndarray, color: Any) -> None:
        median, low, high, budget = (np.array([r[k] for r in mine], float) for k in (
            "median_episodes", "median_low", "median_high", "budget"))
        high = np.where(np.isfinite(high), high, budget)
        ok = np.isfinite(median)
        ax.errorbar(x[ok], median[ok], yerr=[median[ok] - low[ok], high[ok] - median[ok]],
                    color=color, marker="o", capsize=2, elinewidth=0.8, markersize=4,
                    label=mine[0]["title"])
        if (~ok).any():
            ax.plot(x[~ok], budget[~ok], linestyle="none", marker="^", markerfacecolor="none",
                    color=color)
        ax.set_yscale("log")

    return _family_figure(rows, lambda row: True, draw, "median episodes to solve",
                          "open triangle: fewer than half the agents solved within the budget")


def depth_policy_figure(rows: Sequence[dict[str, Any]]) -> Any:
    """One panel per family: each method's mean gap ``V* − V^π`` of its agents' greedy
    policies at their last evaluation, as a share of the task's ``V* − V_random`` (0: the
    optimum, 1: no better than the uniformly random policy; depths of one family have
    optima of different sizes), against N, with 95 % bootstrap intervals."""
    def draw(ax: Any, mine: list[dict[str, Any]], x: np.ndarray, color: Any) -> None:
        span = np.array([r["_span"] for r in mine], float)
        gap, low, high = (np.array([r[k] for r in mine], float) / span for k in (
            "policy_gap", "policy_gap_ci_low", "policy_gap_ci_high"))
        ax.errorbar(x, gap, yerr=[np.maximum(gap - low, 0), np.maximum(high - gap, 0)],
                    color=color, marker="o", capsize=2, elinewidth=0.8, markersize=4,
                    label=mine[0]["title"])
        ax.axhline(0.0, color="black", linewidth=0.8)

    return _family_figure(rows, lambda row: math.isfinite(row["policy_gap"]), draw,
                          "(V* − V^π) / (V* − V_random) of the greedy policy",
                          "each agent's last evaluation (before its stop); mean over agents")


def _family_figure(rows: Sequence[dict[str, Any]], keep: Callable[[dict[str, Any]], bool],
                   draw: Callable[[Any, list[dict[str, Any]], np.ndarray, Any], None],
                   ylabel: str, note: str) -> Any:
    """A panel per family, a series per method (``draw(ax, rows, x, color)`` of its rows
    that ``keep`` keeps) against N on a log2 axis, the methods' bars set apart."""
    import matplotlib

    if "ipykernel" not in sys.modules:  # headless, as results.plotting; a notebook keeps its own
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    families = list(dict.fromkeys(r["family"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    colors = {m: plt.get_cmap("tab20")(i % 20) for i, m in enumerate(methods)}
    fig, axes = plt.subplots(1, len(families), figsize=(7.5 * len(families), 5.2), squeeze=False)
    for ax, family in zip(axes[0], families, strict=True):
        for j, method in enumerate(methods):
            mine = [r for r in rows if r["family"] == family and r["method"] == method
                    and keep(r)]
            if mine:
                spread = 1.0 + 0.012 * (j - (len(methods) - 1) / 2)  # keep the bars apart
                draw(ax, mine, np.array([r["size"] for r in mine], float) * spread,
                     colors[method])
        ax.set_xscale("log", base=2)
        ax.set_xlabel("depth N")
        ax.set_ylabel(ylabel)
        ax.set_title(FAMILY_TITLES.get(family, family), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0][-1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.text(0.01, 0.01, note, fontsize=8)
    fig.tight_layout()
    return fig
