"""Gymnasium toy-text environments as :class:`~vdbejax.envs.TabularMDP` tables.

Toy-text environments (FrozenLake, CliffWalking, Taxi, …) publish their full model in
``env.unwrapped.P``: ``P[s][a]`` is a list of ``(probability, next_state, reward,
terminated)`` outcomes. :func:`from_gymnasium` copies it into dense ``[S, A, K]`` tables
(``K`` = the most outcomes of any pair; shorter lists are padded with probability-0
outcomes), so the same engine and solvers run on it.

Semantics:

* **terminal** is gymnasium's ``terminated`` flag of each outcome (no bootstrap); the
  absorbing entries gymnasium lists for terminal states (e.g. FrozenLake's holes) are kept
  but never reached by an episode.
* **start distribution**: ``env.unwrapped.initial_state_distrib`` (all toy-text
  environments have it), or the ``start_probability`` argument.
* **max_steps**: the ``max_steps`` argument, else the ``TimeLimit``'s
  ``max_episode_steps`` (``env.spec``), which becomes a truncation (bootstraps) as in
  gymnasium.

gymnasium is an optional dependency (``pip install vdbejax[gym]``): this module imports it
only when given an environment id.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp


def _make(env: Any) -> Any:
    if not isinstance(env, str):
        if not hasattr(env, "unwrapped"):
            raise ValueError(f"env={env!r} is invalid: must be a gymnasium environment or an"
                             " environment id such as 'FrozenLake-v1'")
        return env
    try:
        import gymnasium
    except ImportError as err:  # optional extra
        raise ImportError(
            "from_gymnasium needs gymnasium: pip install 'vdbejax[gym]'"
        ) from err
    try:
        return gymnasium.make(env)
    except Exception as error:  # unknown, deprecated or unversioned ids: gymnasium's errors
        message = str(error).strip().splitlines()[0] if str(error).strip() else ""
        raise ValueError(f"env={env!r} is invalid: gymnasium cannot make it"
                         f" ({type(error).__name__}: {message})") from None


def _max_episode_steps(env: Any) -> int | None:
    """``max_episode_steps`` of the env's spec or of a ``TimeLimit`` wrapper, if any."""
    spec = getattr(env, "spec", None)
    if spec is not None and getattr(spec, "max_episode_steps", None):
        return int(spec.max_episode_steps)
    while env is not None:
        steps = getattr(env, "_max_episode_steps", None)
        if steps:
            return int(steps)
        env = getattr(env, "env", None)
    return None


def transition_tables(model: Any, num_states: int, num_actions: int
                      ) -> tuple[np.ndarray, ...]:
    """Dense ``[S, A, K]`` tables of a toy-text model ``P``.

    Args:
      model: ``P[s][a] = [(probability, next_state, reward, terminated), …]``.
      num_states: ``S``.
      num_actions: ``A``.

    Returns:
      ``(next_state, probability, reward, terminal)``; padding outcomes have probability 0
      and stay in ``s``.

    Raises:
      ValueError: a missing state or action, or an empty outcome list.
    """
    outcomes = {}
    for s in range(num_states):
        for a in range(num_actions):
            try:
                entries = model[s][a]
            except (KeyError, IndexError, TypeError):
                raise ValueError(f"env.unwrapped.P lacks state {s}, action {a}: must list"
                                 f" all {num_states} states x {num_actions} actions") from None
            if len(entries) == 0:
                raise ValueError(f"env.unwrapped.P[{s}][{a}] is empty: must list >= 1 outcome")
            outcomes[s, a] = entries
    width = max(len(entries) for entries in outcomes.values())
    shape = (num_states, num_actions, width)
    next_state = np.repeat(np.arange(num_states), num_actions * width).reshape(shape)
    probability = np.zeros(shape)
    reward = np.zeros(shape)
    terminal = np.zeros(shape, bool)
    for (s, a), entries in outcomes.items():
        for k, (p, s_next, r, done) in enumerate(entries):
            next_state[s, a, k], probability[s, a, k] = int(s_next), float(p)
            reward[s, a, k], terminal[s, a, k] = float(r), bool(done)
    return next_state, probability, reward, terminal


def from_gymnasium(
    env: Any,
    *,
    max_steps: int | None = None,
    start_probability: Any | None = None,
    name: str | None = None,
) -> TabularMDP:
    """A gymnasium toy-text environment as a validated :class:`TabularMDP`.

    Args:
      env: a gymnasium environment (wrapped or not) whose ``unwrapped`` has ``P``, or an
        environment id for ``gymnasium.make`` (e.g. ``"FrozenLake-v1"``).
      max_steps: truncation length (default: the ``TimeLimit``'s ``max_episode_steps``).
      start_probability: ``[S]`` start distribution (default:
        ``env.unwrapped.initial_state_distrib``).
      name: label (default: the env id).

    Returns:
      the MDP: state ``i`` is gymnasium's observation ``i``, action ``a`` its action ``a``.
      Deterministic models (one outcome per pair, e.g. ``is_slippery=False``) give ``K = 1``.

    Raises:
      ValueError: no transition model, non-discrete spaces, no start distribution or no
        step limit available, or tables that fail :func:`make_tabular_mdp`'s checks.
    """
    env = _make(env)
    base = env.unwrapped
    model = getattr(base, "P", None)
    if model is None:
        raise ValueError(f"env {type(base).__name__} has no transition model P:"
                         " must be a toy-text environment (FrozenLake, CliffWalking, Taxi, …)")
    num_states = getattr(base.observation_space, "n", None)
    num_actions = getattr(base.action_space, "n", None)
    if num_states is None or num_actions is None:
        raise ValueError(f"env spaces are {base.observation_space} and {base.action_space}:"
                         " must both be Discrete")
    next_state, probability, reward, terminal = transition_tables(
        model, int(num_states), int(num_actions)
    )
    if start_probability is None:
        start_probability = getattr(base, "initial_state_distrib", None)
        if start_probability is None:
            raise ValueError(f"start_probability is None and {type(base).__name__} has no"
                             " initial_state_distrib: pass start_probability ([S] floats)")
    if max_steps is None:
        max_steps = _max_episode_steps(env)
        if max_steps is None:
            raise ValueError("max_steps is None and the env has no TimeLimit"
                             " max_episode_steps: pass max_steps (an integer >= 1)")
    spec = getattr(env, "spec", None)
    label = name or (spec.id if spec is not None else type(base).__name__)
    return make_tabular_mdp(next_state, reward, terminal, np.asarray(start_probability),
                            probability, max_steps=max_steps, name=label)
