"""Agents of several kinds in one lockstep batch (issue 46, point 2): each lane runs its own
kind, and every agent gets the bits it gets kind after kind or in the sequential strategy."""
from __future__ import annotations

import jax
import numpy as np
import pytest

from vdbejax import engine
from vdbejax.engine import kinds
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.envs.task_instances import stack_instances
from vdbejax.methods.agents import AgentOptions, Setting, make_agent, stack_agents

# The paper's kinds, kinds with tables of their own (VDBE's ε, UCB1's counts, Double
# Q's second table), and a kind with a model (R-max: it runs on its own, not mixed).
SETTINGS = [
    Setting("sarsa", "vdbe", 0.001),
    Setting("qlearning", "vdbe_softmax", 1.0),
    Setting("qlearning", "egreedy", 0.1),
    Setting("sarsa", "softmax", 0.0001),
    Setting("expected_sarsa", "ucb1"),
    Setting("double_qlearning", "egreedy", 0.2),
    Setting("rmax", "greedy"),
]
SEEDS = 3


def grid(settings=SETTINGS, options=AgentOptions()):
    params = engine.broadcast_agents(stack_agents([make_agent(s, options) for s in settings]),
                                     SEEDS)
    keys = np.tile(engine.agent_keys(2, SEEDS), (len(settings), 1))
    return params, keys


def assert_same_run(a: engine.RunResult, b: engine.RunResult) -> None:
    np.testing.assert_array_equal(a.lengths, b.lengths)
    for leaf_a, leaf_b in zip(jax.tree.leaves((a.returns, a.final_state)),
                              jax.tree.leaves((b.returns, b.final_state)), strict=True):
        np.testing.assert_array_equal(leaf_a, leaf_b)


def test_kinds_mixed_in_one_batch_give_every_agent_its_bits():
    mdp = make_mdp()
    params, keys = grid(options=AgentOptions(tie_break="first"))  # the default is "random"
    sequential = engine.run_agents(mdp, params, keys, 20,
                                   engine.EngineOptions(strategy="sequential"))
    for options in ({}, {"max_batch": 4, "min_batch": 1, "chunk_episodes": 9},
                    {"compact": False}, {"fixed_blocks": True, "block_iterations": 13}):
        mixed = engine.run_agents(mdp, params, keys, 20,
                                  engine.EngineOptions(strategy="lockstep", mix_kinds=True,
                                                       **options))
        assert_same_run(sequential, mixed)


def test_blocks_of_mixed_kinds_and_kinds_that_cannot_mix(monkeypatch):
    """More kinds than a program serves mix in blocks; a kind with a model runs alone."""
    mdp = make_mdp()
    params, keys = grid()
    apart = engine.run_agents(mdp, params, keys, 15,
                              engine.EngineOptions(strategy="lockstep", mix_kinds=False))
    monkeypatch.setattr(kinds, "MAX_SWITCH_KINDS", 2)
    from vdbejax.engine.lockstep import _kind_groups

    groups = _kind_groups(params, np.asarray(params.kind), True)
    switches = [agent for agent, _ in groups if isinstance(agent, kinds.KindSwitch)]
    assert [len(s.kinds) for s in switches] == [2, 2, 2]  # six kinds mix, R-max alone
    assert sorted(np.concatenate([rows for _, rows in groups])) == list(range(len(keys)))
    mixed = engine.run_agents(mdp, params, keys, 15,
                              engine.EngineOptions(strategy="lockstep", mix_kinds=True, threads=2))
    assert_same_run(apart, mixed)
    # Kind after kind a chunk takes each kind's iterations; a block of kinds, its slowest's.
    assert mixed.iterations < apart.iterations


def test_mixed_kinds_on_an_instance_per_agent():
    from test_task_instances import random_mdp

    params, keys = grid(SETTINGS[:5])
    instances = stack_instances([random_mdp(300 + i) for i in range(len(keys))])
    sequential = engine.run_agents(instances, params, keys, 12,
                                   engine.EngineOptions(strategy="sequential"))
    mixed = engine.run_agents(instances, params, keys, 12,
                              engine.EngineOptions(strategy="lockstep", mix_kinds=True,
                                                   max_batch=8))
    assert_same_run(sequential, mixed)


def test_a_run_asks_for_mixed_kinds_and_its_plan_says_so(tmp_path):
    from vdbejax.runs import RunOptions, run_grid

    with pytest.raises(ValueError, match="mix_kinds='yes' is invalid"):
        RunOptions(mix_kinds="yes")
    # The layout of the test above (every kind, 3 seeds, 15 episodes): its kind-by-kind
    # programs serve the run that does not mix.
    runs = {mix: run_grid(make_mdp(), SETTINGS, num_seeds=SEEDS, num_episodes=15,
                          run=RunOptions(strategy="lockstep", mix_kinds=mix))
            for mix in (None, True)}
    assert runs[None].meta["plan"]["mix_kinds"] is False  # a CPU's default
    assert runs[True].meta["plan"]["mix_kinds"] is True
    np.testing.assert_array_equal(runs[None].returns, runs[True].returns)
