"""Figures: the paper's Figure 3 (one panel per learner × explorer)."""
from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")  # headless by default; notebooks may switch backends themselves
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vdbejax.agents import PARAMETER_NAMES  # noqa: E402
from vdbejax.analysis import WINDOW, moving_average  # noqa: E402
from vdbejax.experiment import GridResult  # noqa: E402

EXPLORER_TITLES = {
    "egreedy": "ε-greedy",
    "softmax": "softmax",
    "vdbe": "VDBE",
    "vdbe_softmax": "VDBE-Softmax",
}
LEARNER_TITLES = {"qlearning": "Q-learning", "sarsa": "SARSA"}
PARAMETER_SYMBOLS = {"epsilon": "ε", "tau": "τ", "sigma": "σ"}


def figure3(
    result: GridResult,
    best_return: float | None = None,
    window: int = WINDOW,
    path: str | os.PathLike | None = None,
) -> plt.Figure:
    """Average return per episode (moving average over ``window``), one curve per parameter.

    Args:
      result: the grid.
      best_return: reference line (the best possible return), if given.
      window: smoothing window (the paper: 20).
      path: save the figure there (PNG) if given.

    Returns:
      the matplotlib figure.
    """
    learners = list(dict.fromkeys(s.learner for s in result.settings))
    explorers = list(dict.fromkeys(s.explorer for s in result.settings))
    fig, axes = plt.subplots(
        len(learners), len(explorers), figsize=(4.2 * len(explorers), 3.4 * len(learners)),
        sharex=True, sharey=True, squeeze=False,
    )
    episodes = np.arange(1, result.num_episodes + 1)
    for row, learner in enumerate(learners):
        for col, explorer in enumerate(explorers):
            ax = axes[row, col]
            indices = result.select(learner, explorer)
            colors = plt.cm.viridis(np.linspace(0, 0.9, max(len(indices), 1)))
            for color, c in zip(colors, indices):
                curve = moving_average(result.returns[c].mean(0), window)
                symbol = PARAMETER_SYMBOLS[PARAMETER_NAMES[explorer]]
                ax.plot(episodes, curve, color=color, lw=1.2, label=f"{symbol}={result.settings[c].param:g}")
            if best_return is not None:
                ax.axhline(best_return, color="crimson", ls="--", lw=1, label=f"best {best_return:.2f}")
            ax.set_title(f"{LEARNER_TITLES.get(learner, learner)} — {EXPLORER_TITLES.get(explorer, explorer)}")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="lower right")
            if row == len(learners) - 1:
                ax.set_xlabel("episode")
            if col == 0:
                ax.set_ylabel(f"average return (MA {window})")
    fig.suptitle(
        f"{result.meta.get('mdp', 'task')}: {result.num_seeds} agents × {result.num_episodes} episodes"
    )
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig
