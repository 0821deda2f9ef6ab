"""Posterior sampling for RL (PSRL): one MDP drawn from the agent's posterior before each
episode, and solved by backward induction.

The posterior's Dirichlet draw is the method's cost (``S² A`` Gamma variates an episode,
``S (S + 1) A`` with a terminal outcome), so :func:`gamma_variates` is written for it:
Marsaglia & Tsang's (2000) exact rejection sampler: one vectorised proposal round over
all variates, then rounds over the few rejected ones, gathered into a small buffer. JAX's
own ``jax.random.gamma`` (a rejection loop per variate, vmapped) is several times slower on
the CPU.

The sampled table is kept successor-major, ``[S, S, A]`` (``[S + 1, S, A]`` with a
terminal outcome), so that the fixed-order sum over successors of every stage
(:func:`dirichlet_expected`) reads one contiguous ``[S, A]`` slice per successor.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp

from vdbejax._numerics import rounded
from vdbejax._pytree import static_field
from vdbejax.methods.contract import Context, LearnerUpdate, TaskFacts, Transition
from vdbejax.methods.finite_horizon import StageLearner, backward_induction
from vdbejax.methods.model import Model, bellman_backup
from vdbejax.methods.registry import learner
from vdbejax.validation import check_choice, check_in_range

Array = jax.Array

#: PSRL's prior outcomes (``terminal_outcome``): the task's (Osband et al. 2013), always
#: a terminal outcome (vdbejax's earlier prior), or never.
PSRL_TERMINAL_OUTCOMES = ("task", "always", "never")

def _proposal(key: Array, d: Array, c: Array) -> tuple[Array, Array]:
    """One Marsaglia–Tsang proposal per entry: (its value ``d v``, whether it is accepted)."""
    normal_key, uniform_key = jax.random.split(key)
    # Opaque to the compiler, which would otherwise fold the normal's own factor √2 into
    # the products below in some programs and not in others (other roundings).
    x = jax.random.normal(normal_key, d.shape, jnp.float32)
    x = rounded(x, x)
    log_u = jnp.log1p(-jax.random.uniform(uniform_key, d.shape, jnp.float32))  # U ∈ (0, 1]
    t = 1.0 + rounded(c * x, c)
    v = t * t * t
    positive = v > 0
    log_v = jnp.log(jnp.where(positive, v, 1.0))
    bound = rounded(0.5 * x * x, x) + (d - rounded(d * v, d)) + rounded(d * log_v, d)
    return rounded(d * v, d), positive & (log_u < bound)


#: The rejected entries of the first round are redrawn in a buffer of this share of the
#: entries (about 5 % are rejected); should more be, the rest are redrawn in place.
RETRY_SHARE = 8


def _rounds(key: Array, d: Array, c: Array, value: Array, done: Array) -> Array:
    """Proposal rounds over all entries of ``d`` until every one has accepted."""
    def propose(carry: tuple) -> tuple:
        value, done, round_ = carry
        candidate, accepted = _proposal(jax.random.fold_in(key, round_), d, c)
        return jnp.where(accepted & ~done, candidate, value), done | accepted, round_ + 1

    start = (value, done, jnp.asarray(0, jnp.uint32))
    return jax.lax.while_loop(lambda carry: ~jnp.all(carry[1]), propose, start)[0]


def gamma_variates(key: Array, alpha: Array) -> Array:
    """Independent Gamma(α, 1) variates, one per entry of ``alpha`` (all > 0), float32.

    Marsaglia & Tsang (2000, "A simple method for generating gamma variables", ACM TOMS
    26(3)) for α ≥ 1; for α < 1, Gamma(α + 1) · U^{1/α} (their section 6). Exact: every
    entry keeps its first accepted proposal. One vectorised round proposes for every
    entry (each accepts with probability ≥ 0.95); the rejected ones are gathered into a
    buffer of 1/:data:`RETRY_SHARE` of the entries and proposed for there until all have
    accepted, and any beyond the buffer in place. A pure function of ``key``: the same
    bits in every engine strategy and batch.
    """
    alpha = jnp.asarray(alpha, jnp.float32)
    shape = alpha.shape
    boosted = alpha < 1.0
    d = (jnp.where(boosted, alpha + 1.0, alpha) - 1.0 / 3.0).reshape(-1)
    c = jnp.sqrt(1.0 / (9.0 * d))  # exact in every program (XLA approximates an rsqrt)
    first_key, retry_key, rest_key, boost_key = jax.random.split(key, 4)
    value, done = _proposal(first_key, d, c)
    n = d.shape[0]
    size = max(1, -(-n // RETRY_SHARE))
    where = jnp.nonzero(~done, size=size, fill_value=n)[0]  # n: an empty slot
    empty = where == n
    slot = jnp.minimum(where, n - 1)
    retried = _rounds(retry_key, d[slot], c[slot], jnp.zeros(size, jnp.float32), empty)
    value = value.at[where].set(retried, mode="drop")
    done = done.at[where].set(True, mode="drop")
    value = _rounds(rest_key, d, c, value, done).reshape(shape)  # no round, but rarely
    log_u = jnp.log1p(-jax.random.uniform(boost_key, shape, jnp.float32))
    inverse = 1.0 / jnp.where(boosted, alpha, 1.0)  # a product below, not a division:
    scale = jnp.exp(rounded(log_u * inverse, inverse))  # XLA rewrites some divisions
    return jnp.where(boosted, value * scale, value)


def posterior_sample(model: Model, key: Array, prior: Any, reward_prior_mean: Any,
                     terminal: bool = True) -> tuple[Array, Array]:
    """One MDP from the posterior: transitions ``Dirichlet(prior + counts)`` over the S
    states, and "terminal" where ``terminal`` (static), rewards ``N((μ₀ + Σr)/(1 + n),
    1/(1 + n))`` (prior N(μ₀, 1), unit noise). Returns ``(rewards [S, A], transitions
    [S (+ 1), S, A])``: successor-major, outcome S (with ``terminal``) is "terminal"."""
    S, A = model.visits.shape
    index = model.next_state.astype(jnp.int32)
    successor = jnp.arange(S)[:, None, None]
    counts = jnp.zeros((S, S, A), jnp.float32)
    for k in range(index.shape[-1]):  # the listed successors' counts, one slot at a time
        counts = counts + jnp.where(successor == index[None, ..., k],
                                    model.next_count[None, ..., k], 0.0)
    if terminal:
        counts = jnp.concatenate([counts, model.terminal[None]], axis=0)  # no scatter
    transitions_key, rewards_key = jax.random.split(key)
    gammas = gamma_variates(transitions_key, prior + counts)

    def add(j: Any, total: Array) -> Array:  # the normaliser, in order of successors
        return total + gammas[j]

    total = jax.lax.fori_loop(0, counts.shape[0], add, jnp.zeros((S, A), jnp.float32))
    # Products by reciprocals, not divisions: XLA turns a division by a broadcast value
    # into such a product in some programs only (other bits).
    transitions = gammas * (1.0 / total)
    precision = 1.0 + model.visits
    mean = (reward_prior_mean + model.reward_sum) / precision
    noise = jax.random.normal(rewards_key, (S, A))
    spread = jnp.sqrt(1.0 / precision)  # exact (no rsqrt)
    return mean + rounded(rounded(noise, noise) * spread, spread), transitions


def dirichlet_expected(values: Array, sample: Array) -> Array:
    """``[S, A]`` Σ_s′ P̃(s′ | s, a) · values(s′) for a sampled successor-major
    ``[S, S, A]`` table, or ``[S + 1, S, A]`` whose last outcome is "terminal" (worth 0),
    summed in order of s′ (the same bits under any batching)."""
    def add(s_next: Any, total: Array) -> Array:
        p = sample[s_next]
        return total + rounded(p * values[s_next], p)

    return jax.lax.fori_loop(0, values.shape[0], add, jnp.zeros(sample.shape[1:], values.dtype))


@learner("psrl", title="PSRL")
class PSRL(StageLearner):
    """Posterior sampling for RL (Osband, Russo & Van Roy 2013, "(More) efficient
    reinforcement learning via posterior sampling", NeurIPS, Alg. 1): before each episode
    (``plan_at = "episode"``) one MDP is drawn from the posterior (:func:`posterior_sample`:
    a Dirichlet over the outcomes with ``prior`` per outcome, Gaussian rewards with prior
    mean ``reward_prior_mean``) and solved by backward induction over ``horizon`` stages;
    the agent follows its greedy policy (explorer ``greedy``).

    The Dirichlet's outcomes (``terminal_outcome``, static): ``"task"`` (the default, the
    paper's prior): the S successor states, and a "terminal" outcome only where the task
    has terminal outcomes (the engine tells, :meth:`for_task`); ``"always"``: the S states
    and "terminal" on every task (vdbejax's prior before 2026-12-05, which also puts mass
    on ending a task that never ends); ``"never"``: the S states (refused on a task with
    terminal outcomes).

    The draw comes from a key made of two of the agent's plan uniforms, so it is a pure
    function of the agent's stream. Costs ``S² A`` Gamma variates and ``S² A`` products per
    stage each episode (``S (S + 1) A`` with "terminal"; a dense sampled table): meant for
    small tasks (RiverSwim, chains, DeepSea of a few rows, gridworlds).
    """

    gamma: float | Array = 1.0
    prior: float | Array = 1.0
    reward_prior_mean: float | Array = 0.0
    terminal_outcome: str = static_field("task")
    uses_model = True
    plan_at = "episode"
    plan_uniforms = 2

    def for_task(self, task: TaskFacts) -> PSRL:
        if self.terminal_outcome == "never" and task.terminates:
            raise ValueError("terminal_outcome='never' is invalid on this task: it has"
                             " terminal outcomes (use 'task' or 'always')")
        if self.terminal_outcome != "task":
            return self
        return dataclasses.replace(self, terminal_outcome="always" if task.terminates
                                   else "never")

    def update(self, t: Transition) -> LearnerUpdate:  # the values come from planning
        return LearnerUpdate(t.q, dict(t.tables), jnp.zeros_like(t.q))

    def plan(self, q: Array, tables: Mapping[str, Array], model: Any, context: Context,
             uniforms: tuple[Array, ...]) -> tuple[Array, dict[str, Array]]:
        bits = [(u * 2.0 ** 23).astype(jnp.uint32) for u in uniforms]
        key = jax.random.wrap_key_data(jnp.stack([bits[0], bits[1]]), impl="threefry2x32")
        if self.terminal_outcome == "task":
            raise ValueError("psrl with terminal_outcome='task' needs to know whether the task"
                             " has terminal outcomes: run it through the engine"
                             " (vdbejax.run_grid or run_agents), or give 'always' or 'never'")
        rewards, transitions = posterior_sample(model, key, self.prior, self.reward_prior_mean,
                                                self.terminal_outcome == "always")

        def stage(values: Array, _: Any) -> tuple:
            q_h = bellman_backup(rewards, self.gamma, dirichlet_expected(values, transitions))
            return jnp.max(q_h, axis=1), q_h

        stages = backward_induction(stage, jnp.zeros(q.shape[0], jnp.float32), self.horizon)
        return stages[..., 0], {"q_stage": stages}

    def validate(self) -> None:
        super().validate()
        check_in_range("gamma", self.gamma, 0.0, 1.0)
        check_in_range("prior", self.prior, 0.0, 1e30, low_open=True)
        check_in_range("reward_prior_mean", self.reward_prior_mean, -1e30, 1e30)
        check_choice("terminal_outcome", self.terminal_outcome, PSRL_TERMINAL_OUTCOMES)


__all__ = ["PSRL", "PSRL_TERMINAL_OUTCOMES", "RETRY_SHARE", "dirichlet_expected",
           "gamma_variates", "posterior_sample"]
