"""Thompson sampling (Thompson 1933) as an explorer: each step, one value per action is
drawn from a posterior over its mean and the largest is taken.

Two posteriors per (state, action), both read from the learner's Q and the explorer's own
visit counts ``n(s, a)`` (so the sample-average learner, whose Q is the mean reward of a
bandit arm, gives the textbook algorithms):

* ``gaussian``: ``θ(a) ~ N(Q(s, a), scale² / (n(s, a) + 1))``, Gaussian Thompson sampling
  (Agrawal & Goyal 2013, "Further optimal regret bounds for Thompson sampling", AISTATS;
  ``scale`` 1 is theirs);
* ``beta``: ``θ(a) ~ Beta(1 + n·Q, 1 + n·(1 − Q))``, Q clipped to [0, 1] as the success
  rate of rewards in {0, 1}: Bernoulli Thompson sampling with a uniform prior (Agrawal &
  Goyal 2012, "Analysis of Thompson sampling for the multi-armed bandit problem", COLT).

It is also the example of a plug-in whose random draws are sized from the task
(:meth:`ThompsonSampling.draws`): the Gaussian posterior asks for one normal per action,
the Beta one for a PRNG key (``jax.random.beta`` of every action at once); both for one
uniform breaking ties.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax._pytree import static_field
from vdbejax.methods.contract import Context, Draws, Explorer, Table
from vdbejax.methods.registry import explorer
from vdbejax.methods.selection import count_visit, greedy
from vdbejax.validation import check_choice, check_in_range

Array = jax.Array

#: The posteriors :class:`ThompsonSampling` draws from.
POSTERIORS = ("gaussian", "beta")


@explorer("thompson", parameter="scale", title="Thompson sampling")
class ThompsonSampling(Explorer):
    """Greedy on one draw per action from a posterior over its mean (module docstring).

    Attributes:
      scale: the Gaussian posterior's standard deviation at ``n = 0`` (``σ`` of the
        rewards; unused by ``beta``).
      posterior: ``gaussian`` or ``beta`` (static: each is its own program).
    """

    scale: float | Array = 1.0
    posterior: str = static_field("gaussian")

    def draws(self, num_actions: int) -> Draws:
        if self.posterior == "beta":
            return Draws(uniforms=1, keys=1)
        return Draws(uniforms=1, normals=num_actions)

    def tables(self) -> dict[str, Table]:
        return {"visits": Table("pair", 0.0)}

    def sample(self, q: Array, visits: Array, draws: tuple) -> Array:
        """The ``[A]`` posterior draws of a state (``draws``: :meth:`draws`' tuple)."""
        if self.posterior == "beta":
            rate = jnp.clip(q, 0.0, 1.0)
            successes = rounded(visits * rate, visits)  # rounded alone: the same bits anywhere
            return jax.random.beta(draws[1], 1.0 + successes, 1.0 + (visits - successes))
        normals = jnp.stack(draws[1:1 + q.shape[0]])
        spread = self.scale / jnp.sqrt(visits + 1.0)
        return q + rounded(spread * normals, spread)

    def select(self, q: Array, tables: Mapping[str, Array], context: Context,
               uniforms: tuple[Array, ...]) -> Array:
        return greedy(self.sample(q, tables["visits"], uniforms), uniforms[0])

    def update(self, tables: Mapping[str, Array], action: Array, delta_q: Array,
               context: Context) -> dict[str, Array]:
        return {"visits": count_visit(tables["visits"], action)}

    def validate(self) -> None:
        check_in_range("scale", self.scale, 0.0, math.inf, high_open=True)
        check_choice("posterior", self.posterior, POSTERIORS)
