"""The action-selection rules as pure functions: greedy, softmax, the paper's one rule
(:func:`select_action`), its exact probabilities, the VDBE ε(s) update and the schedules.

The paper's four explorers (:mod:`vdbejax.methods.explorers`) are one rule::

    with probability p   → sample from  P(a) ∝ exp((Q(s,a) − max Q(s)) / τ)
    otherwise            → greedy (ties broken uniformly at random, or first)

The functions act on the *leading* axis (``[num_actions, batch...]``), so they serve one
row as well as a batch; random draws come in as uniforms in [0, 1) (the engine derives
them from its per-agent stream); the ``key``-taking wrappers (:func:`egreedy`,
:func:`softmax`, :func:`vdbe`, :func:`vdbe_softmax`) draw them with
``jax.random.uniform``.
"""
from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded, sample_categorical

Array = jax.Array

#: Greedy tie breaks: uniformly among the maximal actions, or the first of them.
TIE_BREAKS = ("random", "first")
#: Softmax temperature of VDBE-Softmax's exploratory draws (Tokic & Palm 2011; spec).
VDBE_SOFTMAX_TAU = 0.001
#: VDBE inverse sensitivity δ (spec).
VDBE_DELTA = 0.1
#: Number of uniforms :func:`select_action` consumes.
NUM_ACTION_UNIFORMS = 3


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


def softmax_weights(q: Array, tau: float | Array) -> Array:
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


def softmax_probabilities(q: Array, tau: float | Array) -> Array:
    """Normalised Boltzmann probabilities ``P(a) ∝ exp(Q(s,a)/τ)`` (axis 0 = actions).

    Args:
      q: ``[num_actions, batch...]`` action values.
      tau: temperature > 0 (``inf`` = uniform).

    Returns:
      ``q``-shaped probabilities summing to 1 along axis 0.
    """
    w = softmax_weights(q, tau)
    return w / jnp.sum(w, axis=0)


#: Softmax numerics: ``"stable"`` (exp((Q − max Q)/τ), never NaN), or ``"float64"``: the
#: authors' published formula exp(Q/τ)/Σ exp(Q/τ) in float64 without the max, sampled with
#: ``searchsorted(cumsum(p), u)`` (see :func:`float64_softmax_draw`).
SOFTMAX_NUMERICS = ("stable", "float64")
#: exp(x) overflows float64 above log(DBL_MAX) …
_FLOAT64_EXP_OVERFLOW = 709.782712893384
#: … and is exactly 0 below log of half the smallest subnormal.
_FLOAT64_EXP_ZERO = -745.1332191019412


def float64_softmax_draw(q: Array, tau: float | Array, stable_draw: Array) -> Array:
    """The action the authors' float64 softmax draws, given the stable draw's action.

    Where the float64 weights are a distribution the two draws agree (up to rounding of
    probabilities below 1e-30). They differ in two cases only: (1) some ``Q/τ`` exceeds
    709.78, its weight is inf, its probability inf/inf = NaN, and ``searchsorted`` (NaN
    sorts last) returns the *first* such action, whatever the others are worth; (2) every
    ``Q/τ`` is below −745.13: all weights are 0, all probabilities 0/0 = NaN, and the draw
    is action 0. (Case 2 is what loops a state of the published task onto itself: with
    τ = 0.0001, once all of a state's Q values are below ≈ −0.075.)

    Args:
      q: ``[num_actions, batch...]`` action values.
      tau: temperature.
      stable_draw: the action :func:`sample_categorical` drew from the stable weights.

    Returns:
      int32 ``[batch...]`` actions.
    """
    x = q / tau
    overflow = x > _FLOAT64_EXP_OVERFLOW
    vanished = jnp.all(x < _FLOAT64_EXP_ZERO, axis=0)
    first_overflow = jnp.argmax(overflow, axis=0).astype(jnp.int32)
    return jnp.where(jnp.any(overflow, axis=0), first_overflow,
                     jnp.where(vanished, 0, stable_draw)).astype(jnp.int32)


def select_action(
    q: Array,
    explore_probability: float | Array,
    tau: float | Array | None,
    uniforms: Array | Sequence[Array],
    tie_break: str = "random",
    numerics: str = "stable",
) -> Array:
    """The one action-selection rule behind the paper's explorers (module docstring).

    Args:
      q: ``[num_actions, batch...]`` action values of the current state(s).
      explore_probability: probability of an exploratory draw (ε, 1 or ε(s)).
      tau: temperature of the exploratory draw; ``None`` (or ``inf``) means uniform —
        ``None`` skips the exponentials, with the same result for finite Q.
      uniforms: three uniforms in [0, 1) (an array ``[3, batch...]`` or a sequence of 3):
        explore test, exploratory draw, tie break.
      tie_break: ``"random"`` or ``"first"`` (static).
      numerics: :data:`SOFTMAX_NUMERICS` of the exploratory softmax draw (static).

    Returns:
      int32 ``[batch...]`` action indices.
    """
    explore = uniforms[0] < explore_probability
    # exp((q − max)/∞) is exactly 1 for finite q: uniform weights are the same draw.
    weights = jnp.ones_like(q) if tau is None else softmax_weights(q, tau)
    if tie_break == "random" and (numerics == "stable" or tau is None):
        # One draw, from the exploratory weights with the second uniform where exploring
        # and from the maximal actions with the third elsewhere: a draw depends on its
        # weights and uniform alone, so this is the action of the two draws selected
        # below, at half the work (and half the program to trace).
        maximal = (q == jnp.max(q, axis=0)).astype(q.dtype)
        return sample_categorical(jnp.where(explore, weights, maximal),
                                  jnp.where(explore, uniforms[1], uniforms[2]))
    exploratory = sample_categorical(weights, uniforms[1])
    if numerics == "float64" and tau is not None:
        exploratory = float64_softmax_draw(q, tau, exploratory)
    return jnp.where(explore, exploratory, greedy(q, uniforms[2], tie_break))


def greedy_probabilities(q: Array, tie_break: str = "random") -> Array:
    """``q``-shaped probabilities of :func:`greedy` (axis 0 = actions)."""
    if tie_break == "first":
        return jax.nn.one_hot(jnp.argmax(q, axis=0), q.shape[0], axis=0, dtype=q.dtype)
    maximal = (q == jnp.max(q, axis=0)).astype(q.dtype)
    return maximal / jnp.sum(maximal, axis=0)


def mixture_probabilities(q: Array, explore_probability: float | Array,
                          tau: float | Array | None, tie_break: str = "random") -> Array:
    """Exact probabilities of :func:`select_action`: ``p·softmax_τ(Q) + (1 − p)·greedy(Q)``."""
    exploratory = (jnp.ones_like(q) / q.shape[0] if tau is None
                   else softmax_probabilities(q, tau))
    return (explore_probability * exploratory
            + (1.0 - explore_probability) * greedy_probabilities(q, tie_break))


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
    return select_action(q, epsilon, None, _uniforms(key), tie_break)


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
    return select_action(q, state_epsilon, None, _uniforms(key), tie_break)


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
    epsilon: Array, delta_q: Array, sigma: float | Array, delta: float | Array = VDBE_DELTA
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


def count_visit(counts: Array, action: Array) -> Array:
    """A state's per-action visit counts ``[A]`` after taking ``action`` once more."""
    return counts + (jnp.arange(counts.shape[0]) == action).astype(counts.dtype)


def decayed(initial: float | Array, decay: float | Array, minimum: float | Array,
            episode: Array) -> Array:
    """Exponential schedule over episodes: ``max(minimum, initial · decay^episode)``."""
    return jnp.maximum(minimum, initial * jnp.power(decay, episode.astype(jnp.float32)))
