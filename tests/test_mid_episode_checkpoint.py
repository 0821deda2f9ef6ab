"""Chunks bounded by steps as well as episodes: a chunk of very long episodes runs in
pieces of ``EngineOptions.chunk_steps``, each handed to ``on_chunk``, so a checkpoint may
fall mid-episode (each agent's state, step count, partial return, random-stream position,
pending reset and the running episode's count of optimal actions); a run resumed from
one equals the uninterrupted run bit for bit, under both strategies."""
from __future__ import annotations

import dataclasses
import functools

import jax
import numpy as np
import pytest

from vdbejax import engine
from vdbejax.engine import chunk_loop
from vdbejax.engine.lockstep import LockstepOptions, run_chunk_lockstep
from vdbejax.engine.programs import Programs
from vdbejax.envs import make_tabular_mdp
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.runs import RunOptions, UntilSolved, plan, run_grid

SETTINGS = [Setting("qlearning", "egreedy", 0.001), Setting("sarsa", "vdbe", 1.0)]
STEPS = 700  # loop iterations of a piece


def long_episodes():
    """One state: action 0 stays with reward 0, action 1 stays with reward 1, action 2
    ends the episode with reward 0: once the agents prefer to stay, only exploration ends
    an episode before the limit of 4000 steps cuts it."""
    return make_tabular_mdp(next_state=[[0, 0, 0]], reward=[[0.0, 1.0, 0.0]],
                            terminal=[[False, False, True]], start_probability=[1.0],
                            max_steps=4000, name="long_episodes")


def _agents():
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in SETTINGS]), 2)
    keys = np.tile(engine.agent_keys(4, 2), (len(SETTINGS), 1))
    return params, keys


def _engine_run(strategy, episodes, compact=True, **kwargs):
    params, keys = _agents()
    return engine.run_agents(long_episodes(), params, keys, episodes, engine.EngineOptions(
        strategy=strategy, chunk_episodes=2, chunk_steps=STEPS, compact=compact), **kwargs)


# Without compaction (agents sharded over several devices) the lockstep chunk is one
# program whose loop stops after the trip that reaches ``chunk_steps`` iterations.
@pytest.mark.parametrize("strategy, compact", [("sequential", True), ("lockstep", True),
                                               ("lockstep", False)])
def test_the_engine_resumes_from_a_piece_that_ended_mid_episode(monkeypatch, strategy, compact):
    monkeypatch.setattr(chunk_loop, "PIECE_SECONDS", 0.0)  # every piece handed out
    mask = np.array([[False, True, False]])
    pieces = []

    def keep(done, agents, *episodes):
        pieces.append((np.array(done), jax.tree.map(np.array, agents),
                       *(array.copy() for array in episodes)))

    whole = _engine_run(strategy, 5, compact, optimal_action=mask,
                        hooks=engine.ChunkHooks(on_chunk=keep))
    assert whole.strategy == strategy
    middle = [p for p in pieces if p[0].ndim and (p[1].episode_length > 0).any()]
    assert len(middle) > 3  # pieces that ended mid-episode
    for point in middle[:: max(1, len(middle) // 3)]:
        resumed = _engine_run(strategy, 5, compact, optimal_action=mask, initial=point)
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


def test_pieces_bounded_in_time_give_the_same_bits():
    """On an accelerator a lockstep piece also ends after the block that passes
    ``PIECE_SECONDS``: here every block ends one, and the chunk still ends the same."""
    params, keys = _agents()
    mdp = long_episodes()
    agents = engine.init_agents(mdp, params, keys)
    options = LockstepOptions(compact=True, block_iterations=64, unroll=1, min_batch=8,
                              max_batch=8)
    whole = run_chunk_lockstep(mdp, params, agents, 0, 2, 8, options, Programs())
    timed = dataclasses.replace(options, piece_seconds=0.0)
    calls, records = 0, np.zeros((2, *whole[1].shape))
    while calls == 0 or int(np.asarray(agents.episode).min()) < 2:
        agents, returns, lengths, *_ = run_chunk_lockstep(mdp, params, agents, 0, 2, 8, timed,
                                                          Programs())
        ran = np.asarray(lengths) > 0
        records = np.where(ran, [np.asarray(returns), np.asarray(lengths)], records)
        calls += 1
    assert calls > 10  # one block a piece
    np.testing.assert_array_equal(records[0], whole[1])
    np.testing.assert_array_equal(records[1], whole[2])
    for a, b in zip(jax.tree.leaves(agents), jax.tree.leaves(whole[0]), strict=True):
        np.testing.assert_array_equal(a, b)


class Interrupted(Exception):
    pass


def _interrupted_run(run, calls, **grid):
    """``run_grid`` on the long episodes, stopped at the ``calls``-th call of its progress
    (each follows a checkpoint)."""
    seen = []

    def interrupt(done, total, elapsed):
        seen.append(done)
        if len(seen) == calls:
            raise Interrupted

    with pytest.raises(Interrupted):
        run_grid(long_episodes(), SETTINGS, run=run.replace(progress=interrupt), **grid)


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
    _interrupted_run(run.replace(checkpoint=checkpoint), 12, **grid)  # after the 11th piece
    with np.load(checkpoint) as data:
        assert (data["agent_episode_length"] > 0).any()  # it fell mid-episode
        assert (data["episodes_done"] < 3).any()
    resumed = run_grid(long_episodes(), SETTINGS, run=run.replace(
        checkpoint=checkpoint, resume=True), **grid)
    assert resumed.meta["resumed_from_agent_episodes"] > 0
    for field in ("returns", "lengths", "truncated", "optimal_actions", "nonfinite"):
        np.testing.assert_array_equal(getattr(resumed, field), getattr(whole, field))


@pytest.mark.parametrize("strategy", ["sequential", "lockstep"])
def test_a_run_until_solved_checkpoints_mid_episode_and_resumes_bit_identically(
        tmp_path, monkeypatch, strategy):
    """A stop policy's run: one engine call a chunk, its pieces checkpointed; resumed from
    a checkpoint taken mid-chunk, the agents finish the chunk and are checked together at
    its end, as without the stop."""
    monkeypatch.setattr(chunk_loop, "PIECE_SECONDS", 0.0)
    monkeypatch.setattr(plan, "EngineOptions",
                        functools.partial(engine.EngineOptions, chunk_steps=STEPS))
    stop = UntilSolved(best=4000.0, baseline=0.0, fraction=0.5, window=1)
    run = RunOptions(strategy=strategy, progress=False, stop=stop, chunk_episodes=2)
    grid = dict(num_seeds=2, num_episodes=6, seed=1)
    whole = run_grid(long_episodes(), SETTINGS, run=run, **grid)
    assert whole.episodes_run is not None and whole.episodes_run.min() < 6  # some stopped
    checkpoint = tmp_path / "c.npz"
    # Calls of progress: in the first chunk; in the second, where two agents have finished
    # it and a third runs (its checkpoint holds agents at episodes 2, 4, 4).
    for stop_after in (5, 12):
        checkpoint.unlink(missing_ok=True)
        _interrupted_run(run.replace(checkpoint=checkpoint), stop_after, **grid)
        with np.load(checkpoint) as data:
            assert (data["agent_episode_length"] > 0).any()  # it fell mid-episode
            assert len(set(data["episodes_done"][~data["stopped"]])) > 1
        resumed = run_grid(long_episodes(), SETTINGS, run=run.replace(
            checkpoint=checkpoint, resume=True), **grid)
        for field in ("returns", "lengths", "truncated", "episodes_run", "nonfinite"):
            np.testing.assert_array_equal(getattr(resumed, field), getattr(whole, field))
