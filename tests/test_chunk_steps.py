"""Chunks bounded by steps as well as episodes: the sequential strategy's native calls stop
after ``EngineOptions.chunk_steps`` loop iterations, mid-episode if need be, so that a stop
waits for one call, not for a chunk of very long episodes; the results do not change."""
from __future__ import annotations

import os
import signal

import jax
import numpy as np
import pytest

from vdbejax import engine
from vdbejax.engine import sequential
from vdbejax.envs import make_tabular_mdp
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import Setting, make_agent, stack_agents

SETTINGS = [Setting("sarsa", "vdbe", 0.001), Setting("qlearning", "vdbe_softmax", 1.0),
            Setting("qlearning", "egreedy", 0.1)]


def _grid(settings, seeds: int):
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in settings]), seeds)
    keys = np.tile(engine.agent_keys(0, seeds), (len(settings), 1))
    return params, keys


def _same(a: engine.RunResult, b: engine.RunResult) -> None:
    for x, y in zip(jax.tree.leaves((a.returns, a.lengths, a.optimal, a.final_state,
                                     a.nonfinite)),
                    jax.tree.leaves((b.returns, b.lengths, b.optimal, b.final_state,
                                     b.nonfinite)), strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.iterations == b.iterations


def _one_state(max_steps: int):
    """One state, one action that stays there with reward 1: an episode lasts its
    ``max_steps`` (truncated)."""
    return make_tabular_mdp(np.zeros((1, 1), int), np.ones((1, 1)), np.zeros((1, 1), bool),
                            np.ones(1), max_steps=max_steps)


@pytest.mark.parametrize("threads", [1, 2])
def test_calls_that_end_mid_episode_give_the_same_bits(threads):
    mdp = make_mdp()
    params, keys = _grid(SETTINGS, 5)
    mask = np.random.default_rng(0).random((mdp.num_states, mdp.num_actions)) < 0.5
    runs = [engine.run_agents(mdp, params, keys, 30, engine.EngineOptions(
        strategy="sequential", threads=threads, chunk_episodes=chunk, chunk_steps=steps),
        optimal_action=mask) for chunk, steps in [(30, sequential.CHUNK_STEPS), (30, 1),
                                                   (7, 13), (11, 500)]]
    assert runs[0].strategy == "sequential"
    for run in runs[1:]:
        _same(run, runs[0])


def test_a_long_episode_runs_in_calls_of_at_most_chunk_steps(monkeypatch):
    calls = []
    real = sequential.SequentialRun._arguments

    def counted(self, *args):
        calls.append(1)
        return real(self, *args)

    monkeypatch.setattr(sequential.SequentialRun, "_arguments", counted)
    mdp = _one_state(20_000)
    params, keys = _grid([Setting("qlearning", "egreedy", 0.1)], 1)
    whole = engine.run_agents(mdp, params, keys, 2, engine.EngineOptions(strategy="sequential"))
    calls.clear()
    cut = engine.run_agents(mdp, params, keys, 2, engine.EngineOptions(
        strategy="sequential", chunk_steps=1000))
    _same(cut, whole)
    assert whole.lengths.tolist() == [[20_000, 20_000]]
    assert len(calls) >= 2 * 20_000 // 1000  # the chunk's 40,001 iterations, 1000 a call


@pytest.mark.parametrize("seeds, threads", [(1, 1), (4, 2)])
def test_a_stop_during_a_long_episode_is_honoured_after_one_call(monkeypatch, seeds, threads):
    # Ctrl-C: Python raises KeyboardInterrupt in the main thread once it runs Python again,
    # between two native calls; a call lasts at most chunk_steps iterations, however long
    # the episode (here 2·10⁹ steps: hours).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    calls = []
    real = sequential.SequentialRun._arguments

    def stop_at_the_third(self, *args):
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGINT)
        return real(self, *args)

    monkeypatch.setattr(sequential.SequentialRun, "_arguments", stop_at_the_third)
    mdp = _one_state(2_000_000_000)
    params, keys = _grid([Setting("qlearning", "egreedy", 0.1)], seeds)
    try:
        with pytest.raises(KeyboardInterrupt):
            engine.run_agents(mdp, params, keys, 1, engine.EngineOptions(
                strategy="sequential", threads=threads, chunk_steps=10_000))
    finally:
        signal.signal(signal.SIGINT, previous)
    # The program is got first (one call of shapes), then native calls of 10,000
    # iterations: the stop came after the few calls the workers made while the main thread
    # woke up, of the episode's 200,000.
    assert 3 <= len(calls) <= (3 if threads == 1 else 100)


def test_chunk_steps_is_checked_in_one_line():
    with pytest.raises(ValueError, match="chunk_steps=0 is invalid"):
        engine.EngineOptions(chunk_steps=0)


def test_a_stop_in_the_lockstep_strategys_thread_pool_waits_for_one_block_a_group(
        monkeypatch):
    # Two kinds, two groups on two threads: a stop in the main thread stops both groups at
    # their next block of block_iterations, not at the end of the chunk.
    from vdbejax.engine import programs as programs_module

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    calls = []
    real_get = programs_module.Programs.get

    def counted_get(self, fn, *args, **kwargs):
        executable = real_get(self, fn, *args, **kwargs)

        def call(*call_args):
            calls.append(1)
            if len(calls) == 6:
                os.kill(os.getpid(), signal.SIGINT)
            return executable(*call_args)

        return call

    monkeypatch.setattr(programs_module.Programs, "get", counted_get)
    mdp = _one_state(2_000_000_000)
    params, keys = _grid([Setting("qlearning", "egreedy", 0.1),
                          Setting("sarsa", "softmax", 1.0)], 2)
    try:
        with pytest.raises(KeyboardInterrupt):
            engine.run_agents(mdp, params, keys, 1, engine.EngineOptions(
                strategy="lockstep", threads=2, mix_kinds=False, block_iterations=1000))
    finally:
        signal.signal(signal.SIGINT, previous)
    # The few blocks the groups ran while the main thread woke up, of the episode's 2·10⁶.
    assert 6 <= len(calls) <= 1000
