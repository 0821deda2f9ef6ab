"""The canon's rules against their published formulas, each eager, under ``jax.jit`` and
under ``jax.vmap`` (a batch whose rows differ; every row must equal its own unbatched
call), in the manner of rlax's ``chex.variants``: MBIE-EB's and R-max's optimistic backup,
UCBVI's Hoeffding and Bernstein bonuses, UCB-H's learning rate and bonus, Dyna-Q+'s
κ·√τ bonus, Dyna's simulated update and Delayed Q-learning's attempted update."""
from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax.methods import model as model_lib
from vdbejax.methods.contract import Context, Transition
from vdbejax.methods.dyna import simulated_update
from vdbejax.methods.learners import make_learner
from vdbejax.methods.model_based import optimistic_backup

F = np.float32
S, A, K = 4, 2, 3


def variants(fn, batch):
    """``fn`` on every row of ``batch`` (a list of argument tuples): eager, jitted, and
    vmapped over the stacked rows; checks the three agree and returns the eager results."""
    eager = [fn(*args) for args in batch]
    jitted = [jax.jit(fn)(*args) for args in batch]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *batch)
    mapped = jax.vmap(fn)(*stacked)
    for i, (e, j) in enumerate(zip(eager, jitted, strict=True)):
        for a, b in zip(jax.tree.leaves(e), jax.tree.leaves(j), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
        for a, b in zip(jax.tree.leaves(e), jax.tree.leaves(jax.tree.map(lambda x: x[i], mapped)),
                        strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    return eager


def random_model(seed: int) -> model_lib.Model:
    rng = np.random.default_rng(seed)
    counts = rng.integers(0, 4, (S, A, K)).astype(F)
    terminal = rng.integers(0, 2, (S, A)).astype(F)
    visits = counts.sum(-1) + terminal
    rewards = rng.normal(size=(S, A)).astype(F) * visits
    return model_lib.Model(jnp.asarray(visits), jnp.asarray(rewards), jnp.asarray(rewards ** 2),
                           jnp.asarray(terminal),
                           jnp.asarray(rng.integers(0, S, (S, A, K)).astype(F)),
                           jnp.asarray(counts))


def np_expected(model: model_lib.Model, values: np.ndarray) -> np.ndarray:
    """Σ_k n_k / n · values(s′_k) (terminal outcomes worth 0), by loops."""
    out = np.zeros((S, A))
    for s in range(S):
        for a in range(A):
            n = max(float(model.visits[s, a]), 1.0)
            for k in range(K):
                out[s, a] += float(model.next_count[s, a, k]) / n * values[
                    int(model.next_state[s, a, k])]
    return out


def context(episode: int = 0) -> Context:
    return Context(episode=jnp.int32(episode), step=jnp.int32(1), terminal=jnp.bool_(False))


@pytest.mark.parametrize("method", ["mbie_eb", "rmax"])
def test_optimistic_backup_is_reward_plus_bonus_plus_discounted_expected_maximum(method):
    gamma, v_max = 0.9, 10.0
    rng = np.random.default_rng(1)
    batch = []
    for seed in range(3):
        model = random_model(seed)
        q = jnp.asarray(rng.normal(size=(S, A)).astype(F))
        # MBIE-EB: β/√n on visited pairs; R-max: no bonus, pairs known from m = 2 visits.
        bonus = (0.1 / np.sqrt(np.maximum(np.asarray(model.visits), 1.0))).astype(F) if (
            method == "mbie_eb") else np.zeros((S, A), F)
        known = np.asarray(model.visits) >= (1 if method == "mbie_eb" else 2)
        batch.append((model, q, jnp.float32(gamma), jnp.asarray(bonus), jnp.asarray(known),
                      jnp.float32(v_max)))
    results = variants(optimistic_backup, batch)
    for (model, q, _, bonus, known, _), got in zip(batch, results, strict=True):
        mean = np.asarray(model.reward_sum) / np.maximum(np.asarray(model.visits), 1.0)
        want = np.where(np.asarray(known), mean + np.asarray(bonus) + gamma * np_expected(
            model, np.asarray(q).max(1)), v_max)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("bonus", ["hoeffding", "bernstein"])
def test_ucbvi_bonuses_are_the_papers(bonus):
    H, scale, delta = 5, 0.7, 0.1
    learner = make_learner("ucbvi", horizon=H, bonus=bonus, bonus_scale=scale, delta=delta)

    def stage_bonus(model, episode, v_max, h):
        return learner.stage_bonus(model, context(episode))(model.visits, v_max, h)

    batch = [(random_model(seed), jnp.int32(episode), jnp.float32(v_max), jnp.int32(h))
             for seed, episode, v_max, h in ((0, 0, 5.0, 0), (1, 3, 4.0, 1), (2, 9, 1.0, 4))]
    results = variants(stage_bonus, batch)
    for (model, episode, v_max, _), got in zip(batch, results, strict=True):
        n = np.maximum(np.asarray(model.visits, np.float64), 1.0)
        if bonus == "hoeffding":  # c · 7 H L √(1/n), L = ln(5 S A T / δ), T = H · episodes
            log_term = math.log(5 * S * A * H * (int(episode) + 1) / delta)
            want = scale * 7 * H * log_term * np.sqrt(1 / n)
        else:  # min(c √(1/n) + v_max_h / n, v_max_h)
            want = np.minimum(scale * np.sqrt(1 / n) + float(v_max) / n, float(v_max))
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def stage_transition(reward, step, q_stage, visits, q_stage_next, discount=1.0):
    return Transition(q=jnp.float32(q_stage[0]), tables={"q_stage": jnp.asarray(q_stage, F),
                                                        "visits_stage": jnp.asarray(visits, F)},
                      reward=jnp.float32(reward), discount=jnp.float32(discount),
                      q_next=jnp.zeros(A, F),
                      tables_next={"q_stage": jnp.asarray(q_stage_next, F),
                                   "visits_stage": jnp.zeros((A, len(q_stage)), F)},
                      next_action=jnp.int32(0), next_probabilities=jnp.zeros(A, F),
                      uniforms=(), terminal=jnp.bool_(False), step=jnp.int32(step),
                      time=jnp.int32(0))


def test_ucb_h_learning_rate_and_bonus_are_the_papers():
    H, c, iota, r_max = 4, 0.5, 2.0, 1.0
    learner = make_learner("ucb_h", horizon=H, bonus_scale=c, iota=iota, r_max=r_max)
    rng = np.random.default_rng(2)
    batch = []
    for reward, step in ((0.3, 1), (-0.2, 2), (1.0, 4)):
        q_stage = rng.uniform(0, H, H).astype(F)
        visits = rng.integers(0, 5, H).astype(F)
        q_next = rng.uniform(0, 2 * H, (A, H)).astype(F)  # some above v_max = H · r_max
        batch.append((stage_transition(reward, step, q_stage, visits, q_next),))
    results = variants(lambda t: learner.update(t), batch)
    for (t,), got in zip(batch, results, strict=True):
        h = int(t.step) - 1
        visits = float(t.tables["visits_stage"][h]) + 1  # t, this visit included
        rate = (H + 1) / (H + visits)  # α_t = (H + 1)/(H + t)
        bonus = c * math.sqrt(H ** 3 * iota / visits)  # b_t = c √(H³ ι / t)
        later = np.asarray(t.tables_next["q_stage"])[:, min(h + 1, H - 1)]
        value = min(H * r_max, later.max()) if h + 1 < H else 0.0
        old = float(t.tables["q_stage"][h])
        want = old + rate * (float(t.reward) + float(t.discount) * value + bonus - old)
        assert float(got.tables["q_stage"][h]) == pytest.approx(want, rel=1e-5)
        assert float(got.tables["visits_stage"][h]) == visits
        others = np.delete(np.arange(H), h)
        np.testing.assert_array_equal(np.asarray(got.tables["q_stage"])[others],
                                      np.asarray(t.tables["q_stage"])[others])
        assert float(got.q) == pytest.approx(want if h == 0 else float(t.q), rel=1e-5)


def test_dyna_q_plus_bonus_is_kappa_root_tau():
    def bonus(learner, last):  # the learner is a pytree: κ is a leaf, batched by vmap
        return learner.planning_bonus(jnp.zeros((S, A), F), {"last_tried": last})

    rng = np.random.default_rng(3)
    batch = [(make_learner("dyna_q_plus", kappa=kappa),
              jnp.asarray(rng.integers(0, 50, (S, A)).astype(F))) for kappa in (1e-3, 0.01, 0.5)]
    results = variants(bonus, batch)
    for (learner, last), got in zip(batch, results, strict=True):
        tau = np.asarray(last).max() - np.asarray(last)  # iterations since last tried
        np.testing.assert_allclose(got, float(learner.kappa) * np.sqrt(tau), rtol=1e-6,
                                   atol=1e-7)


def test_dyna_simulated_update_is_q_learning_on_a_drawn_outcome():
    alpha, gamma = 0.5, 0.9
    batch = []
    for seed, (s, a, u) in enumerate(((0, 1, 0.05), (2, 0, 0.6), (3, 1, 0.99))):
        model = random_model(seed)
        q = jnp.asarray(np.random.default_rng(seed).normal(size=S * A).astype(F))
        batch.append((q, model, jnp.int32(s), jnp.int32(a), jnp.float32(u)))

    def update(q, model, s, a, u):
        return simulated_update(q, model, s, a, u, jnp.float32(alpha), jnp.float32(gamma),
                                jnp.float32(0.0), jnp.bool_(False))

    results = variants(update, batch)
    checked = 0
    for (q, model, s, a, u), got in zip(batch, results, strict=True):
        s, a = int(s), int(a)
        weights = np.r_[np.asarray(model.next_count[s, a]), float(model.terminal[s, a])]
        if weights.sum() == 0:
            continue  # an unvisited pair has no outcome to draw
        k = int(np.searchsorted(np.cumsum(weights) / weights.sum(), float(u), side="right"))
        reward = float(model.reward_sum[s, a]) / max(float(model.visits[s, a]), 1.0)
        table = np.asarray(q).reshape(S, A)
        future = 0.0 if k >= K else gamma * table[int(model.next_state[s, a, k])].max()
        want = table.copy()
        want[s, a] += alpha * (reward + future - table[s, a])
        np.testing.assert_allclose(np.asarray(got).reshape(S, A), want, rtol=1e-5, atol=1e-6)
        checked += 1
    assert checked >= 2


def test_delayed_q_attempts_its_update_after_m_targets():
    m, gamma, eps1 = 2.0, 0.9, 0.05
    learner = make_learner("delayed_q", updates=m, gamma=gamma, epsilon1=eps1)
    q0 = jnp.full((S, A), 10.0, F)
    q_next = jnp.asarray([1.0, 2.0], F)

    def case(s, a, reward, collected):  # (s, a) holds `collected` targets summing to 0.5 each
        tables = {name: jnp.zeros((S, A), F) for name in learner.tables()}
        tables["learning"] = jnp.ones((S, A), F)
        tables["targets"] = tables["targets"].at[s, a].set(collected)
        tables["target_sum"] = tables["target_sum"].at[s, a].set(0.5 * collected)
        q = q0.at[s, a].set(2.5)
        t = Transition(q=q[s, a], tables={}, reward=jnp.float32(reward),
                       discount=jnp.float32(gamma), q_next=q_next, tables_next={},
                       next_action=jnp.int32(0), next_probabilities=jnp.zeros(A, F),
                       uniforms=(), terminal=jnp.bool_(False), step=jnp.int32(1),
                       time=jnp.int32(7), state=jnp.int32(s), action=jnp.int32(a))
        return q, tables, t

    batch = [case(1, 0, 0.0, 1.0),  # 2nd target: mean (0.5 + 1.8)/2 = 1.15, 2.5 − 1.15 ≥ 0.1
             case(2, 1, 2.6, 1.0),  # 2nd target: mean (0.5 + 4.4)/2 = 2.45: not 0.1 below
             case(3, 1, 0.0, 0.0)]  # 1st target: collected, no attempt
    results = variants(lambda q, tables, t: learner.update_table(q, tables, t), batch)
    for (q, tables, t), got in zip(batch, results, strict=True):
        s, a = int(t.state), int(t.action)
        target = float(t.reward) + gamma * float(q_next.max())
        collected = float(tables["targets"][s, a])
        want = np.asarray(q).copy()
        if collected + 1 >= m:  # the attempted update: mean + ε₁ if ≥ 2ε₁ below Q(s, a)
            mean = (float(tables["target_sum"][s, a]) + target) / m
            if float(q[s, a]) - mean >= 2 * eps1:
                want[s, a] = mean + eps1
            assert float(got.tables["targets"][s, a]) == 0.0  # the collection starts again
            assert float(got.tables["attempted"][s, a]) == 8.0  # t = time + 1
        else:
            assert float(got.tables["targets"][s, a]) == collected + 1
            assert float(got.tables["target_sum"][s, a]) == pytest.approx(
                float(tables["target_sum"][s, a]) + target)
        np.testing.assert_allclose(got.q, want, rtol=1e-6)
    assert float(results[0].q[1, 0]) == pytest.approx(1.2)  # 1.15 + ε₁: the paper's rule
    assert float(results[1].q[2, 1]) == 2.5  # a failed attempt changes nothing
