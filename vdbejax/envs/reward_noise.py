"""Random rewards: per outcome of a :class:`~vdbejax.envs.tabular.TabularMDP`, a mean and
a noise model.

An outcome's ``reward`` is its mean; its noise model is one of :data:`NOISE_MODELS`:

* ``none``: the reward is the mean (every task without reward noise);
* ``gaussian``: ``mean + std · z`` with ``z ~ N(0, 1)`` (``std`` per outcome);
* ``bernoulli``: 1 with probability ``mean`` and 0 otherwise (the mean lies in [0, 1]).

The draw is one uniform of the agent's own random stream per step (the engine's
``reward_uniform``, :mod:`vdbejax.engine.agent_state`), turned into a normal by the inverse
normal CDF (``jax.scipy.special.ndtri``), so results still depend only on the agent's
seed and hyperparameters. A task whose outcomes are all ``none`` stores no noise at all
(``TabularMDP.reward_noise is None``): its programs draw nothing more and it keeps its
bits and fingerprint. Exact solvers (:mod:`vdbejax.envs.solvers`) use the means.
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtri

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass
from vdbejax.validation import first_bad

Array = jax.Array

#: The noise models, by name; an outcome stores its model's index.
NOISE_MODELS = ("none", "gaussian", "bernoulli")
NONE, GAUSSIAN, BERNOULLI = range(len(NOISE_MODELS))


@pytree_dataclass
class RewardNoise:
    """Per-outcome noise of a task's rewards (``[S, A, K]`` like its ``reward``).

    Attributes:
      model: int32 index into :data:`NOISE_MODELS` of each outcome.
      std: float32 standard deviation of each Gaussian outcome (0 elsewhere).
    """

    model: Array
    std: Array


def noisy_reward(mean: Array, model: Array, std: Array, u: Array) -> Array:
    """A reward drawn around ``mean`` with one uniform ``u`` in (0, 1) (elementwise).

    Args:
      mean: float32 mean rewards of the outcomes taken.
      model: their noise models (index into :data:`NOISE_MODELS`).
      std: their Gaussian standard deviations.
      u: uniforms in the open interval (0, 1).

    Returns:
      the float32 rewards.
    """
    gaussian = mean + rounded(std * ndtri(u), std)  # the product rounded on its own
    bernoulli = (u < mean).astype(mean.dtype)
    return jnp.where(model == GAUSSIAN, gaussian, jnp.where(model == BERNOULLI, bernoulli, mean))


def make_reward_noise(reward: np.ndarray, reward_noise: Any, reward_std: Any,
                      outcome_array: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """Validated ``(model, std)`` arrays of :func:`make_tabular_mdp`'s noise arguments,
    or ``None`` when no outcome is noisy.

    Args:
      reward: the ``[S, A, K]`` mean rewards (float32, finite).
      reward_noise: a name of :data:`NOISE_MODELS` for every outcome, or an array of names
        shaped like ``reward`` (or ``[S, A]`` when ``K = 1``), or ``None`` (no noise).
      reward_std: the Gaussian standard deviation, a number or such an array; required
        when an outcome is Gaussian, refused otherwise.
      outcome_array: ``make_tabular_mdp``'s reader of outcome-shaped arrays
        ``(label, value, dtype)``.

    Raises:
      ValueError: one line naming the parameter, the value and what is allowed.
    """
    shape = reward.shape
    if reward_noise is None:
        if reward_std is not None:
            raise ValueError(f"reward_std={reward_std!r} is invalid without reward_noise:"
                             " a standard deviation needs Gaussian outcomes")
        return None
    allowed = f"must be one of {', '.join(NOISE_MODELS)}"
    if isinstance(reward_noise, str):
        if reward_noise not in NOISE_MODELS:
            raise ValueError(f"reward_noise={reward_noise!r} is invalid: {allowed}")
        model = np.full(shape, NOISE_MODELS.index(reward_noise), np.int32)
    else:
        names = np.asarray(reward_noise, dtype=object)
        if names.shape == shape[:2] and shape[2] == 1:
            names = names[:, :, None]
        if names.shape != shape:
            raise ValueError(f"reward_noise has shape {names.shape}: must be a name or"
                             f" {list(shape)} names (the shape of next_state)")
        known = np.vectorize(lambda n: isinstance(n, str) and n in NOISE_MODELS,
                             otypes=[bool])(names)
        first_bad("reward_noise", names, ~known, allowed)
        model = np.vectorize(NOISE_MODELS.index, otypes=[np.int32])(names)
    gaussian = model == GAUSSIAN
    if reward_std is None:
        if gaussian.any():
            raise ValueError("reward_std is None but reward_noise has Gaussian outcomes:"
                             " pass their standard deviation (a number >= 0)")
        std = np.zeros(shape, np.float32)
    else:
        if not gaussian.any():
            raise ValueError(f"reward_std={reward_std!r} is invalid: no outcome has Gaussian"
                             " noise (reward_noise)")
        if np.ndim(reward_std) == 0:
            reward_std = np.full(shape, reward_std)
        std = outcome_array("reward_std", reward_std, np.float32)
        first_bad("reward_std", std, ~np.isfinite(std) | (std < 0),
                  "must be finite and >= 0 in float32")
        std = np.where(gaussian, std, np.float32(0))
    bernoulli = model == BERNOULLI
    first_bad("reward", reward, bernoulli & ((reward < 0) | (reward > 1)),
              "must lie in [0, 1] for a Bernoulli outcome (its mean)")
    if not (model != NONE).any():
        return None
    return model, std.astype(np.float32)
