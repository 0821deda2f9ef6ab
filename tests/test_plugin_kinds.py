"""Kinds of agent stay apart: plug-in classes with the same fields never share a program."""
import jax
import numpy as np

from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.experiment import run_grid
from vdbejax.methods import Setting, make_agent


def test_classes_with_the_same_fields_have_different_tree_structures():
    # jax.tree_util.register_dataclass gives Q-learning and SARSA (same fields) equal
    # structures, so JAX's caches could run one's program for the other (it happened,
    # intermittently); vdbejax's pytree dataclasses keep the class in the structure.
    q = make_agent(Setting("qlearning", "egreedy", 0.1))
    sarsa = make_agent(Setting("sarsa", "egreedy", 0.1))
    assert jax.tree.structure(q) != jax.tree.structure(sarsa)


def test_each_kind_runs_its_own_rule_inside_a_mixed_grid():
    mdp = make_mdp(max_steps=30)
    settings = [Setting("qlearning", "softmax", 0.1), Setting("sarsa", "softmax", 0.1),
                Setting("qlearning", "vdbe", 1.0), Setting("sarsa", "vdbe", 1.0)]
    grid = run_grid(mdp, settings, num_seeds=3, num_episodes=40, seed=5)
    for c, setting in enumerate(settings):
        alone = run_grid(mdp, [setting], num_seeds=3, num_episodes=40, seed=5)
        np.testing.assert_array_equal(grid.returns[c], alone.returns[0])
    # Same hyperparameters and keys, other learner: other curves.
    assert not np.array_equal(grid.returns[0], grid.returns[1])
