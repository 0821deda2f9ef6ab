"""Figures: the paper's Figure 3 (one panel per learner × explorer, optional bootstrap
bands), the parameter-sensitivity plot, the % optimal action beside the average reward
(Sutton & Barto's Figure 2.2), and ε(s) heatmaps.

Every function returns the matplotlib figure and, given ``path``, saves it as PNG. The
figures serve any grid: titles wrap to the figure's width, legends sit outside the data
(right of each panel; the sensitivity plot's one legend below its panels), curves get one
of :data:`COLORS` (Okabe–Ito, colour-blind safe) and, past seven in a panel, a line style
of :data:`LINE_STYLES` as well (21 distinct curves), and a legend shows only the values
that vary within its panel.
"""
from __future__ import annotations

import json
import os
import sys
import textwrap
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import matplotlib

if "ipykernel" not in sys.modules:  # headless by default; keep a notebook's inline backend
    matplotlib.use("Agg")
import matplotlib.pyplot as plt
import matplotlib.ticker
import numpy as np

from vdbejax.methods.agents import parameter_name
from vdbejax.methods.registry import EXPLORERS, explorer_title, learner_title
from vdbejax.results.curves import WINDOW, convolve_full
from vdbejax.results.grid_result import GridResult
from vdbejax.results.optimal_actions import step_curves
from vdbejax.results.stats import CurveStatistics, curve_statistics
from vdbejax.results.summary import SummaryRow, summary_rows
from vdbejax.validation import check_choice

#: Figure 3's smoothing conventions (:func:`figure3`).
SMOOTHINGS = ("trailing", "authors")
PARAMETER_SYMBOLS = {"epsilon": "ε", "tau": "τ", "sigma": "σ", "alpha": "α", "gamma": "γ",
                     "delta": "δ"}


#: Curve colours: the Okabe–Ito palette without its yellow (too pale on white).
COLORS = ("#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#000000")
#: Line styles that extend the colours past seven curves in one panel.
LINE_STYLES = ("-", "--", ":")
#: The reference line of the best possible return (grey, so that it is no curve's colour).
BEST_STYLE = {"color": "0.45", "ls": (0, (6, 3)), "lw": 1.0}
#: Characters per inch of a title at its size (for wrapping; a little conservative).
_TITLE_CHARS_PER_INCH = {12: 9.0, 10: 11.0}


def curve_style(index: int) -> dict[str, Any]:
    """Colour and line style of a panel's ``index``-th curve (distinct for 21 curves)."""
    return {"color": COLORS[index % len(COLORS)],
            "ls": LINE_STYLES[(index // len(COLORS)) % len(LINE_STYLES)]}


def _wrap(text: str, width_inches: float, size: int) -> str:
    return "\n".join(textwrap.wrap(text, max(int(width_inches * _TITLE_CHARS_PER_INCH[size]),
                                              12), break_long_words=False))


def _legend_outside(ax: plt.Axes, containing: str = "") -> None:
    """The axes' legend right of its data region (the layout makes room for it), of the
    entries whose label contains ``containing`` (all by default)."""
    entries = [(handle, label) for handle, label in zip(*ax.get_legend_handles_labels(),
                                                        strict=True) if containing in label]
    if entries:
        handles, labels = zip(*entries, strict=True)
        ax.legend(handles, labels, fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0),
                  borderaxespad=0.0, frameon=False)


def _symbol(name: str) -> str:
    return PARAMETER_SYMBOLS.get(name, name)


def curve_label(setting: Any, varying: Sequence[str]) -> str:
    """A curve's legend: the values that vary within its panel (its parameter by default)."""
    values = setting.values
    names = [n for n in varying if n in values] or list(values)[:1]
    return ", ".join(f"{_symbol(n)}={_fmt(values[n])}" for n in names) or setting.label


def curve_width(index: int, curves: int) -> float:
    """Line width of a panel's ``index``-th of ``curves`` curves, 2.4 down to 0.8 points:
    curves that coincide (the paper's VDBE-Softmax ones) show as nested colour stripes."""
    return 1.2 if curves <= 1 else 2.4 - 1.6 * index / (curves - 1)


def _fmt(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def figure3(
    result: GridResult,
    best_return: float | None = None,
    window: int = WINDOW,
    path: str | os.PathLike | None = None,
    bands: bool = False,
    statistics: CurveStatistics | None = None,
    smoothing: str = "trailing",
) -> plt.Figure:
    """Average return per episode (moving average over ``window``), one curve per parameter.

    Args:
      result: the grid.
      best_return: reference line (the best possible return), if given.
      window: smoothing window (the paper: 20).
      path: save the figure there (PNG) if given.
      bands: shade each curve's pointwise 95% bootstrap interval over seeds.
      statistics: the curves (and, for ``bands``, their bands) already computed by
        :func:`~vdbejax.results.stats.curve_statistics` with this ``window``.
      smoothing: ``"trailing"`` (:func:`~vdbejax.results.curves.moving_average`, from episode 1)
        or ``"authors"``: as the first author's code plots Figure 3 —
        :func:`~vdbejax.results.curves.convolve_full` of the agents' mean, from episode ``window``
        to its end, the fall-off past the last episode included (no bands).

    Returns:
      the matplotlib figure.
    """
    check_choice("smoothing", smoothing, SMOOTHINGS)
    if smoothing == "authors" and bands:
        raise ValueError("bands=True is invalid with smoothing='authors': the authors' figure"
                         " has no bands")
    if statistics is None:
        statistics = curve_statistics(result.returns, window, bands=bands)
    elif statistics.window != window or len(statistics.curves) != len(result.settings) or (
            bands and statistics.band_low is None):
        raise ValueError(f"statistics (window={statistics.window}, {len(statistics.curves)} "
                         f"settings, bands={statistics.band_low is not None}) do not match "
                         f"window={window}, bands={bands} and the grid's "
                         f"{len(result.settings)} settings")
    learners = list(dict.fromkeys(s.learner for s in result.settings))
    explorers = list(dict.fromkeys(s.explorer for s in result.settings))
    width = 5.6 * len(explorers)  # a panel and its legend
    fig, axes = plt.subplots(
        len(learners), len(explorers), figsize=(width, 3.4 * len(learners) + 0.6),
        sharex=True, sharey=True, squeeze=False, layout="constrained",
    )
    episodes = np.arange(1, result.num_episodes + 1)
    if smoothing == "authors":  # full convolution, shown from episode `window` on
        episodes = np.arange(window, result.num_episodes + window)
    for row, learner in enumerate(learners):
        for col, explorer in enumerate(explorers):
            ax = axes[row, col]
            indices = result.select(learner, explorer)
            varying = _varying([result.settings[c] for c in indices])
            for k, c in enumerate(indices):
                style = curve_style(k)
                if bands:
                    # curve_statistics(bands=True) has both bands (checked above)
                    assert statistics.band_low is not None and statistics.band_high is not None
                    ax.fill_between(episodes, statistics.band_low[c], statistics.band_high[c],
                                    color=style["color"], alpha=0.18, lw=0)
                curve = statistics.curves[c] if smoothing == "trailing" else convolve_full(
                    result.returns[c].mean(0), window)[window - 1:]
                ax.plot(episodes, curve, lw=curve_width(k, len(indices)),
                        label=curve_label(result.settings[c], varying), **style)
            if best_return is not None:
                ax.axhline(best_return, label=f"best {best_return:.2f}", **BEST_STYLE)
            ax.set_title(_wrap(f"{learner_title(learner)} — {explorer_title(explorer)}", 4.0,
                               10), fontsize=10)
            ax.grid(alpha=0.3)
            if not indices:
                ax.text(0.5, 0.5, "not in this grid", ha="center", va="center",
                        transform=ax.transAxes, color="gray")
            _legend_outside(ax)
            if row == len(learners) - 1:
                ax.set_xlabel("episode")
            if col == 0:
                ax.set_ylabel(f"average return (MA {window})")
    band_note = " (bands: 95% bootstrap CI over agents)" if bands else ""
    if smoothing == "authors":
        band_note = f" (smoothed as the authors plot it: np.convolve 'full', from episode {window})"
    fig.suptitle(_wrap(f"{result.meta.get('mdp', 'task')}: {result.num_seeds} agents"
                       f" × {result.num_episodes} episodes" + band_note, width, 12))
    return _finish(fig, path)


def _varying(settings: Sequence[Any]) -> list[str]:
    """Names of the values that differ between ``settings``."""
    return _differing([s.values for s in settings])


def _differing(values: Sequence[Mapping[str, Any]]) -> list[str]:
    """Names whose value is not the same in all of ``values`` (in order of appearance)."""
    names = list(dict.fromkeys(n for v in values for n in v))
    return [n for n in names if len({repr(v.get(n)) for v in values}) > 1]


def _finish(fig: plt.Figure, path: str | os.PathLike | None) -> plt.Figure:
    if fig.get_layout_engine() is None:  # figures made without a layout (heatmaps)
        fig.tight_layout()
        # tight_layout leaves a placeholder layout engine, which makes savefig lay out and
        # draw the whole figure once more; the pixels are the same without.
        fig.set_layout_engine(None)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def _extra_values(hyperparameters: str, varying: Sequence[str]) -> str:
    """``α=0.1, γ=0.9`` of a summary row's hyperparameters (JSON), only the ``varying`` ones."""
    values = _parsed(hyperparameters)
    if "" in values:  # not JSON: shown as written
        return hyperparameters
    return ", ".join(f"{_symbol(k)}={_fmt(v)}" for k, v in values.items() if k in varying)


def _x_axis(rows: Sequence[SummaryRow]) -> str | None:
    """A sensitivity column's x axis: ``None`` (the explorer's parameter) when it takes
    several values, else the first numeric hyperparameter that does (α swept at one ε)."""
    if len({r.param for r in rows}) > 1:
        return None
    values = [_parsed(r.hyperparameters) for r in rows]
    for name in _differing(values):
        if name and all(type(v.get(name)) in (int, float) for v in values):
            return name
    return None


def _x_value(row: SummaryRow, axis: str | None) -> float:
    return row.swept_param() if axis is None else float(_parsed(row.hyperparameters)[axis])


def _line_key(row: SummaryRow, axis: str | None) -> str:
    """The hyperparameters that tell a column's lines apart (all but ``axis``), as JSON."""
    others = {k: v for k, v in _parsed(row.hyperparameters).items() if k != axis}
    return row.hyperparameters if axis is None else json.dumps(others, sort_keys=True)


def _parsed(hyperparameters: str) -> dict[str, Any]:
    """A summary row's hyperparameters (``configs.csv``'s JSON); ``{"": text}`` if not JSON."""
    try:
        return json.loads(hyperparameters) if hyperparameters else {}
    except ValueError:
        return {"": hyperparameters}


def _final_return(row: SummaryRow) -> tuple[float, float | None, float | None]:
    return row.final_return, row.final_ci_low, row.final_ci_high


def _convergence_episode(row: SummaryRow) -> tuple[float, float | None, float | None]:
    return row.convergence_episode, row.convergence_ci_low, row.convergence_ci_high


#: The sensitivity plot's rows: ``(name, axis label, (value, CI low, CI high) of a row)``.
SENSITIVITY_METRICS: tuple[tuple[str, str, Callable[[SummaryRow], tuple[float, float | None,
                                                                        float | None]]], ...] = (
    ("final_return", "final return (last 100 ep.)", _final_return),
    ("convergence_episode", "convergence episode (median)", _convergence_episode),
)
#: The legend of a sensitivity plot's censored marks (no convergence episode).
CENSORED_LABEL = "censored (> budget: half or more of the agents never converge)"
LEARNER_STYLES = {"qlearning": ("tab:blue", "o"), "sarsa": ("tab:orange", "s")}


def sensitivity(
    rows: Sequence[SummaryRow | Mapping[str, Any]],
    best_return: float | None = None,
    path: str | os.PathLike | None = None,
    title: str | None = None,
    parameter_names: Mapping[str, str] | None = None,
) -> plt.Figure:
    """Final return and convergence episode against each explorer's parameter.

    One column per explorer (x: its own parameter, or, where that takes one value, the
    hyperparameter swept beside it, e.g. α; a log axis for positive values, labelled at
    the swept values), one row per metric, one line per learner with its 95% bootstrap
    interval as error bars; one legend below the panels, which all have the same width. A
    flat line near the best return means "robust to parametrization".

    Args:
      rows: summary rows (:func:`vdbejax.results.analysis.summarize`, or mappings of their columns
        to strings or numbers as read from ``summary.csv``:
        :func:`vdbejax.results.summary.summary_rows`).
      best_return: reference line on the final-return row, if given.
      path: save the figure there (PNG) if given.
      title: figure title.
      parameter_names: ``{explorer: swept parameter's name}`` for the x labels of
        explorers not registered in this process (a grid's ``Setting.parameter``).

    Returns:
      the matplotlib figure.
    """
    swept = [r for r in summary_rows(rows) if r.param is not None]
    known = [e for e in EXPLORERS if any(r.explorer == e for r in swept)]  # built-ins first
    explorers = known + list(dict.fromkeys(r.explorer for r in swept if r.explorer not in known))
    columns = max(len(explorers), 1)
    fig, axes = plt.subplots(len(SENSITIVITY_METRICS), columns, squeeze=False,
                             figsize=(5.4 * columns, 6.4), sharey="row", layout="constrained")
    styles: dict[str, dict[str, Any]] = {}  # a line's style by its label, in every column
    if not explorers:
        axes[0, 0].text(0.5, 0.5, "no swept parameter in these settings", ha="center")
    for col, explorer in enumerate(explorers):
        mine = [r for r in swept if r.explorer == explorer]
        axis = _x_axis(mine)  # None: the explorer's parameter
        varying = [n for n in _differing([_parsed(r.hyperparameters) for r in mine])
                   if n != axis]
        column_lines = list(dict.fromkeys((r.learner, _line_key(r, axis)) for r in mine))
        for row, (key, label, metric) in enumerate(SENSITIVITY_METRICS):
            ax = axes[row, col]
            for learner, extra in column_lines:
                points = sorted((r for r in mine
                                 if r.learner == learner and _line_key(r, axis) == extra),
                                key=lambda r: _x_value(r, axis))
                x = np.array([_x_value(r, axis) for r in points])
                values = [metric(r) for r in points]
                y = np.array([value for value, _, _ in values], np.float64)
                # Intervals may be missing from older summaries: plot without error bars then.
                lows = [low for _, low, _ in values]
                highs = [high for _, _, high in values]
                has_ci = all(v is not None for v in lows + highs)
                # Censored values (+∞, "never") are not drawn as numbers: a point is marked
                # at the top edge instead, and an open upper end has no bar.
                censored = np.isinf(y)
                yerr = None
                if has_ci:
                    edges = np.array([lows, highs], np.float64)
                    yerr = np.abs(np.where(np.isinf(edges) | censored, np.nan, edges) - y)
                color, marker = LEARNER_STYLES.get(learner, (None, "o"))
                # The values beside the learner show only those that vary in the column.
                shown = _extra_values(extra, varying)
                name = learner_title(learner) + (f" {shown}" if shown else "")
                style = styles.setdefault(name, {"color": color, "ls": "-"}
                                          if color is not None and not varying
                                          else curve_style(len(styles)))
                drawn = ax.errorbar(x, np.where(censored, np.nan, y), yerr=yerr, marker=marker,
                                    ms=4, capsize=3, lw=1.2, label=name, **style)
                if censored.any():
                    ax.plot(x[censored], np.ones(int(censored.sum())), ls="none", marker="^",
                            ms=7, fillstyle="none", clip_on=False,
                            color=drawn.lines[0].get_color(), transform=ax.get_xaxis_transform(),
                            label=f"{name}: {CENSORED_LABEL}")
            if all(_x_value(r, axis) > 0 for r in mine):
                _log_axis(ax, [_x_value(r, axis) for r in mine])
            if key == "final_return" and best_return is not None:
                ax.axhline(best_return, label=f"best {best_return:.2f}", **BEST_STYLE)
            if row == 0:
                ax.set_title(_wrap(explorer_title(explorer), 4.0, 10), fontsize=10)
            if row == len(SENSITIVITY_METRICS) - 1:
                name = axis or (parameter_names or {}).get(explorer) or parameter_name(explorer)
                ax.set_xlabel(_symbol(name) + (" (log scale)" if ax.get_xscale() == "log"
                                               else ""))
            if col == 0:
                ax.set_ylabel(label)
            ax.grid(alpha=0.3, which="both")
    _legend_below(fig)
    fig.suptitle(_wrap(title or "Sensitivity to the exploration parameter (95% bootstrap CI"
                       " over agents)", 5.4 * columns, 12))
    return _finish(fig, path)


#: Tick labels of a log axis at most (:func:`_log_axis`).
LOG_TICKS = 6


def _log_axis(ax: plt.Axes, values: Sequence[float]) -> None:
    """A log x axis labelled at the swept values (``0.01``, ``20``: as written), at most
    :data:`LOG_TICKS` of them, each at least a sixth of the values' span from the one
    before: the labels never run into each other (matplotlib's own label minor ticks,
    ``2×10`` … ``6×10``, when the values span less than a decade). Minor ticks stay
    unlabelled, for the grid."""
    ax.set_xscale("log")
    points = np.unique(np.asarray(values, np.float64))
    logs = np.log10(points)
    gap = (logs[-1] - logs[0]) / LOG_TICKS
    kept = [0]
    for i in range(1, len(points)):
        if logs[i] - logs[kept[-1]] >= gap:
            kept.append(i)
    if len(kept) > 1 and kept[-1] != len(points) - 1 and logs[-1] - logs[kept[-1]] >= gap / 2:
        kept[-1] = len(points) - 1  # the largest value labelled, not its neighbour
    ax.xaxis.set_major_locator(matplotlib.ticker.FixedLocator(points[kept].tolist()))
    ax.xaxis.set_major_formatter(matplotlib.ticker.FixedFormatter(
        [_fmt(float(p)) for p in points[kept]]))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())


def _legend_below(fig: plt.Figure) -> None:
    """One legend of the figure's lines below its panels (a line has the same style in
    every panel), in as many columns as fit the figure's width: panels keep equal widths
    whatever the labels' length."""
    entries: dict[str, Any] = {}
    for ax in fig.axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    if not entries:
        return
    longest = max(len(label) for label in entries)
    fit = int(fig.get_size_inches()[0] // (0.06 * longest + 0.6))
    fig.legend(list(entries.values()), list(entries), loc="outside lower center", fontsize=7,
               ncols=max(1, min(fit, len(entries), 4)), frameon=False)


def optimal_actions_figure(result: GridResult, path: str | os.PathLike | None = None
                           ) -> plt.Figure:
    """Sutton & Barto's Figure 2.2 (2018, §2.3) for any grid run with ``record_optimal``:
    the average reward (left) and the % optimal action (right) against the pulls — or,
    where an episode is more than one pull or step, against the episodes (the reward per
    step and the % of an episode's actions that are optimal) — one curve per setting,
    each the mean over its agents
    (:func:`~vdbejax.results.optimal_actions.step_curves`), one legend below both panels.

    Args:
      result: a grid with a record of optimal actions (``GridResult.optimal_actions``).
      path: save the figure there (PNG) if given.

    Returns:
      the matplotlib figure.

    Raises:
      ValueError: the grid has no record of optimal actions.
    """
    curves = [step_curves(result, c) for c in range(len(result.settings))]
    varying = _varying(result.settings)
    pulls = int(result.meta.get("max_steps", 0)) == 1  # one pull (step) an episode
    x = np.arange(1, result.num_episodes + 1)
    fig, (reward, optimal) = plt.subplots(1, 2, figsize=(11.0, 4.4), layout="constrained")
    for c, (fraction, per_step) in enumerate(curves):
        setting = result.settings[c]
        label = f"{learner_title(setting.learner)}, {explorer_title(setting.explorer)}"
        if setting.values:
            label += f" {curve_label(setting, varying)}"
        style = dict(curve_style(c), lw=1.0)
        reward.plot(x, per_step, label=label, **style)
        optimal.plot(x, 100.0 * fraction, label=label, **style)
    reward.set_ylabel("average reward" + ("" if pulls else " per step"))
    optimal.set_ylabel("% optimal action")
    optimal.set_ylim(0.0, 100.0)
    for ax in (reward, optimal):
        ax.set_xlabel("pulls" if pulls else "episode")
        ax.grid(alpha=0.3)
    _legend_below(fig)
    fig.suptitle(_wrap(f"{result.meta.get('mdp', 'task')}: mean over {result.num_seeds}"
                       f" agents per setting", 11.0, 12))
    return _finish(fig, path)


def epsilon_heatmap(
    epsilon: np.ndarray,
    episodes: np.ndarray,
    states: np.ndarray | None = None,
    state_labels: Sequence[str] | None = None,
    ax: plt.Axes | None = None,
    title: str = "VDBE ε(s)",
    path: str | os.PathLike | None = None,
) -> plt.Figure:
    """Heatmap of per-state exploration probabilities over episodes (states × episodes).

    Args:
      epsilon: ``[snapshots, S]`` ε(s) (e.g. averaged over agents) or ``[snapshots,
        agents, S]`` (averaged here).
      episodes: ``[snapshots]`` episode count of each snapshot.
      states: state indices to show (rows), e.g. the reachable ones (default all).
      state_labels: one label per shown state.
      ax: draw into these axes (default: a new figure).
      title: axes title.
      path: save the figure there (PNG) if given.

    Returns:
      the matplotlib figure.
    """
    epsilon = np.asarray(epsilon, np.float64)
    if epsilon.ndim == 3:
        epsilon = epsilon.mean(1)
    states = np.arange(epsilon.shape[-1]) if states is None else np.asarray(states)
    if ax is None:
        fig, ax = plt.subplots(figsize=(8, max(3.0, 0.12 * len(states) + 1.5)))
    else:
        parent = ax.figure
        if not isinstance(parent, plt.Figure):  # a subfigure's axes: _finish needs a figure
            raise ValueError("ax is invalid: must be axes of a figure, not of a subfigure")
        fig = parent
    image = ax.imshow(epsilon[:, states].T, aspect="auto", origin="lower", cmap="magma",
                      vmin=0.0, vmax=1.0, interpolation="nearest",
                      extent=(0.5, len(episodes) + 0.5, -0.5, len(states) - 0.5))
    # Tick labels show episode counts, not snapshot indices.
    ticks = np.unique(np.linspace(1, len(episodes), min(len(episodes), 6)).round().astype(int))
    ax.set_xticks(ticks, [str(int(episodes[t - 1])) for t in ticks])
    if state_labels is not None and len(states) <= 60:
        ax.set_yticks(np.arange(len(states)), list(state_labels), fontsize=5)
    ax.set_xlabel("episode")
    ax.set_ylabel("state")
    ax.set_title(title)
    fig.colorbar(image, ax=ax, label="ε(s)")
    return _finish(fig, path)
