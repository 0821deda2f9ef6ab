"""Action-selection methods: the rules as pure functions, and the explorers built on them.

The paper's four explorers are one rule, :func:`select_action`::

    with probability p   → sample from  P(a) ∝ exp((Q(s,a) − max Q(s)) / τ)
    otherwise            → greedy (ties broken uniformly at random, or first)

| explorer                 | p        | τ          | tables            |
| ------------------------ | -------- | ---------- | ----------------- |
| ``egreedy``              | ε        | ∞ (uniform)| –                 |
| ``softmax``              | 1        | τ          | –                 |
| ``vdbe`` (Tokic 2010)    | ε(s)     | ∞          | ε(s), starts at 1 |
| ``vdbe_softmax``         | ε(s)     | 0.001      | ε(s)              |
| ``max_boltzmann``        | ε        | τ          | –                 |
| ``egreedy_decay``        | ε₀·dᵏ ∨ ε_min (episode k) | ∞ | –            |
| ``softmax_decay``        | 1        | τ₀·dᵏ ∨ τ_min | –              |
| ``ucb1``                 | argmax Q + c·√(ln N(s) / N(s,a)), untried actions first | N(s,a) |

Each explorer is a plug-in (:mod:`vdbejax.methods.api`): a pytree dataclass of its
hyperparameters whose ``select``/``update``/``probabilities`` act on one agent's Q row.
The functions below act on the *leading* axis (``[num_actions, batch...]``), so they
serve one row as well as a batch; random draws come in as uniforms in [0, 1) (the engine
derives them from its per-agent stream); the ``key``-taking wrappers draw them with
``jax.random.uniform``.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded, sample_categorical
from vdbejax._pytree import static_field
from vdbejax.methods.api import EXPLORERS, Context, Explorer, Table, build, explorer
from vdbejax.validation import check_bool, check_choice, check_in_range, check_positive

Array = jax.Array

#: The paper's explorers.
PAPER_EXPLORERS = ("egreedy", "softmax", "vdbe", "vdbe_softmax")
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


# --------------------------------------------------------------------------- explorers
def _check_tie_break(tie_break: str) -> None:
    check_choice("tie_break", tie_break, TIE_BREAKS)


@explorer("egreedy", parameter="epsilon", title="ε-greedy")
class EpsilonGreedy(Explorer):
    """ε-greedy: a uniformly random action with probability ε, else greedy."""

    epsilon: float | Array = 0.1
    tie_break: str = static_field("random")

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return select_action(q, self.epsilon, None, uniforms, self.tie_break)

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return mixture_probabilities(q, self.epsilon, None, self.tie_break)

    def validate(self) -> None:
        check_in_range("epsilon", self.epsilon, 0.0, 1.0)
        _check_tie_break(self.tie_break)


@explorer("softmax", parameter="tau", title="softmax")
class Softmax(Explorer):
    """Softmax (Boltzmann): sample ``P(a) ∝ exp(Q(s,a)/τ)``."""

    tau: float | Array = 1.0
    #: :data:`SOFTMAX_NUMERICS` (``"float64"``: the authors' unstabilised formula).
    softmax_numerics: str = static_field("stable")

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        # The paper's rule with p = 1 (uniforms are < 1, so the draw is always
        # exploratory); XLA compiles this form faster than the draw alone (measured).
        return select_action(q, 1.0, self.tau, uniforms, numerics=self.softmax_numerics)

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return softmax_probabilities(q, self.tau)

    def validate(self) -> None:
        check_positive("tau", self.tau)
        check_choice("softmax_numerics", self.softmax_numerics, SOFTMAX_NUMERICS)


@explorer("vdbe", parameter="sigma", title="VDBE")
class VDBE(Explorer):
    """VDBE (Tokic 2010): uniform exploration with the per-state probability ε(s), which
    follows the value changes (:func:`vdbe_epsilon_update`)."""

    sigma: float | Array = 1.0
    delta: float | Array = VDBE_DELTA
    epsilon_init: float | Array = 1.0
    tie_break: str = static_field("random")
    #: Update ε(s) on a step that ends the episode too (the authors' code does not).
    update_on_terminal: bool = static_field(True)

    def tables(self) -> dict[str, Table]:
        return {"epsilon": Table("state", self.epsilon_init)}

    def _tau(self) -> float | Array | None:
        return None  # uniform exploratory draws

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return select_action(q, tables["epsilon"], self._tau(), uniforms, self.tie_break,
                             self._numerics())

    def _numerics(self) -> str:
        return "stable"  # uniform exploratory draws: no softmax

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return mixture_probabilities(q, tables["epsilon"], self._tau(), self.tie_break)

    def update(self, tables: Mapping[str, Array], action: Array, delta_q: Array,
               context: Context) -> dict[str, Array]:
        epsilon = vdbe_epsilon_update(tables["epsilon"], delta_q, self.sigma, self.delta)
        if not self.update_on_terminal:
            epsilon = jnp.where(context.terminal, tables["epsilon"], epsilon)
        return {"epsilon": epsilon}

    def validate(self) -> None:
        check_positive("sigma", self.sigma)
        check_in_range("delta", self.delta, 0.0, 1.0, low_open=True)
        check_in_range("epsilon_init", self.epsilon_init, 0.0, 1.0)
        _check_tie_break(self.tie_break)
        check_bool("update_on_terminal", self.update_on_terminal)


@explorer("vdbe_softmax", parameter="sigma", title="VDBE-Softmax")
class VDBESoftmax(VDBE):
    """VDBE-Softmax (Tokic & Palm 2011): with probability ε(s) a softmax(τ) draw, else greedy."""

    tau: float | Array = VDBE_SOFTMAX_TAU
    #: :data:`SOFTMAX_NUMERICS` of the exploratory draw.
    softmax_numerics: str = static_field("stable")
    option_aliases: ClassVar[dict[str, str]] = {"vdbe_softmax_tau": "tau"}

    def _tau(self) -> float | Array | None:
        return self.tau

    def _numerics(self) -> str:
        return self.softmax_numerics

    def validate(self) -> None:
        super().validate()
        check_positive("tau", self.tau)
        check_choice("softmax_numerics", self.softmax_numerics, SOFTMAX_NUMERICS)


@explorer("max_boltzmann", parameter="epsilon", title="Max-Boltzmann")
class MaxBoltzmann(Explorer):
    """Max-Boltzmann (ε-softmax, Wiering 1999): with probability ε a softmax(τ) draw,
    else greedy."""

    epsilon: float | Array = 0.1
    tau: float | Array = 0.1
    tie_break: str = static_field("random")

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return select_action(q, self.epsilon, self.tau, uniforms, self.tie_break)

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return mixture_probabilities(q, self.epsilon, self.tau, self.tie_break)

    def validate(self) -> None:
        check_in_range("epsilon", self.epsilon, 0.0, 1.0)
        check_positive("tau", self.tau)
        _check_tie_break(self.tie_break)


def decayed(initial: float | Array, decay: float | Array, minimum: float | Array,
            episode: Array) -> Array:
    """Exponential schedule over episodes: ``max(minimum, initial · decay^episode)``."""
    return jnp.maximum(minimum, initial * jnp.power(decay, episode.astype(jnp.float32)))


@explorer("egreedy_decay", parameter="epsilon", title="decaying ε-greedy")
class DecayingEpsilonGreedy(Explorer):
    """ε-greedy with ε decaying over episodes: ε_k = max(ε_min, ε·decay^k) in episode k."""

    epsilon: float | Array = 1.0
    decay: float | Array = 0.99
    epsilon_min: float | Array = 0.01
    tie_break: str = static_field("random")

    def _epsilon(self, context: Context) -> Array:
        return decayed(self.epsilon, self.decay, self.epsilon_min, context.episode)

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return select_action(q, self._epsilon(context), None, uniforms, self.tie_break)

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return mixture_probabilities(q, self._epsilon(context), None, self.tie_break)

    def validate(self) -> None:
        check_in_range("epsilon", self.epsilon, 0.0, 1.0)
        check_in_range("decay", self.decay, 0.0, 1.0, low_open=True)
        check_in_range("epsilon_min", self.epsilon_min, 0.0, 1.0)
        _check_tie_break(self.tie_break)


@explorer("softmax_decay", parameter="tau", title="decaying softmax")
class DecayingSoftmax(Explorer):
    """Softmax with τ decaying over episodes: τ_k = max(τ_min, τ·decay^k) in episode k."""

    tau: float | Array = 1.0
    decay: float | Array = 0.99
    tau_min: float | Array = 0.001

    def _tau(self, context: Context) -> Array:
        return decayed(self.tau, self.decay, self.tau_min, context.episode)

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return sample_categorical(softmax_weights(q, self._tau(context)), uniforms[1])

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return softmax_probabilities(q, self._tau(context))

    def validate(self) -> None:
        check_positive("tau", self.tau)
        check_in_range("decay", self.decay, 0.0, 1.0, low_open=True)
        check_positive("tau_min", self.tau_min)


@explorer("ucb1", parameter="c", title="UCB-1")
class UCB1(Explorer):
    """UCB-1 (Auer et al. 2002) per state: untried actions first, then
    ``argmax Q(s,a) + c·sqrt(ln N(s) / N(s,a))`` with N the visit counts."""

    c: float | Array = 1.0
    tie_break: str = static_field("random")
    num_uniforms = 1

    def tables(self) -> dict[str, Table]:
        return {"counts": Table("pair", 0.0)}

    def scores(self, q: Array, counts: Array) -> Array:
        """Upper confidence bounds; untried actions score 1 and the others 0 while any is
        untried."""
        untried = counts == 0
        total = jnp.sum(counts, axis=0)
        # The bonus rounds on its own (no FMA with the addition): otherwise XLA may fuse it
        # into Q + bonus in one fusion and not in another, and greedy's max would then
        # match no action at all (vdbejax._numerics).
        bonus = rounded(self.c * jnp.sqrt(jnp.log(jnp.maximum(total, 1.0))
                                          / jnp.maximum(counts, 1.0)), self.c)
        return jnp.where(jnp.any(untried, axis=0), untried.astype(q.dtype), q + bonus)

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return greedy(self.scores(q, tables["counts"]), uniforms[0], self.tie_break)

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return greedy_probabilities(self.scores(q, tables["counts"]), self.tie_break)

    def update(self, tables: Mapping[str, Array], action: Array, delta_q: Array,
               context: Context) -> dict[str, Array]:
        return {"counts": count_visit(tables["counts"], action)}

    def validate(self) -> None:
        check_in_range("c", self.c, 0.0, math.inf, high_open=True)
        _check_tie_break(self.tie_break)


@explorer("count_bonus", parameter="beta", title="count bonus")
class CountBonus(Explorer):
    """Greedy on ``Q(s,a) + β / sqrt(N(s,a) + 1)``, N the visit counts: a count-based
    optimism bonus that fades as a pair is tried (the bonus shape of MBIE-EB, Strehl &
    Littman 2008, added to Q itself rather than to a model's values)."""

    beta: float | Array = 0.1
    tie_break: str = static_field("random")
    num_uniforms = 1  # the greedy tie break

    def tables(self) -> dict[str, Table]:
        return {"visits": Table("pair", 0.0)}

    def scores(self, q: Array, visits: Array) -> Array:
        """Q plus the bonus (rounded on its own: every program adds the same bits, so
        greedy's max always matches an action; vdbejax._numerics)."""
        return q + rounded(self.beta / jnp.sqrt(visits + 1.0), self.beta)

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return greedy(self.scores(q, tables["visits"]), uniforms[0], self.tie_break)

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return greedy_probabilities(self.scores(q, tables["visits"]), self.tie_break)

    def update(self, tables: Mapping[str, Array], action: Array, delta_q: Array,
               context: Context) -> dict[str, Array]:
        return {"visits": count_visit(tables["visits"], action)}

    def validate(self) -> None:
        check_in_range("beta", self.beta, 0.0, math.inf, high_open=True)
        _check_tie_break(self.tie_break)


def make_explorer(name: str, param: float | None = None, **values: object) -> Explorer:
    """A registered explorer from its name, its swept parameter and any other fields.

    Args:
      name: a registered name (:data:`EXPLORERS`: the built-ins above and user plug-ins).
      param: the explorer's swept parameter (``EpsilonGreedy``: ε, ``Softmax``: τ,
        ``VDBE``: σ, …; its class's ``parameter``), or ``None`` for its default.
      **values: other fields (``tie_break``, ``delta``, ``tau`` …).

    Returns:
      the explorer, hyperparameters as float32 host scalars.

    Raises:
      ValueError: unknown name, unknown field or out-of-range value.
    """
    cls = explorer_class(name)
    values = dict(values)
    if param is not None:
        if cls.parameter is None:
            raise ValueError(f"param={param!r} is invalid: explorer {name!r} has no swept"
                             " parameter (give its fields instead)")
        values[cls.parameter] = param
    return build(cls, values, "explorer")


def explorer_class(name: str) -> type[Explorer]:
    """The explorer class registered as ``name`` (one-line ``ValueError`` if none)."""
    if name not in EXPLORERS:
        check_choice("explorer", name, EXPLORERS)
    return EXPLORERS[name]
