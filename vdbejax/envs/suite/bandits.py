"""k-armed bandits as tasks: one state, one action per arm, an episode of one pull (or a
fixed number of pulls), random rewards (:mod:`vdbejax.envs.reward_noise`).

* ``gaussian_bandit:k``: arm means uniform in [0, 1), rewards ``N(mean, 1)``;
* ``bernoulli_bandit:k``: arm success probabilities uniform in [0, 1), rewards 0 or 1
  (the Bernoulli bandit of Thompson-sampling studies, e.g. Chapelle & Li 2011);
* ``testbed:k``: Sutton & Barto's 10-armed testbed (2018, §2.3) at any ``k``: arm means
  ``N(0, 1)``, rewards ``N(mean, 1)``.

Each name is one instance: its arm means are drawn once from :data:`INSTANCE_SEED` and
the family (the same task in every run). The book averages over 2,000 random testbeds:
:func:`bandit_family` is the family with its generator, whose run gives every agent its
own instance (:class:`~vdbejax.envs.task_instances.TaskFamily`; ``--instances per-agent``).
"""
from __future__ import annotations

import numpy as np

from vdbejax.envs.tabular import TabularMDP, make_tabular_mdp
from vdbejax.envs.task_instances import TaskFamily

#: The bandit families: their noise model.
FAMILIES = {"gaussian_bandit": "gaussian", "bernoulli_bandit": "bernoulli", "testbed": "gaussian"}
#: The seed of every family's one instance (its arm means).
INSTANCE_SEED = 0
#: Pulls per episode unless a run asks for more (``max_steps``).
PULLS = 1


def arm_means(family: str, arms: int, seed: int | tuple[int, ...] = INSTANCE_SEED
              ) -> np.ndarray:
    """The float32 means of a family's instance (:data:`FAMILIES`) drawn from ``seed``
    (an integer, or a tuple of them: a run's per-agent instance ``(root seed, seed
    index)``), by NumPy's ``default_rng`` of ``[*seed, family index]``.

    Raises:
      ValueError: an unknown family or fewer than one arm.
    """
    if family not in FAMILIES:
        raise ValueError(f"family={family!r} is invalid: must be one of {', '.join(FAMILIES)}")
    if isinstance(arms, bool) or not isinstance(arms, (int, np.integer)) or arms < 1:
        raise ValueError(f"arms={arms!r} is invalid: must be an integer >= 1")
    entropy = [seed] if isinstance(seed, (int, np.integer)) else list(seed)
    rng = np.random.default_rng([*entropy, list(FAMILIES).index(family)])
    means = rng.normal(size=arms) if family == "testbed" else rng.random(arms)
    return means.astype(np.float32)


def make_bandit(means: np.ndarray, noise: str, *, pulls: int = PULLS, std: float = 1.0,
                name: str = "bandit") -> TabularMDP:
    """A bandit with these arm means as a one-state task.

    Args:
      means: ``[k]`` mean reward of each arm (in [0, 1] for ``bernoulli``).
      noise: ``gaussian`` or ``bernoulli`` (:mod:`vdbejax.envs.reward_noise`).
      pulls: pulls per episode: 1 ends the episode with the pull (terminal, no bootstrap);
        more truncate it after ``pulls`` (the next pull's value is bootstrapped).
      std: the Gaussian rewards' standard deviation.
      name: the task's label.

    Raises:
      ValueError: one line naming a bad argument.
    """
    means = np.asarray(means, np.float32)
    if means.ndim != 1 or means.size < 1:
        raise ValueError(f"means has shape {means.shape}: must be [k] with k >= 1 arms")
    if noise not in ("gaussian", "bernoulli"):
        raise ValueError(f"noise={noise!r} is invalid: must be gaussian or bernoulli")
    arms = means.size
    return make_tabular_mdp(
        np.zeros((1, arms), np.int32), means[None], np.full((1, arms), pulls == 1), [1.0],
        max_steps=pulls, name=name, reward_noise=noise,
        reward_std=std if noise == "gaussian" else None)


def make_family_bandit(family: str, arms: int, *, pulls: int = PULLS, name: str) -> TabularMDP:
    """The instance of ``family`` (:data:`FAMILIES`) with ``arms`` arms."""
    return make_bandit(arm_means(family, arms), FAMILIES[family], pulls=pulls, name=name)


def optimal_arms(mdp: TabularMDP) -> np.ndarray:
    """The arms of largest mean of a one-state task (bool ``[k]``)."""
    means = np.asarray(mdp.reward)[0, :, 0]
    return means == means.max()


def bandit_family(family: str, arms: int, *, pulls: int = PULLS, name: str,
                  instance: int | None = None) -> TaskFamily:
    """``family`` (:data:`FAMILIES`) with ``arms`` arms as a generator of instances: the
    instance of entropy ``(root seed, seed index)`` has the arm means :func:`arm_means`
    draws from it. The Gaussian families' reward standard deviation is their parameter
    ``std`` (default 1; a sweep axis ``task.std``); ``instance`` is the default instance
    seed (:class:`~vdbejax.envs.task_instances.TaskFamily`; :data:`INSTANCE_SEED` gives every
    agent the named task's instance)."""
    arm_means(family, arms)  # a bad family or number of arms: one line now
    noise = FAMILIES[family]

    def generate(entropy: tuple[int, ...], **parameters: float) -> TabularMDP:
        return make_bandit(arm_means(family, arms, entropy), noise, pulls=pulls, name=name,
                           **parameters)

    return TaskFamily(name, generate, f"{family} with {arms} arms, an instance per agent"
                      " (arm means drawn from the root seed and the agent's seed index)",
                      parameters={"std": 1.0} if noise == "gaussian" else {},
                      instance=instance)
