"""Chunks bounded by steps as well as episodes: a chunk of very long episodes runs in
pieces of ``EngineOptions.chunk_steps``, each handed to ``on_chunk``, so a checkpoint may
fall mid-episode (each agent's state, step count, partial return, random-stream position,
pending reset and the running episode's count of optimal actions); a run resumed from
one equals the uninterrupted run bit for bit, under both strategies."""
from __future__ import annotations

import functools

import jax
import numpy as np
import pytest

from vdbejax import engine
from vdbejax.engine import chunk_loop
from vdbejax.envs import make_tabular_mdp
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.runs import RunOptions, plan, run_grid

SETTINGS = [Setting("qlearning", "egreedy", 0.001), Setting("sarsa", "vdbe", 1.0)]
STEPS = 700  # loop iterations of a piece


def long_episodes():
    """One state: action 0 stays with reward 0, action 1 stays with reward 1, action 2
    ends the episode with reward 0: once the agents prefer to stay, only exploration ends
    an episode before the limit of 4000 steps cuts it."""
    return make_tabular_mdp(next_state=[[0, 0, 0]], reward=[[0.0, 1.0, 0.0]],
                            terminal=[[False, False, True]], start_probability=[1.0],
                            max_steps=4000, name="long_episodes")


def _engine_run(strategy, episodes, **kwargs):
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in SETTINGS]), 2)
    keys = np.tile(engine.agent_keys(4, 2), (len(SETTINGS), 1))
    return engine.run_agents(long_episodes(), params, keys, episodes, engine.EngineOptions(
        strategy=strategy, chunk_episodes=2, chunk_steps=STEPS), **kwargs)


@pytest.mark.parametrize("strategy", ["sequential", "lockstep"])
def test_the_engine_resumes_from_a_piece_that_ended_mid_episode(monkeypatch, strategy):
    monkeypatch.setattr(chunk_loop, "PIECE_SECONDS", 0.0)  # every piece handed out
    mask = np.array([[False, True, False]])
    pieces = []

    def keep(done, agents, *episodes):
        pieces.append((np.array(done), jax.tree.map(np.array, agents),
                       *(array.copy() for array in episodes)))

    whole = _engine_run(strategy, 5, optimal_action=mask,
                        hooks=engine.ChunkHooks(on_chunk=keep))
    assert whole.strategy == strategy
    middle = [p for p in pieces if p[0].ndim and (p[1].episode_length > 0).any()]
    assert len(middle) > 3  # pieces that ended mid-episode
    for point in middle[:: max(1, len(middle) // 3)]:
        resumed = _engine_run(strategy, 5, optimal_action=mask, initial=point)
        for field in ("returns", "lengths", "cut", "optimal", "nonfinite"):
            np.testing.assert_array_equal(getattr(resumed, field), getattr(whole, field))
        for a, b in zip(jax.tree.leaves(resumed.final_state),
                        jax.tree.leaves(whole.final_state), strict=True):
            np.testing.assert_array_equal(a, b)
    assert whole.cut.any() and (~whole.cut & (whole.lengths > 0)).any()


def test_both_strategies_run_the_same_pieces_to_the_same_bits():
    runs = [_engine_run(strategy, 4) for strategy in ("sequential", "lockstep")]
    for field in ("returns", "lengths", "cut"):
        np.testing.assert_array_equal(getattr(runs[0], field), getattr(runs[1], field))


class Interrupted(Exception):
    pass


@pytest.mark.parametrize("strategy", ["sequential", "lockstep"])
def test_a_run_stopped_mid_episode_resumes_from_its_checkpoint_bit_identically(
        tmp_path, monkeypatch, strategy):
    monkeypatch.setattr(chunk_loop, "PIECE_SECONDS", 0.0)
    monkeypatch.setattr(plan, "EngineOptions",
                        functools.partial(engine.EngineOptions, chunk_steps=STEPS))
    run = RunOptions(strategy=strategy, progress=False, record_optimal=True)
    grid = dict(num_seeds=2, num_episodes=3, seed=1)
    whole = run_grid(long_episodes(), SETTINGS, run=run, **grid)
    checkpoint = tmp_path / "c.npz"
    calls = []

    def stop_at_the_twelfth(done, total, elapsed):
        calls.append(done)
        if len(calls) == 12:  # after the checkpoint of the 11th piece
            raise Interrupted

    with pytest.raises(Interrupted):
        run_grid(long_episodes(), SETTINGS, run=run.replace(
            checkpoint=checkpoint, progress=stop_at_the_twelfth), **grid)
    with np.load(checkpoint) as data:
        assert (data["agent_episode_length"] > 0).any()  # it fell mid-episode
        assert (data["episodes_done"] < 3).any()
    resumed = run_grid(long_episodes(), SETTINGS, run=run.replace(
        checkpoint=checkpoint, resume=True), **grid)
    assert resumed.meta["resumed_from_agent_episodes"] > 0
    for field in ("returns", "lengths", "truncated", "optimal_actions", "nonfinite"):
        np.testing.assert_array_equal(getattr(resumed, field), getattr(whole, field))
