"""MushroomRL peer: the table-cleaning task through MushroomRL's own tabular agents.

What a researcher gets from an off-the-shelf RL library for this experiment: the task as a
MushroomRL :class:`~mushroom_rl.environments.FiniteMDP` (built from vdbejax's tabular MDP,
:func:`vdbejax.envs.table_cleaning.make_mdp`), MushroomRL's ``QLearning`` / ``SARSA`` with
its ``EpsGreedy`` / ``Boltzmann`` policies, trained through its ``Core``
(``core.learn(n_episodes=..., n_steps_per_fit=1)``: one TD update per step, as in the
paper). The returns of the training episodes are summed from the samples passed to
``Core``'s ``callback_step``.

Mapping of the semantics (checked against vdbejax's in ``tests/test_benchmarks_peers.py``):

* **Terminal transitions.** ``FiniteMDP`` flags a step as absorbing when the *next state*
  has no outgoing transition; in the table-cleaning task an episode ends on a
  *transition* (a failure leaves the state as it was, e.g. ``abort``). So the environment
  has ``2 S`` states: ``0 … S-1`` are the task's states, ``S + s`` is an absorbing copy of
  state ``s`` (all its transition probabilities zero). A terminal transition to ``s`` goes
  to ``S + s`` with the transition's reward; the learners then do not bootstrap, like
  vdbejax. ``state % S`` is vdbejax's next state.
* **Truncation.** ``MDPInfo.horizon`` = the MDP's ``max_steps`` (100): ``Core`` ends the
  episode after 100 steps with ``absorbing`` false, so the last update bootstraps, as the
  spec's truncation does.
* **SARSA.** MushroomRL draws the next action inside the update (before ``Q(s, a)``
  changes) and uses it as the next step's action; ``Core.reset`` clears it, so every
  episode's first action is drawn in the start state: the same order as vdbejax's.
* **ε-greedy.** ``EpsGreedy(ε)``: with probability ε a uniform action among all 7 (the
  greedy one included), else a greedy action, ties broken uniformly: vdbejax's ε-greedy
  with ``tie_break="random"``.
* **Softmax.** ``Boltzmann(β)`` is parameterised by the *inverse* temperature:
  ``β = 1/τ`` gives vdbejax's ``softmax(τ)`` (``exp(β q - max β q)``, normalised).
* **Learning rate and discount.** A constant ``Parameter(α)`` with α = ``PAPER_ALPHA``
  (0.8); γ = ``PAPER_GAMMA`` (0.9), the ``FiniteMDP``'s discount, which MushroomRL's TD
  learners read from ``MDPInfo``; Q starts at 0 (MushroomRL's ``Table``).
* **Random numbers.** MushroomRL draws from NumPy's global ``np.random``; each agent
  re-seeds it (``np.random.seed(seed)``) before it starts, so an agent's run depends on
  its seed alone.

MushroomRL has no VDBE / VDBE-Softmax explorer: :func:`covered` keeps the ε-greedy and
softmax settings (2 learners × (5 ε + 6 τ) = 22 of the paper's 46).

mushroom-rl is a dependency of the ``benchmarks`` extra only; :mod:`vdbejax` never
imports it.
"""
from __future__ import annotations

import numpy as np

from vdbejax.methods.learners import PAPER_ALPHA, PAPER_GAMMA

#: vdbejax explorer names MushroomRL has a policy for.
COVERED_EXPLORERS = ("egreedy", "softmax")


def covered(settings):
    """The settings MushroomRL can run (ε-greedy and softmax)."""
    return [s for s in settings if s.explorer in COVERED_EXPLORERS]


def finite_mdp_arrays(mdp):
    """``(p, r, mu)`` of MushroomRL's ``FiniteMDP`` for a vdbejax ``TabularMDP``.

    ``p`` and ``r`` are ``[2S, A, 2S]``; states ``S … 2S-1`` are absorbing copies of
    ``0 … S-1`` that the terminal outcomes lead to (see the module docstring).

    Raises:
      ValueError: two outcomes of one state-action reach the same environment state with
        different rewards (``FiniteMDP`` keeps one reward per ``(s, a, s')``).
    """
    next_state = np.asarray(mdp.next_state, np.int64)
    probability = np.asarray(mdp.probability, np.float64)
    reward = np.asarray(mdp.reward, np.float64)
    terminal = np.asarray(mdp.terminal, bool)
    num_states, num_actions, num_outcomes = next_state.shape
    size = 2 * num_states
    p = np.zeros((size, num_actions, size))
    r = np.zeros((size, num_actions, size))
    seen = np.zeros((size, num_actions, size), bool)
    for s in range(num_states):
        for a in range(num_actions):
            for k in range(num_outcomes):
                prob = probability[s, a, k]
                if prob <= 0.0:
                    continue
                target = next_state[s, a, k] + (num_states if terminal[s, a, k] else 0)
                if seen[s, a, target] and r[s, a, target] != reward[s, a, k]:
                    raise ValueError(f"state {s}, action {a}: two outcomes reach state "
                                     f"{target} with different rewards")
                seen[s, a, target] = True
                p[s, a, target] += prob
                r[s, a, target] = reward[s, a, k]
    p[:num_states] /= p[:num_states].sum(axis=2, keepdims=True)  # float32 rows → exact 1
    mu = np.zeros(size)
    mu[:num_states] = np.asarray(mdp.start_probability, np.float64)
    mu /= mu.sum()
    return p, r, mu


def make_environment(mdp=None, gamma: float = PAPER_GAMMA):
    """The task as a MushroomRL ``FiniteMDP`` (default: vdbejax's table-cleaning MDP)."""
    from mushroom_rl.environments import FiniteMDP

    if mdp is None:
        from vdbejax.envs.table_cleaning import make_mdp

        mdp = make_mdp()
    p, r, mu = finite_mdp_arrays(mdp)
    return FiniteMDP(p, r, mu, gamma=gamma, horizon=int(mdp.max_steps))


def make_agent(env, learner: str, explorer: str, param: float, alpha: float = PAPER_ALPHA):
    """MushroomRL's ``QLearning`` / ``SARSA`` with ``EpsGreedy(ε)`` / ``Boltzmann(1/τ)``."""
    from mushroom_rl.algorithms.value import SARSA, QLearning
    from mushroom_rl.policy import Boltzmann, EpsGreedy
    from mushroom_rl.utils.parameters import Parameter

    if explorer == "egreedy":
        policy = EpsGreedy(epsilon=Parameter(value=float(param)))
    elif explorer == "softmax":
        policy = Boltzmann(beta=Parameter(value=1.0 / float(param)))  # β = 1/τ
    else:
        raise ValueError(f"MushroomRL has no {explorer!r} explorer (only {COVERED_EXPLORERS})")
    cls = {"qlearning": QLearning, "sarsa": SARSA}[learner]
    return cls(env.info, policy, learning_rate=Parameter(value=float(alpha)))


class EpisodeReturns:
    """``Core`` step callback: the undiscounted return and length of every episode."""

    def __init__(self):
        self.returns: list[float] = []
        self.lengths: list[int] = []
        self._total, self._steps = 0.0, 0

    def __call__(self, samples):
        for sample in samples:  # (s, a, r, s', absorbing, last)
            self._total += float(sample[2])
            self._steps += 1
            if sample[5]:
                self.returns.append(self._total)
                self.lengths.append(self._steps)
                self._total, self._steps = 0.0, 0


def train_agent(learner: str, explorer: str, param: float, seed: int, episodes: int, *,
                alpha: float = PAPER_ALPHA, gamma: float = PAPER_GAMMA, env=None):
    """Train one MushroomRL agent; return ``(returns, lengths)`` lists, one per episode."""
    from mushroom_rl.core import Core

    env = env if env is not None else make_environment(gamma=gamma)
    np.random.seed(seed)
    agent = make_agent(env, learner, explorer, param, alpha)
    record = EpisodeReturns()
    core = Core(agent, env, callback_step=record)
    core.learn(n_episodes=episodes, n_steps_per_fit=1, quiet=True)
    assert len(record.returns) == episodes, (len(record.returns), episodes)
    return record.returns, record.lengths
