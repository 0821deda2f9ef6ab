"""The explorers: the built-in action-selection plug-ins, built on the rules of
:mod:`vdbejax.methods.selection`.

The paper's four explorers are one rule, :func:`~vdbejax.methods.selection.select_action`::

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

Each explorer is a plug-in (:mod:`vdbejax.methods.contract`): a pytree dataclass of its
hyperparameters whose ``select``/``update``/``probabilities`` act on one agent's Q row.
The pure rules (``greedy``, ``select_action``, ``mixture_probabilities``,
``vdbe_epsilon_update``, the ``key``-taking ``egreedy``/``softmax``/``vdbe``/
``vdbe_softmax`` …) live in :mod:`vdbejax.methods.selection`.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded, sample_categorical
from vdbejax._pytree import static_field
from vdbejax.methods.contract import Context, Explorer, Table
from vdbejax.methods.registry import EXPLORERS, build, explorer
from vdbejax.methods.selection import (
    SOFTMAX_NUMERICS,
    TIE_BREAKS,
    VDBE_DELTA,
    VDBE_SOFTMAX_TAU,
    count_visit,
    decayed,
    greedy,
    greedy_probabilities,
    mixture_probabilities,
    select_action,
    softmax_probabilities,
    softmax_weights,
    vdbe_epsilon_update,
)
from vdbejax.validation import check_bool, check_choice, check_in_range, check_positive

Array = jax.Array

#: The paper's explorers.
PAPER_EXPLORERS = ("egreedy", "softmax", "vdbe", "vdbe_softmax")


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


@explorer("greedy", title="greedy")
class Greedy(Explorer):
    """Always a greedy action (ties broken by ``tie_break``): for learners whose Q holds
    their own exploration (R-max, MBIE-EB, UCBVI, PSRL, optimistic initial values)."""

    tie_break: str = static_field("random")
    num_uniforms = 1

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return greedy(q, uniforms[0], self.tie_break)

    def probabilities(self, q: Array, tables: Mapping[str, Array], context: Context) -> Array:
        return greedy_probabilities(q, self.tie_break)

    def validate(self) -> None:
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
