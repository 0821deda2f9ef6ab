"""A synthetic GridResult (no training) for the figure and CLI tests: the paper's 46
settings with smooth, seed-dependent learning curves."""
from __future__ import annotations

import numpy as np

from vdbejax.methods.agents import paper_settings
from vdbejax.results.grid_result import GridResult

BEST = 0.86
#: The uniformly random policy's expected return (the paper's task: −1.047).
RANDOM = -1.05


def synthetic_grid(seeds: int = 4, episodes: int = 120, seed: int = 0) -> GridResult:
    """Curves rising from −1 towards a setting-dependent level, plus noise."""
    rng = np.random.default_rng(seed)
    settings = paper_settings()
    levels = np.linspace(-1.0, BEST, len(settings))
    t = np.arange(episodes)
    rise = 1.0 - np.exp(-t / 20.0)
    returns = (-1.0 + (levels[:, None, None] + 1.0) * rise
               + rng.normal(0, 0.05, (len(settings), seeds, episodes))).astype(np.float32)
    lengths = rng.integers(15, 101, (len(settings), seeds, episodes)).astype(np.int32)
    meta = {"mdp": "table_cleaning", "num_seeds": seeds, "num_episodes": episodes, "seed": seed,
            "max_steps": 100, "options": {}, "best_return": BEST,
            "random_return": RANDOM}
    return GridResult(settings, returns, lengths, np.zeros((len(settings), seeds), bool), meta)
