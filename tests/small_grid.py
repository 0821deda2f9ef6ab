"""Small, fast grids shared by the reliability tests (validation, resume, determinism,
sharding, batching): one setting per explorer and learner, few seeds and episodes."""
from __future__ import annotations

from typing import Any

from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import Setting
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import run_grid

#: One setting of every explorer, both learners.
SETTINGS = [
    Setting("qlearning", "egreedy", 0.1),
    Setting("sarsa", "softmax", 0.01),
    Setting("qlearning", "vdbe", 1.0),
    Setting("sarsa", "vdbe_softmax", 0.1),
]
SEEDS = 3
EPISODES = 24
MAX_STEPS = 20


def small_mdp():
    """The table-cleaning task with short episodes."""
    return make_mdp(max_steps=MAX_STEPS)


def run_small(**overrides: Any) -> GridResult:
    """:func:`run_grid` over the small grid; keyword arguments override its defaults."""
    options = dict(num_seeds=SEEDS, num_episodes=EPISODES, seed=3, chunk_episodes=8)
    options.update(overrides)
    mdp = options.pop("mdp", None) or small_mdp()
    settings = options.pop("settings", SETTINGS)
    return run_grid(mdp, settings, **options)


def assert_same_curves(a: GridResult, b: GridResult) -> None:
    """Bit-identical returns, lengths, cut flags and NaN flags."""
    import numpy as np

    assert a.returns.dtype == b.returns.dtype
    np.testing.assert_array_equal(a.returns, b.returns)
    np.testing.assert_array_equal(a.lengths, b.lengths)
    np.testing.assert_array_equal(a.truncated, b.truncated)
    np.testing.assert_array_equal(a.nonfinite, b.nonfinite)


def assert_fixed_budget_up_to_each_stop(stopped: Any, fixed: GridResult,
                                        stops: Any) -> None:
    """``stopped``'s curves (a GridResult or AdaptiveRun) equal ``fixed``'s bit for bit up
    to each agent's stop (``stops``: ``[configs, seeds]``), NaN returns and 0 lengths past it."""
    import numpy as np

    for (c, i), e in np.ndenumerate(stops):
        np.testing.assert_array_equal(stopped.returns[c, i, :e], fixed.returns[c, i, :e])
        np.testing.assert_array_equal(stopped.lengths[c, i, :e], fixed.lengths[c, i, :e])
        assert np.isnan(stopped.returns[c, i, e:]).all() and (stopped.lengths[c, i, e:] == 0).all()


def budget_for(mdp: Any, agents: int, chunk_episodes: int = 8) -> int:
    """The per-device memory budget that fits exactly ``agents`` agents."""
    from vdbejax.runs.batching import bytes_per_agent, mdp_bytes

    return mdp_bytes(mdp) + agents * bytes_per_agent(mdp, chunk_episodes)


def interrupt_then_resume(mdp: Any, settings: Any, run: Any, stop_at: int,
                          **grid: Any) -> GridResult:
    """Run a checkpointed grid (``run``: its RunOptions), kill it once ``stop_at``
    agent-episodes are done (an exception from its progress callback), then resume it."""
    import pytest

    from vdbejax.runs import prepare_grid, run_prepared

    class Stop(Exception):
        pass

    def stop_after(done: int, total: int, elapsed: float) -> None:
        if done >= stop_at:
            raise Stop

    with pytest.raises(Stop):
        run_prepared(prepare_grid(mdp, settings, run=run.replace(progress=stop_after), **grid))
    return run_prepared(prepare_grid(mdp, settings, run=run.replace(resume=True), **grid))
