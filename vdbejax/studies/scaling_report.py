"""The report of ``vdbejax scale``: its result folder, tables, ``scaling.md`` and figure.

A study folder (:func:`~vdbejax.studies.scaling.run_scaling`) holds ``scaling.csv`` (one row per
variant × setting, :data:`ROW_COLUMNS`), ``meta.json`` (the options, one record per variant
(:data:`VARIANT_COLUMNS`), the versions), ``runs/NxK/`` (each variant's result folder: its curves)
and what this module draws from the rows: ``scaling.md`` (:func:`scaling_markdown`) and
``scaling.png`` (:func:`scaling_figure`), both written by :func:`write_reports`.
:func:`load_scaling` reads a folder back, so the report redraws without training.

It takes the rows as they are and imports nothing of the runner (the data flow one way:
runner → results → report).
"""
from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vdbejax.methods.agents import Setting, with_parameter_names
from vdbejax.results import io
from vdbejax.results.analysis import markdown_table
from vdbejax.results.folder_lock import MARKER_FILE, marked_stage

#: The files of a study folder (``runs/`` holds one result folder ``NxK/`` per variant).
CSV_FILE = "scaling.csv"
MARKDOWN_FILE = "scaling.md"
FIGURE_FILE = "scaling.png"
META_FILE = "meta.json"
RUNS_FOLDER = "runs"

#: ``scaling.csv``'s columns: one row per variant × setting.
ROW_COLUMNS = [
    "size", "config", "states", "actions", "best_return", "random_return", "threshold", "learner",
    "explorer",
    "param", "method", "status", "agents", "solved", "fraction_solved", "fraction_low",
    "fraction_high",
    "median_episodes", "median_low", "median_high", "budget", "median_text", "agent_episodes",
    "nonfinite_agents",
]
#: The fields of a variant's record in ``meta.json``'s ``variants`` (besides ``threshold``).
VARIANT_COLUMNS = [
    "size", "states", "actions", "best_return", "random_return", "shortest_solution",
    "settings_run", "agents",
    "budget_episodes", "chunk_episodes", "episodes_reached", "stopped", "agent_episodes",
    "fixed_budget_agent_episodes", "agent_steps", "training_seconds", "compile_seconds",
    "steps_per_second",
]


def method_label(setting: Setting) -> str:
    """``Q-learning VDBE-Softmax`` style names (figure legends, tables): the plug-ins'
    titles."""
    from vdbejax.methods.registry import explorer_title, learner_title

    return f"{learner_title(setting.learner)} {explorer_title(setting.explorer)}"


def write_reports(out_dir: str | Path, rows: Sequence[dict[str, Any]],
                  variants: Sequence[dict[str, Any]], meta: dict[str, Any],
                  figure: bool = True) -> None:
    """``scaling.md`` and (unless ``figure=False``) ``scaling.png`` from a study's rows."""
    out = Path(out_dir)
    io.atomic_write_text(out / MARKDOWN_FILE, scaling_markdown(rows, variants, meta))
    if figure:
        io.save_figure(scaling_figure(rows, variants), out / FIGURE_FILE)


def load_scaling(out_dir: str | Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]],
                                                dict[str, Any]]:
    """``(rows, variants, meta)`` of a folder written by
    :func:`~vdbejax.studies.scaling.run_scaling` (no training):
    redraw with :func:`write_reports`, or read the numbers in a notebook.

    Raises:
      ValueError: the folder lacks ``scaling.csv`` or ``meta.json``, or a study was
        stopped while writing them.
    """
    out = Path(out_dir)
    missing = [f for f in (CSV_FILE, META_FILE) if not (out / f).is_file()]
    if missing:
        raise ValueError(f"scaling folder {str(out)!r} lacks {', '.join(missing)}")
    if marked_stage(out) is not None:
        raise ValueError(f"scaling folder {str(out)!r} is half-written: a study was stopped"
                         f" while writing its files ({MARKER_FILE} is still there); run it"
                         " again with --resume (its whole variants are reused)")
    meta = io.load_json(out / META_FILE)
    settings = with_parameter_names(  # plug-ins not imported here carry their saved names
        [Setting(learner, explorer, param, values)
         for learner, explorer, param, values in meta["settings"]],
        meta.get("parameter_names", {}))
    integers = {"config", "states", "actions", "agents", "solved", "budget", "agent_episodes",
                "nonfinite_agents"}
    rows = []
    for raw in io.read_csv(out / CSV_FILE):
        row: dict[str, Any] = {}
        for key, value in raw.items():
            if key in integers:
                row[key] = int(value)
            elif ((key in ROW_COLUMNS[ROW_COLUMNS.index("fraction_solved"):]
                   and key != "median_text")
                  or key in ("best_return", "random_return", "threshold")):
                row[key] = float(value)
            else:
                row[key] = value
        row["param"] = "" if raw["param"] == "" else float(raw["param"])
        row["_setting"] = settings[row["config"]]
        rows.append(row)
    return rows, list(meta["variants"]), meta


def row_setting(row: dict[str, Any]) -> Setting:
    """The setting a row of the scaling table belongs to (kept with the row, never written)."""
    return row["_setting"]


def growth_exponents(rows: Sequence[dict[str, Any]]) -> dict[Setting, tuple[float, int]]:
    """Per setting, the slope of log(median episodes to solve) against log(reachable states)
    (least squares over the variants where its median is defined) and how many variants
    that is; the slope is NaN with fewer than two. 1 = episodes grow in proportion to states.
    """
    points: dict[Setting, list[tuple[float, float]]] = {}
    for r in rows:
        setting = row_setting(r)
        points.setdefault(setting, [])
        if r["status"] == "run" and math.isfinite(r["median_episodes"]):
            points[setting].append((math.log(r["states"]), math.log(r["median_episodes"])))
    slopes = {}
    for setting, xy in points.items():
        if len({x for x, _ in xy}) < 2:
            slopes[setting] = (math.nan, len(xy))
            continue
        x, y = np.array(xy).T
        slopes[setting] = (float(np.polyfit(x, y, 1)[0]), len(xy))
    return slopes


def scaling_markdown(rows: Sequence[dict[str, Any]], variants: Sequence[dict[str, Any]],
                     meta: dict[str, Any]) -> str:
    """``scaling.md``: the variants, then one row per method with a column per variant
    (median episodes to solve [95% interval], solved/agents) and its growth exponent."""
    options = meta["options"]
    lines = ["# Episodes to solve against task size", ""]
    if meta.get("command"):
        lines += [f"Command: `{meta['command']}`", ""]
    lines += [
        f"Solved = the {options['window']}-episode moving average of an agent's normalised"
        f" returns reaches {options['fraction']:g} (0 = the uniformly random policy's expected"
        " return, 1 = the variant's exact best; full windows only; `threshold`: that score"
        " in returns);"
        f" {options['seeds']} agents per setting; episode budget per variant"
        + (f" max({options['episodes']}, {options['episodes_per_state']:g} × states)"
           if options.get("episodes_per_state") else f" {options['episodes']}")
        + (f", or {options['seconds']:g} s of wall clock" if options.get("seconds") else "")
        + ". Cells: median episodes to solve [95% bootstrap interval] (solved/agents);"
        " \"> B\": censored (half or more of the agents did not solve within B episodes);"
        " \"-\": not run. Exponent: slope of log(median) against log(states) over the variants"
        " with a median (how many in brackets; 1 = proportional to the states).", "",
        "## Variants", ""]
    columns = ["size", "states", "actions", "best_return", "random_return", "threshold",
               "shortest_solution", "settings_run",
               "budget_episodes", "episodes_reached", "stopped", "agent_episodes",
               "fixed_budget_agent_episodes",
               "training_seconds", "compile_seconds", "steps_per_second"]
    table = []
    for v in variants:
        row = dict(v)
        row["steps_per_second"] = (f"{v['steps_per_second'] / 1e6:.2f} M"
                                   if math.isfinite(v["steps_per_second"]) else "-")
        row["training_seconds"] = f"{v['training_seconds']:.1f}"
        row["compile_seconds"] = f"{v['compile_seconds']:.1f}"
        table.append(row)
    lines += [markdown_table(table, columns, digits=2), "", "## Median episodes to solve", ""]
    sizes = [v["size"] for v in variants]
    header = (["method"]
              + [f"{s} ({v['states']})" for s, v in zip(sizes, variants, strict=True)]
              + ["exponent"])
    slopes = growth_exponents(rows)
    pivot: dict[Setting, dict[str, str]] = {}
    for r in rows:
        setting = row_setting(r)
        cells = pivot.setdefault(setting, {"method": f"{r['method']} ({param_text(setting)})"})
        cells[f"{r['size']} ({r['states']})"] = (
            "-" if r["status"] != "run" else f"{r['median_text']} ({r['solved']}/{r['agents']})")
    for setting, cells in pivot.items():
        slope, count = slopes[setting]
        cells["exponent"] = "-" if math.isnan(slope) else f"{slope:.2f} ({count})"
    lines += [markdown_table([{c: cells.get(c, "-") for c in header} for cells in pivot.values()],
                             header), ""]
    return "\n".join(lines)


def param_text(setting: Setting) -> str:
    """``ε = 0.01`` or ``ε = 1, decay = 0.99``: the values the setting sets."""
    symbols = {"epsilon": "ε", "tau": "τ", "sigma": "σ", "beta": "β"}
    values = setting.values
    return ", ".join(f"{symbols.get(k, k)} = {v:g}" if isinstance(v, float) else f"{k} = {v}"
                     for k, v in values.items()) or "default"


def scaling_figure(rows: Sequence[dict[str, Any]], variants: Sequence[dict[str, Any]]) -> Any:
    """One row of panels per learner, one line per method, against reachable states:
    median episodes to solve (log-log, 95% intervals), the same relative to the fastest
    method on each variant (the constant factors the log-log panel hides), and the
    fraction of agents solved within the budget.

    Censored medians are drawn as open triangles at the budget ("> budget"), not joined;
    the methods are spread a little along the state axis so that their bars stay apart.
    """
    import matplotlib

    if "ipykernel" not in sys.modules:  # headless, as results.plotting; a notebook keeps its own
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vdbejax.methods.registry import learner_title

    learners = list(dict.fromkeys(r["learner"] for r in rows))
    explorers = list(dict.fromkeys(r["explorer"] for r in rows))
    colors = {e: plt.get_cmap("tab10")(i % 10) for i, e in enumerate(explorers)}
    height = 3.9 * len(learners) + 0.9
    fig, axes = plt.subplots(len(learners), 3, figsize=(17, height), squeeze=False)
    budgets = [(v["states"], v["episodes_reached"]) for v in variants if v["episodes_reached"]]
    handles: dict[str, Any] = {}
    bars = {"capsize": 2, "elinewidth": 0.8, "markersize": 4}

    def column(mine: list[dict[str, Any]], key: str) -> np.ndarray:
        return np.array([r[key] for r in mine], float)

    for i, learner in enumerate(learners):
        ax_median, ax_relative, ax_fraction = axes[i]
        ran = [r for r in rows if r["learner"] == learner and r["status"] == "run"]
        fastest: dict[str, float] = {}
        for r in ran:
            if math.isfinite(r["median_episodes"]):
                fastest[r["size"]] = min(fastest.get(r["size"], math.inf), r["median_episodes"])
        for j, explorer in enumerate(explorers):
            mine = [r for r in ran if r["explorer"] == explorer]
            if not mine:
                continue
            label = (method_label(row_setting(mine[0])).split(" ", 1)[1]
                     + f" ({param_text(row_setting(mine[0]))})")
            spread = 1.0 + 0.015 * (j - (len(explorers) - 1) / 2)
            x = column(mine, "states") * spread
            median, low, budget = (column(mine, k) for k in ("median_episodes", "median_low",
                                                                "budget"))
            high = column(mine, "median_high")
            high = np.where(np.isfinite(high), high, budget)
            ok = np.isfinite(median)
            line = ax_median.errorbar(x[ok], median[ok], yerr=[median[ok] - low[ok],
                                                               high[ok] - median[ok]],
                                      color=colors[explorer], marker="o", **bars)
            handles.setdefault(label, line)
            if (~ok).any():
                ax_median.plot(x[~ok], budget[~ok], linestyle="none", marker="^",
                               markerfacecolor="none", color=colors[explorer])
            scale = np.array([fastest.get(r["size"], math.nan) for r in mine])
            ax_relative.errorbar(x[ok], median[ok] / scale[ok],
                                 yerr=[(median[ok] - low[ok]) / scale[ok],
                                       (high[ok] - median[ok]) / scale[ok]],
                                 color=colors[explorer], marker="o", **bars)
            fraction = column(mine, "fraction_solved")
            ax_fraction.errorbar(x, fraction, yerr=[fraction - column(mine, "fraction_low"),
                                                    column(mine, "fraction_high") - fraction],
                                 color=colors[explorer], marker="o", alpha=0.85, **bars)
        if budgets:
            bx, by = zip(*budgets, strict=True)
            (budget_line,) = ax_median.plot(bx, by, color="0.6", linestyle=":")
            handles.setdefault("budget (open ▲: median > budget)", budget_line)
        title = learner_title(learner)
        ax_median.set(xscale="log", yscale="log", xlabel="reachable states",
                      ylabel="median episodes to solve", title=f"{title}: episodes to solve")
        ax_relative.set(xscale="log", xlabel="reachable states",
                        ylabel="median / fastest method's median",
                        title=f"{title}: relative to the fastest method")
        ax_fraction.set(xscale="log", ylim=(-0.05, 1.05), xlabel="reachable states",
                        ylabel="fraction of agents solved",
                        title=f"{title}: solved within the budget")
        for ax in (ax_median, ax_relative, ax_fraction):
            ax.grid(alpha=0.3, which="both")
    fig.legend(list(handles.values()), list(handles.keys()), loc="lower center",
               ncol=min(5, len(handles)), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.9 / height + 0.02, 1, 1))
    return fig


__all__ = [
    "CSV_FILE",
    "FIGURE_FILE",
    "MARKDOWN_FILE",
    "META_FILE",
    "ROW_COLUMNS",
    "RUNS_FOLDER",
    "VARIANT_COLUMNS",
    "growth_exponents",
    "load_scaling",
    "method_label",
    "param_text",
    "scaling_figure",
    "scaling_markdown",
    "write_reports",
]
