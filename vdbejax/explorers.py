"""Action-selection methods: ε-greedy, softmax, VDBE and VDBE-Softmax.

Every explorer is one instance of a single rule, implemented once in
:func:`select_action`::

    with probability p   → sample from  P(a) ∝ exp((Q(s,a) − max Q(s)) / τ)
    otherwise            → greedy (ties broken uniformly at random, or first)

| explorer      | p            | τ                       |
| ------------- | ------------ | ----------------------- |
| ε-greedy      | ε            | ∞ (uniform over actions)|
| softmax       | 1            | τ                       |
| VDBE          | ε(s)         | ∞                       |
| VDBE-Softmax  | ε(s)         | τ = 0.001 (spec)        |

Because all four share one rule, a grid mixing explorer kinds runs one code path for
every agent (no branch over kinds), and the public per-explorer functions below are the
exact same computation as the engine's.

All functions act on the *leading* axis: a single Q row has shape ``[num_actions]``, and
a batch laid out ``[num_actions, batch...]`` (batch as the fast axis, which XLA's CPU
backend vectorises; the engine uses this layout) is handled by the same code. ``jax.vmap``
works as well. Random draws are passed in as uniforms in [0, 1) so that the engine can derive
them from its own per-agent counter-based stream; the ``key``-taking wrappers draw them
with ``jax.random.uniform``.
"""
from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from vdbejax._numerics import rounded
from vdbejax._pytree import pytree_dataclass, static_field

Array = jax.Array

EXPLORERS = ("egreedy", "softmax", "vdbe", "vdbe_softmax")
TIE_BREAKS = ("random", "first")
#: Softmax temperature of VDBE-Softmax's exploratory draws (Tokic & Palm 2011; spec).
VDBE_SOFTMAX_TAU = 0.001
#: VDBE inverse sensitivity δ (spec).
VDBE_DELTA = 0.1
#: Number of uniforms :func:`select_action` consumes.
NUM_ACTION_UNIFORMS = 3
#: sample_categorical unrolls its prefix sums up to this many categories.
_UNROLLED_CDF_MAX = 32


def sample_categorical(weights: Array, u: Array) -> Array:
    """Inverse-CDF sample from unnormalised non-negative ``weights`` with one uniform.

    Args:
      weights: ``[n, batch...]`` non-negative weights, positive sum along axis 0.
      u: uniforms in [0, 1), shape ``[batch...]``.

    Returns:
      int32 ``[batch...]`` index ``i`` with probability ``weights[i] / sum(weights)``; an
      index of zero weight is never returned.
    """
    n = weights.shape[0]
    # u has a 23-bit mantissa, so u * total < total and the count stays < n.
    if n > _UNROLLED_CDF_MAX:
        cdf = jnp.cumsum(weights, axis=0)
        threshold = u * cdf[-1]
        # Weights shared by a batch of uniforms ([n] against [batch]): compare per column.
        batch_dims = threshold.ndim - (cdf.ndim - 1)
        cdf = cdf.reshape(cdf.shape[:1] + (1,) * batch_dims + cdf.shape[1:])
        return jnp.sum(cdf <= threshold, axis=0, dtype=jnp.int32)
    # Left-to-right prefix sums, unrolled: for the few actions of a tabular task this is
    # much cheaper on CPU than XLA's reduce-window cumsum.
    partial = [weights[0]]
    for i in range(1, n):
        partial.append(partial[-1] + weights[i])
    threshold = u * partial[-1]
    count = (partial[0] <= threshold).astype(jnp.int32)
    for value in partial[1:]:
        count = count + (value <= threshold).astype(jnp.int32)
    return count


def greedy(q: Array, u: Array, tie_break: str = "random") -> Array:
    """Greedy action of Q rows.

    Args:
      q: ``[num_actions, batch...]`` action values.
      u: uniforms in [0, 1) (``[batch...]``) used to break ties.
      tie_break: ``"random"`` (uniform among maximal actions) or ``"first"``.

    Returns:
      int32 ``[batch...]`` action indices.
    """
    if tie_break == "first":
        return jnp.argmax(q, axis=0).astype(jnp.int32)
    return sample_categorical((q == jnp.max(q, axis=0)).astype(q.dtype), u)


def softmax_weights(q: Array, tau: Array) -> Array:
    """Unnormalised Boltzmann weights ``exp((q − max q)/τ)`` along axis 0, stable for tiny τ.

    The maximal action has weight 1, so the sum is ≥ 1 and no overflow, NaN or inf can
    occur for any τ > 0; τ = ∞ gives uniform weights.

    Args:
      q: ``[num_actions, batch...]`` action values.
      tau: temperature > 0 (``inf`` = uniform).

    Returns:
      ``q``-shaped weights in [0, 1] (1 for a maximal action).
    """
    return jnp.exp((q - jnp.max(q, axis=0)) / tau)


def softmax_probabilities(q: Array, tau: Array) -> Array:
    """Normalised Boltzmann probabilities ``P(a) ∝ exp(Q(s,a)/τ)`` (axis 0 = actions).

    Args:
      q: ``[num_actions, batch...]`` action values.
      tau: temperature > 0 (``inf`` = uniform).

    Returns:
      ``q``-shaped probabilities summing to 1 along axis 0.
    """
    w = softmax_weights(q, tau)
    return w / jnp.sum(w, axis=0)


def select_action(
    q: Array,
    explore_probability: Array,
    tau: Array,
    uniforms: Array,
    tie_break: str = "random",
) -> Array:
    """The one action-selection rule behind every explorer.

    Args:
      q: ``[num_actions, batch...]`` action values of the current state(s).
      explore_probability: probability of an exploratory draw (ε, 1 or ε(s)).
      tau: temperature of the exploratory draw; ``inf`` means uniform.
      uniforms: three uniforms in [0, 1) (an array ``[3, batch...]`` or a sequence of 3):
        explore test, exploratory draw, tie break.
      tie_break: ``"random"`` or ``"first"`` (static).

    Returns:
      int32 ``[batch...]`` action indices.
    """
    explore = uniforms[0] < explore_probability
    exploratory = sample_categorical(softmax_weights(q, tau), uniforms[1])
    return jnp.where(explore, exploratory, greedy(q, uniforms[2], tie_break))


def _uniforms(key: Array) -> Array:
    return jax.random.uniform(key, (NUM_ACTION_UNIFORMS,))


def egreedy(key: Array, q: Array, epsilon: float | Array, tie_break: str = "random") -> Array:
    """ε-greedy: a uniformly random action with probability ε, else greedy.

    Args:
      key: PRNG key.
      q: ``[num_actions]`` action values.
      epsilon: exploration probability in [0, 1].
      tie_break: ``"random"`` or ``"first"``.

    Returns:
      int32 action index.
    """
    return select_action(q, epsilon, jnp.inf, _uniforms(key), tie_break)


def softmax(key: Array, q: Array, tau: float | Array) -> Array:
    """Softmax (Boltzmann): sample ``P(a) ∝ exp(Q(s,a)/τ)``.

    Args:
      key: PRNG key.
      q: ``[num_actions]`` action values.
      tau: temperature > 0.

    Returns:
      int32 action index.
    """
    return select_action(q, 1.0, tau, _uniforms(key))


def vdbe(key: Array, q: Array, state_epsilon: Array, tie_break: str = "random") -> Array:
    """VDBE (Tokic 2010): a uniformly random action with probability ε(s), else greedy.

    Args:
      key: PRNG key.
      q: ``[num_actions]`` action values of state ``s``.
      state_epsilon: ε(s), the current state's exploration probability.
      tie_break: ``"random"`` or ``"first"``.

    Returns:
      int32 action index.
    """
    return select_action(q, state_epsilon, jnp.inf, _uniforms(key), tie_break)


def vdbe_softmax(
    key: Array,
    q: Array,
    state_epsilon: Array,
    tau: float | Array = VDBE_SOFTMAX_TAU,
    tie_break: str = "random",
) -> Array:
    """VDBE-Softmax (Tokic & Palm 2011): softmax(τ) with probability ε(s), else greedy.

    Args:
      key: PRNG key.
      q: ``[num_actions]`` action values of state ``s``.
      state_epsilon: ε(s).
      tau: temperature of the exploratory softmax draw (spec: 0.001).
      tie_break: ``"random"`` or ``"first"``.

    Returns:
      int32 action index.
    """
    return select_action(q, state_epsilon, tau, _uniforms(key), tie_break)


def vdbe_epsilon_update(
    epsilon: Array, delta_q: Array, sigma: Array, delta: Array = VDBE_DELTA
) -> Array:
    """VDBE update of ε(s) after a change ``ΔQ = α·TD-error`` of Q(s, a).

    ``f = (1 − e^{−|ΔQ|/σ}) / (1 + e^{−|ΔQ|/σ})``, ``ε ← δ·f + (1 − δ)·ε``.

    Args:
      epsilon: current ε(s).
      delta_q: the change just made to Q(s, a).
      sigma: inverse sensitivity σ > 0.
      delta: mixing weight δ in (0, 1].

    Returns:
      the new ε(s).
    """
    decay = jnp.exp(-jnp.abs(delta_q) / sigma)
    value_difference = (1.0 - decay) / (1.0 + decay)
    return rounded(delta * value_difference, delta) + rounded((1.0 - delta) * epsilon, delta)


@pytree_dataclass
class ExplorerParams:
    """Hyperparameters of any of the four explorers, as vmappable pytree leaves.

    Attributes:
      epsilon: fixed exploration probability (ε-greedy: ε; softmax: 1); unused when
        ``adaptive``.
      tau: temperature of exploratory draws (``inf`` = uniform).
      adaptive: use the per-state VDBE ε(s) instead of ``epsilon``.
      sigma: VDBE inverse sensitivity σ.
      delta: VDBE mixing weight δ.
      tie_break: ``"random"`` or ``"first"`` (static: it changes the program).
    """

    epsilon: Array
    tau: Array
    adaptive: Array
    sigma: Array
    delta: Array
    tie_break: str = static_field("random")


def make_explorer(
    name: str,
    param: float,
    *,
    tie_break: str = "random",
    delta: float = VDBE_DELTA,
    vdbe_softmax_tau: float = VDBE_SOFTMAX_TAU,
) -> ExplorerParams:
    """Explorer hyperparameters from its name and its one swept parameter.

    Args:
      name: one of ``egreedy`` (param = ε), ``softmax`` (τ), ``vdbe`` (σ),
        ``vdbe_softmax`` (σ).
      param: the swept parameter.
      tie_break: ``"random"`` or ``"first"``.
      delta: VDBE δ.
      vdbe_softmax_tau: VDBE-Softmax's temperature.

    Returns:
      ExplorerParams with float32 scalar numpy leaves.

    Raises:
      ValueError: unknown name or out-of-range parameter.
    """
    from vdbejax.validation import check_explorer  # local: validation imports us

    check_explorer(name, param, tie_break=tie_break, delta=delta, tau=vdbe_softmax_tau)
    inf = math.inf
    epsilon, tau, adaptive, sigma = {
        "egreedy": (param, inf, False, 1.0),
        "softmax": (1.0, param, False, 1.0),
        "vdbe": (1.0, inf, True, param),
        "vdbe_softmax": (1.0, vdbe_softmax_tau, True, param),
    }[name]
    f32 = np.float32  # host scalars, as in make_learner
    return ExplorerParams(
        epsilon=np.asarray(epsilon, f32),
        tau=np.asarray(tau, f32),
        adaptive=np.asarray(adaptive),
        sigma=np.asarray(sigma, f32),
        delta=np.asarray(delta, f32),
        tie_break=tie_break,
    )
