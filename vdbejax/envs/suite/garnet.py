"""Random MDPs: the Garnet family, a generator of instances (an instance per agent).

A Garnet MDP (Archibald, McKinnon & Thomas 1995, "On the generation of Markov decision
processes", JORS 46; named in Bhatnagar, Sutton, Ghavamzadeh & Lee 2009, "Natural
actor-critic algorithms", Automatica 45) has ``S`` states and ``A`` actions; each pair
leads to ``branching`` distinct next states chosen uniformly, with probabilities from
``branching − 1`` uniform cuts of [0, 1]; here each pair pays a reward uniform in [0, 1),
episodes start in state 0 and are truncated after ``max_steps`` steps (no terminal
state). :func:`garnet_family` draws instance ``entropy`` with NumPy's ``default_rng``.
"""
from __future__ import annotations

import numpy as np

from vdbejax.envs.instances import TaskFamily
from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp
from vdbejax.validation import INT32_MAX, check_int


def make_garnet(states: int, actions: int, branching: int, entropy: tuple[int, ...], *,
                max_steps: int, name: str = "garnet") -> TabularMDP:
    """The Garnet instance drawn from the integers ``entropy``.

    Raises:
      ValueError: a size that is not an integer ≥ 1, or ``branching`` above ``states``.
    """
    check_int("states", states, 1, 2**16)
    check_int("actions", actions, 1, 2**16)
    check_int("branching", branching, 1, states)
    check_int("max_steps", max_steps, 1, INT32_MAX)
    rng = np.random.default_rng([*entropy, states, actions, branching])
    shape = (states, actions, branching)
    next_state = np.empty(shape, np.int64)
    for s in range(states):
        for a in range(actions):
            next_state[s, a] = rng.choice(states, branching, replace=False)
    cuts = np.sort(rng.random((states, actions, branching - 1)), axis=-1)
    edges = np.concatenate([np.zeros((states, actions, 1)), cuts,
                            np.ones((states, actions, 1))], -1)
    probability = np.diff(edges, axis=-1)
    reward = np.repeat(rng.random((states, actions, 1)), branching, axis=-1)
    start = np.zeros(states)
    start[0] = 1.0
    return make_tabular_mdp(next_state, reward, np.zeros(shape, bool), start, probability,
                            max_steps=max_steps, name=name)


def garnet_family(states: int, actions: int, branching: int = 2, *, max_steps: int = 20,
                  name: str | None = None) -> TaskFamily:
    """Garnet MDPs of these sizes as a generator of instances
    (:class:`~vdbejax.envs.instances.TaskFamily`; pass it to ``run_grid`` in place of a
    task: every agent meets the instance of its root seed and seed index)."""
    label = name or f"garnet:{states}x{actions}x{branching}"
    make_garnet(states, actions, branching, (0,), max_steps=max_steps, name=label)  # checks

    def generate(entropy: tuple[int, ...]) -> TabularMDP:
        return make_garnet(states, actions, branching, entropy, max_steps=max_steps,
                           name=label)

    return TaskFamily(label, generate, f"Garnet MDPs, {states} states, {actions} actions,"
                      f" branching {branching}, horizon {max_steps}, an instance per agent")
