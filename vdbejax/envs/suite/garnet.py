"""Random MDPs: the Garnet family, a generator of instances (an instance per agent).

A Garnet MDP (Archibald, McKinnon & Thomas 1995, "On the generation of Markov decision
processes", JORS 46; named in Bhatnagar, Sutton, Ghavamzadeh & Lee 2009, "Natural
actor-critic algorithms", Automatica 45) has ``S`` states and ``A`` actions; each pair
leads to ``branching`` distinct next states chosen uniformly, with probabilities from
``branching − 1`` uniform cuts of [0, 1]; here each pair pays a reward uniform in [0, 1),
episodes start in state 0 and are truncated after ``max_steps`` steps (no terminal
state). :func:`garnet_family` draws instance ``entropy`` with NumPy's ``default_rng``.
The suite's name ``garnet:SxAxB`` is the instance of :data:`INSTANCE_SEED`, or with
``--instances per-agent`` the family (:func:`vdbejax.envs.suite.make_suite_family`).
"""
from __future__ import annotations

import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp
from vdbejax.envs.task_instances import TaskFamily
from vdbejax.validation import INT32_MAX, check_int

#: The episode length unless a run sets another (``max_steps``): no state is terminal.
HORIZON = 20
#: The seed of the suite's named instance (``garnet:SxAxB``).
INSTANCE_SEED = 0
#: The largest number of states or actions.
MAX_SIZE = 2**16


def make_garnet(states: int, actions: int, branching: int, entropy: tuple[int, ...], *,
                max_steps: int, name: str = "garnet") -> TabularMDP:
    """The Garnet instance drawn from the integers ``entropy``.

    Raises:
      ValueError: a size that is not an integer ≥ 1, or ``branching`` above ``states``.
    """
    check_int("states", states, 1, MAX_SIZE)
    check_int("actions", actions, 1, MAX_SIZE)
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


def sizes_of(name: str, size: str) -> tuple[int, int, int] | None:
    """``(states, actions, branching)`` of the suite's name ``name`` = ``garnet:{size}``
    (``size``: ``SxAxB``, canonical decimal integers), or ``None`` when it is no such form.

    Raises:
      ValueError: sizes that :func:`make_garnet` refuses, in one line naming ``name``.
    """
    parts = size.split("x")
    if len(parts) != 3 or not all(p.isascii() and p.isdigit() and str(int(p)) == p
                                  for p in parts):
        return None
    states, actions, branching = (int(p) for p in parts)
    if not (1 <= states <= MAX_SIZE and 1 <= actions <= MAX_SIZE and 1 <= branching <= states):
        raise ValueError(f"name={name!r} is invalid: garnet:SxAxB needs 1 <= S <= {MAX_SIZE}"
                         f" states, 1 <= A <= {MAX_SIZE} actions and a branching 1 <= B <= S")
    return states, actions, branching


def garnet_family(states: int, actions: int, branching: int = 2, *, max_steps: int = HORIZON,
                  name: str | None = None, instance: int | None = None) -> TaskFamily:
    """Garnet MDPs of these sizes as a generator of instances
    (:class:`~vdbejax.envs.task_instances.TaskFamily`; pass it to ``run_grid`` in place of a
    task: every agent meets the instance of its root seed and seed index). ``instance``
    is the default instance seed (:data:`INSTANCE_SEED`: every agent the suite's named
    task)."""
    label = name or f"garnet:{states}x{actions}x{branching}"
    make_garnet(states, actions, branching, (0,), max_steps=max_steps, name=label)  # checks

    def generate(entropy: tuple[int, ...]) -> TabularMDP:
        return make_garnet(states, actions, branching, entropy, max_steps=max_steps,
                           name=label)

    return TaskFamily(label, generate, f"Garnet MDPs, {states} states, {actions} actions,"
                      f" branching {branching}, horizon {max_steps}, an instance per agent",
                      instance=instance)
