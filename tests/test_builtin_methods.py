"""The built-in explorers and learners beyond the paper's (UCB-1, decaying ε-greedy and
softmax, Max-Boltzmann, Expected SARSA, Double Q-learning) against their formulas, under
jit and vmap, inside the engine, and the one-line errors of broken plug-ins."""
import dataclasses
import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from absl.testing import parameterized

from vdbejax.engine import EngineOptions, agent_keys, broadcast_agents, run_agents
from vdbejax.envs.table_cleaning import make_mdp as _make_mdp
from vdbejax.methods import (
    EXPLORERS,
    LEARNERS,
    Context,
    Explorer,
    Learner,
    LearnerUpdate,
    Setting,
    Table,
    Transition,
    explorer,
    learner,
    make_agent,
    stack_agents,
)
from vdbejax.methods.explorers import UCB1, make_explorer
from vdbejax.methods.learners import (
    double_q_learning_target,
    expected_sarsa_target,
    make_learner,
    td_update,
)
from vdbejax.methods.selection import (
    decayed,
    greedy,
    greedy_probabilities,
    mixture_probabilities,
    softmax_probabilities,
)
from vdbejax.runs import run_grid

NUM_DRAWS = 20_000
Q = jnp.array([0.1, 0.5, -0.2, 0.3, 0.0, -1.0, 0.45])  # unique maximum: action 1
BUILTIN_EXPLORERS = ("egreedy", "softmax", "vdbe", "vdbe_softmax", "max_boltzmann",
                     "egreedy_decay", "softmax_decay", "ucb1", "count_bonus")
BUILTIN_LEARNERS = ("qlearning", "sarsa", "expected_sarsa", "double_qlearning")


@functools.cache
def make_mdp(max_steps=100):
    """The table-cleaning task (108 states, 7 actions), built once per length."""
    return _make_mdp(max_steps=max_steps)


def context(episode=0, step=0):
    return Context(episode=jnp.asarray(episode, jnp.int32), step=jnp.asarray(step, jnp.int32),
                   terminal=jnp.asarray(False))


def frequencies(select, num_uniforms=3, num_actions=7, key=0):
    """Empirical distribution of ``select(uniforms)`` over NUM_DRAWS fixed keys."""
    keys = jax.random.split(jax.random.PRNGKey(key), NUM_DRAWS)

    def draw(k):
        u = jax.random.uniform(k, (num_uniforms,))
        return select(tuple(u[i] for i in range(num_uniforms)))

    actions = np.asarray(jax.jit(jax.vmap(draw))(keys))
    return np.bincount(actions, minlength=num_actions) / NUM_DRAWS


def assert_matches(freq, probs):
    probs = np.asarray(probs, np.float64)
    # 5 binomial standard deviations (plus a floor for p ≈ 0): fixed keys, so no flakes.
    tolerance = 5 * np.sqrt(probs * (1 - probs) / NUM_DRAWS) + 1e-4
    np.testing.assert_array_less(np.abs(freq - probs), tolerance)


def np_softmax(q, tau):
    logits = np.asarray(q, np.float64) / tau
    w = np.exp(logits - logits.max())
    return w / w.sum()


def onehot(index, n=7):
    return np.eye(n)[index]


# --------------------------------------------------------------------------- UCB-1
def np_ucb_scores(q, counts, c):
    q, counts = np.asarray(q, np.float64), np.asarray(counts, np.float64)
    return q + c * np.sqrt(np.log(counts.sum()) / counts)


def ucb_select(ucb, q, counts, u):
    return int(ucb.select(jnp.asarray(q, jnp.float32), {"counts": jnp.asarray(counts, jnp.float32)},
                          context(), (jnp.float32(u),)))


def test_ucb1_tries_untried_actions_first():
    q = [0.3, -0.2, 0.9, 0.1, 2.0]        # action 4 has by far the largest Q …
    counts = [3.0, 0.0, 5.0, 0.0, 7.0]    # … but actions 1 and 3 are untried
    first = make_explorer("ucb1", 1.0, tie_break="first")
    assert {ucb_select(first, q, counts, u) for u in (0.0, 0.3, 0.7, 0.999)} == {1}
    np.testing.assert_array_equal(
        first.probabilities(jnp.asarray(q), {"counts": jnp.asarray(counts)}, context()),
        [0, 1, 0, 0, 0])
    rand = make_explorer("ucb1", 1.0)
    np.testing.assert_array_equal(
        rand.probabilities(jnp.asarray(q), {"counts": jnp.asarray(counts)}, context()),
        [0, 0.5, 0, 0.5, 0])
    freq = frequencies(lambda u: rand.select(jnp.asarray(q), {"counts": jnp.asarray(counts)},
                                             context(), u), num_uniforms=1, num_actions=5)
    assert_matches(freq, [0, 0.5, 0, 0.5, 0])
    # One untried action left: it is chosen whatever its Q and whatever c.
    for c in (0.0, 1.0, 100.0):
        ucb = make_explorer("ucb1", c)
        assert {ucb_select(ucb, q, [1, 2, 3, 4, 0], u) for u in (0.0, 0.5, 0.999)} == {4}
        assert {ucb_select(ucb, [5.0, 0.0, 0.0], [0, 2, 2], u) for u in (0.0, 0.999)} == {0}


@pytest.mark.parametrize("c", [0.0, 0.5, 1.0, 2.0, 10.0])
def test_ucb1_picks_the_upper_confidence_bound_maximum(c):
    # Hand-made row: N(s) = 11, ln 11 = 2.3979; bonus·c⁻¹ = √(2.3979/n) =
    # 0.894 (n=3), 1.548 (n=1), 0.693 (n=5), 1.095 (n=2): c = 1 → action 2, c = 2 → action 1.
    q, counts = [0.3, -0.2, 0.9, 0.1], [3.0, 1.0, 5.0, 2.0]
    expected = {0.0: 2, 0.5: 2, 1.0: 2, 2.0: 1, 10.0: 1}[c]
    rows = [(q, counts)]
    rng = np.random.default_rng(int(c * 10))
    while len(rows) < 40:
        row_q = rng.normal(size=6).round(3)
        row_counts = rng.integers(1, 30, size=6).astype(float)
        scores = np.sort(np_ucb_scores(row_q, row_counts, c))
        if scores[-1] - scores[-2] > 1e-3:  # clear maximum (float32 cannot flip it)
            rows.append((row_q, row_counts))
    for i, (row_q, row_counts) in enumerate(rows):
        scores = np_ucb_scores(row_q, row_counts, c)
        best = int(np.argmax(scores))
        if i == 0:
            assert best == expected
        for tie_break in ("random", "first"):
            ucb = make_explorer("ucb1", c, tie_break=tie_break)
            tables = {"counts": jnp.asarray(row_counts, jnp.float32)}
            np.testing.assert_allclose(ucb.scores(jnp.asarray(row_q, jnp.float32), tables["counts"]),
                                       scores, rtol=1e-5, atol=1e-5)
            assert {ucb_select(ucb, row_q, row_counts, u) for u in (0.0, 0.5, 0.999)} == {best}
            np.testing.assert_array_equal(
                ucb.probabilities(jnp.asarray(row_q, jnp.float32), tables, context()),
                onehot(best, len(row_q)))


def test_ucb1_ties_are_uniform_or_first():
    # Actions 0 and 2 have equal Q and counts, so equal bounds (1.2 + √(ln 8 / 2) = 2.220).
    q, counts = [1.2, 0.2, 1.2], [2.0, 4.0, 2.0]
    assert np.argmax(np_ucb_scores(q, counts, 1.0)) in (0, 2)
    tables = {"counts": jnp.asarray(counts)}
    rand, first = make_explorer("ucb1", 1.0), make_explorer("ucb1", 1.0, tie_break="first")
    np.testing.assert_array_equal(rand.probabilities(jnp.asarray(q), tables, context()), [0.5, 0, 0.5])
    np.testing.assert_array_equal(first.probabilities(jnp.asarray(q), tables, context()), [1, 0, 0])
    freq = frequencies(lambda u: rand.select(jnp.asarray(q), tables, context(), u), 1, 3)
    assert_matches(freq, [0.5, 0, 0.5])
    assert {ucb_select(first, q, counts, u) for u in (0.0, 0.6, 0.999)} == {0}


@pytest.mark.parametrize("beta", [0.0, 0.05, 0.5])
def test_count_bonus_is_greedy_on_q_plus_its_bonus(beta):
    rng = np.random.default_rng(7)
    bonus = make_explorer("count_bonus", beta, tie_break="first")
    for _ in range(20):
        q = rng.normal(size=5).astype(np.float32) * 0.1
        visits = rng.integers(0, 6, 5).astype(np.float32)
        scores = q + np.float32(beta) / np.sqrt(visits + np.float32(1.0))
        context = Context(jnp.int32(0), jnp.int32(0), jnp.asarray(False))
        action = bonus.select(jnp.asarray(q), {"visits": jnp.asarray(visits)}, context,
                              (jnp.float32(0.5),))
        assert int(action) == int(np.argmax(scores))
        probs = bonus.probabilities(jnp.asarray(q), {"visits": jnp.asarray(visits)}, context)
        np.testing.assert_array_equal(np.asarray(probs), np.eye(5)[np.argmax(scores)])


def test_count_bonus_update_counts_the_chosen_action_only():
    bonus = make_explorer("count_bonus", 0.1)
    context = Context(jnp.int32(0), jnp.int32(0), jnp.asarray(False))
    new = bonus.update({"visits": jnp.asarray([1.0, 0.0, 2.0])}, jnp.int32(2), jnp.float32(0.3),
                       context)
    np.testing.assert_array_equal(np.asarray(new["visits"]), [1.0, 0.0, 3.0])
    with pytest.raises(ValueError, match="beta"):
        make_explorer("count_bonus", -1.0)


def test_ucb1_update_counts_the_chosen_action_only():
    ucb = make_explorer("ucb1", 1.0)
    assert ucb.tables() == {"counts": Table("pair", 0.0)}
    counts = jnp.array([3.0, 0.0, 5.0, 2.0])
    for action, expected in [(0, [4, 0, 5, 2]), (1, [3, 1, 5, 2]), (3, [3, 0, 5, 3])]:
        for delta_q in (0.0, -0.7, 12.0):  # ΔQ does not matter
            new = ucb.update({"counts": counts}, jnp.int32(action), jnp.float32(delta_q), context())
            assert set(new) == {"counts"}
            np.testing.assert_array_equal(new["counts"], expected)


# --------------------------------------------------------------------------- decaying
@pytest.mark.parametrize("episode", [0, 1, 5, 20, 29, 30, 100, 5000])
def test_decaying_egreedy_epsilon_per_episode(episode):
    e = make_explorer("egreedy_decay", 0.8, decay=0.9, epsilon_min=0.05)
    # 0.8·0.9^k: 0.8, 0.72, 0.4724, 0.0973 (k = 20), 0.0377→0.05 (k = 29) …:
    # the minimum binds from k = 27 on.
    epsilon = max(0.05, 0.8 * 0.9**episode)
    np.testing.assert_allclose(decayed(e.epsilon, e.decay, e.epsilon_min, jnp.int32(episode)),
                               epsilon, rtol=1e-5)
    for q in (Q, jnp.array([0.0, 0.7, 0.2, 0.7, 0.7, -1.0, 0.0])):
        for tie_break in ("random", "first"):
            e = make_explorer("egreedy_decay", 0.8, decay=0.9, epsilon_min=0.05, tie_break=tie_break)
            got = e.probabilities(q, {}, context(episode))
            np.testing.assert_allclose(got, mixture_probabilities(q, epsilon, None, tie_break),
                                       rtol=1e-5, atol=1e-7)
    q = np.asarray(Q, np.float64)
    np.testing.assert_allclose(e.probabilities(Q, {}, context(episode, step=17)),
                               epsilon / 7 + (1 - epsilon) * onehot(int(np.argmax(q))), rtol=1e-5)


@pytest.mark.parametrize("episode", [0, 3, 10, 14, 50, 10_000])
def test_decaying_softmax_tau_per_episode(episode):
    e = make_explorer("softmax_decay", 2.0, decay=0.8, tau_min=0.1)
    # 2·0.8^k: 2, 1.024, 0.2147, 0.0880→0.1 (min binds from k = 14 on) …
    tau = max(0.1, 2.0 * 0.8**episode)
    np.testing.assert_allclose(decayed(e.tau, e.decay, e.tau_min, jnp.int32(episode)), tau, rtol=1e-5)
    got = e.probabilities(Q, {}, context(episode))
    np.testing.assert_allclose(got, softmax_probabilities(Q, tau), rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(got, np_softmax(Q, tau), rtol=1e-4, atol=1e-7)


def test_decaying_schedules_differ_between_episodes():
    # Guards the test above: one episode more is a visibly different distribution.
    e = make_explorer("egreedy_decay", 0.8, decay=0.9, epsilon_min=0.05)
    s = make_explorer("softmax_decay", 2.0, decay=0.8, tau_min=0.1)
    for k in (0, 5):
        for x in (e, s):
            a, b = x.probabilities(Q, {}, context(k)), x.probabilities(Q, {}, context(k + 1))
            assert np.abs(np.asarray(a) - np.asarray(b)).max() > 1e-3


def test_decaying_egreedy_frequencies():
    e = make_explorer("egreedy_decay", 0.8, decay=0.9, epsilon_min=0.05)
    epsilon = 0.8 * 0.9**5  # 0.4724
    freq = frequencies(lambda u: e.select(Q, {}, context(5), u))
    assert_matches(freq, epsilon / 7 + (1 - epsilon) * onehot(1))
    freq = frequencies(lambda u: e.select(Q, {}, context(60), u))  # min binds: ε = 0.05
    assert_matches(freq, 0.05 / 7 + 0.95 * onehot(1))


def test_decaying_softmax_frequencies():
    s = make_explorer("softmax_decay", 2.0, decay=0.8, tau_min=0.1)
    freq = frequencies(lambda u: s.select(Q, {}, context(3), u))
    assert_matches(freq, np_softmax(Q, 2.0 * 0.8**3))  # τ = 1.024
    freq = frequencies(lambda u: s.select(Q, {}, context(40), u))
    assert_matches(freq, np_softmax(Q, 0.1))


# --------------------------------------------------------------------------- Max-Boltzmann
@pytest.mark.parametrize("epsilon, tau", [(0.3, 0.2), (0.6, 1.0), (1.0, 0.5), (0.0, 0.5)])
def test_max_boltzmann_frequencies(epsilon, tau):
    m = make_explorer("max_boltzmann", epsilon, tau=tau)
    formula = epsilon * np_softmax(Q, tau) + (1 - epsilon) * onehot(1)
    np.testing.assert_allclose(m.probabilities(Q, {}, context()), formula, rtol=1e-5, atol=1e-7)
    freq = frequencies(lambda u: m.select(Q, {}, context(), u))
    assert_matches(freq, formula)


def test_max_boltzmann_ties():
    q = jnp.array([0.0, 0.7, 0.2, 0.7, 0.7, -1.0, 0.0])
    soft = np_softmax(q, 0.3)
    m = make_explorer("max_boltzmann", 0.4, tau=0.3)
    assert_matches(frequencies(lambda u: m.select(q, {}, context(), u)),
                   0.4 * soft + 0.6 * np.array([0, 1, 0, 1, 1, 0, 0]) / 3)
    m = make_explorer("max_boltzmann", 0.4, tau=0.3, tie_break="first")
    assert_matches(frequencies(lambda u: m.select(q, {}, context(), u)), 0.4 * soft + 0.6 * onehot(1))


# --------------------------------------------------------------------------- learners
Q_NEXT = jnp.array([0.2, 0.7, -0.1])
Q2_NEXT = jnp.array([0.6, 0.1, 0.4])


def transition(q=0.5, q2=None, reward=-0.01, discount=0.9, q_next=Q_NEXT, q2_next=None,
               next_probabilities=None, uniforms=()):
    tables = {} if q2 is None else {"q2": jnp.float32(q2)}
    tables_next = {} if q2_next is None else {"q2": q2_next}
    probs = jnp.zeros_like(q_next) if next_probabilities is None else next_probabilities
    return Transition(q=jnp.float32(q), tables=tables, reward=jnp.float32(reward),
                      discount=jnp.float32(discount), q_next=q_next, tables_next=tables_next,
                      next_action=jnp.int32(0), next_probabilities=probs,
                      uniforms=tuple(jnp.float32(u) for u in uniforms),
                      terminal=jnp.bool_(discount == 0))


def test_expected_sarsa_hand_computed():
    pi = jnp.array([0.25, 0.5, 0.25])
    # Σ π Q' = 0.05 + 0.35 − 0.025 = 0.375; target = −0.01 + 0.9·0.375 = 0.3275
    assert float(expected_sarsa_target(-0.01, 0.9, Q_NEXT, pi)) == pytest.approx(0.3275, abs=1e-6)
    # Terminal: the reward alone.
    assert float(expected_sarsa_target(1.0, 0.0, Q_NEXT, pi)) == 1.0
    # One-hot π on the maximum: the Q-learning target 0.62; uniform π: −0.01 + 0.9·0.2667 = 0.23
    greedy_pi, uniform_pi = jnp.array([0.0, 1.0, 0.0]), jnp.full(3, 1 / 3)
    assert float(expected_sarsa_target(-0.01, 0.9, Q_NEXT, greedy_pi)) == pytest.approx(0.62)
    assert float(expected_sarsa_target(-0.01, 0.9, Q_NEXT, uniform_pi)) == pytest.approx(0.23, abs=1e-6)
    # ΔQ = 0.8·(0.3275 − 0.5) = −0.138; Q = 0.362
    result = make_learner("expected_sarsa").update(transition(next_probabilities=pi))
    assert isinstance(result, LearnerUpdate) and result.tables == {}
    assert float(result.q) == pytest.approx(0.362, abs=1e-6)
    assert float(result.delta_q) == pytest.approx(-0.138, abs=1e-6)
    # α = 0.5, terminal, r = 1: ΔQ = 0.5·(1 − 0.5) = 0.25
    result = make_learner("expected_sarsa", alpha=0.5).update(
        transition(reward=1.0, discount=0.0, next_probabilities=pi))
    assert (float(result.q), float(result.delta_q)) == (pytest.approx(0.75), pytest.approx(0.25))


def test_double_q_learning_target_uses_the_other_tables_value():
    # argmax of the selector (0.7 at 1) valued by the other table (0.1): −0.01 + 0.9·0.1 = 0.08
    assert float(double_q_learning_target(-0.01, 0.9, Q2_NEXT, Q_NEXT)) == pytest.approx(0.08)
    # argmax Q2' = 0, valued by Q': −0.01 + 0.9·0.2 = 0.17
    assert float(double_q_learning_target(-0.01, 0.9, Q_NEXT, Q2_NEXT)) == pytest.approx(0.17)
    # Ties in the selector: the lowest index.
    assert float(double_q_learning_target(0.0, 1.0, jnp.array([1.0, 2.0, 3.0]),
                                          jnp.array([0.4, 0.1, 0.4]))) == 1.0
    assert float(double_q_learning_target(2.0, 0.0, Q_NEXT, Q2_NEXT)) == 2.0


@pytest.mark.parametrize("u", [0.0, 0.2, 0.4999])
def test_double_q_learning_updates_the_first_table_when_u_below_half(u):
    dq = make_learner("double_qlearning")
    assert dq.tables() == {"q2": Table("pair", 0.0)}
    # Q is updated: target = −0.01 + 0.9·Q2'(s', argmax Q'(s') = 1) = −0.01 + 0.9·0.1 = 0.08;
    # ΔQ = 0.8·(0.08 − 0.5) = −0.336, Q = 0.164; Q2(s,a) = 0.3 unchanged.
    result = dq.update(transition(q=0.5, q2=0.3, q2_next=Q2_NEXT, uniforms=(u,)))
    assert float(result.q) == pytest.approx(0.164, abs=1e-6)
    assert float(result.delta_q) == pytest.approx(-0.336, abs=1e-6)
    assert set(result.tables) == {"q2"} and float(result.tables["q2"]) == pytest.approx(0.3)


@pytest.mark.parametrize("u", [0.5, 0.7, 0.9999])
def test_double_q_learning_updates_the_second_table_otherwise(u):
    dq = make_learner("double_qlearning")
    # Q2 is updated: target = −0.01 + 0.9·Q'(s', argmax Q2'(s') = 0) = −0.01 + 0.9·0.2 = 0.17;
    # ΔQ = 0.8·(0.17 − 0.3) = −0.104, Q2 = 0.196; Q(s,a) = 0.5 unchanged.
    result = dq.update(transition(q=0.5, q2=0.3, q2_next=Q2_NEXT, uniforms=(u,)))
    assert float(result.q) == pytest.approx(0.5)
    assert float(result.tables["q2"]) == pytest.approx(0.196, abs=1e-6)
    assert float(result.delta_q) == pytest.approx(-0.104, abs=1e-6)
    # Terminal (discount 0), r = 1: Q2 = 0.3 + 0.8·(1 − 0.3) = 0.86
    result = dq.update(transition(q=0.5, q2=0.3, reward=1.0, discount=0.0, q2_next=Q2_NEXT,
                                  uniforms=(u,)))
    assert float(result.tables["q2"]) == pytest.approx(0.86, abs=1e-6)
    assert float(result.delta_q) == pytest.approx(0.56, abs=1e-6)


def test_double_q_learning_acts_on_the_sum_of_its_tables():
    dq = make_learner("double_qlearning", q_init=0.25)
    assert dq.tables() == {"q2": Table("pair", 0.25)}
    np.testing.assert_allclose(dq.behaviour(Q_NEXT, {"q2": Q2_NEXT}), [0.8, 0.8, 0.3], rtol=1e-6)
    np.testing.assert_array_equal(dq.initial_q(jax.random.PRNGKey(0), 2, 3), np.full((2, 3), 0.25))


# --------------------------------------------------------------------------- jit and vmap
BATCH = 16


def explorer_batch(name):
    """BATCH instances of one explorer with different hyperparameters, and inputs."""
    rng = np.random.default_rng(BUILTIN_EXPLORERS.index(name))
    params = {"egreedy": rng.uniform(0, 1, BATCH), "softmax": rng.uniform(0.05, 2, BATCH),
              "vdbe": rng.uniform(0.05, 5, BATCH), "vdbe_softmax": rng.uniform(0.05, 5, BATCH),
              "max_boltzmann": rng.uniform(0, 1, BATCH), "egreedy_decay": rng.uniform(0.2, 1, BATCH),
              "softmax_decay": rng.uniform(0.2, 3, BATCH), "ucb1": rng.uniform(0, 3, BATCH),
              "count_bonus": rng.uniform(0, 1, BATCH)}[name]
    extra = {"vdbe_softmax": lambda: {"tau": float(rng.uniform(0.05, 1))},
             "max_boltzmann": lambda: {"tau": float(rng.uniform(0.05, 1))},
             "egreedy_decay": lambda: {"decay": float(rng.uniform(0.8, 1))},
             "softmax_decay": lambda: {"decay": float(rng.uniform(0.8, 1))}}.get(name, dict)
    instances = [make_explorer(name, float(p), **extra()) for p in params]
    q = rng.normal(size=(BATCH, 7)).astype(np.float32)
    tables = {}
    for key, spec in instances[0].tables().items():
        if spec.per == "state":
            tables[key] = rng.uniform(0, 1, BATCH).astype(np.float32)
        else:  # counts: rows with and without untried actions
            tables[key] = rng.integers(0, 4, (BATCH, 7)).astype(np.float32)
            tables[key][::2] += 1.0
    contexts = Context(episode=rng.integers(0, 60, BATCH).astype(np.int32),
                       step=rng.integers(0, 30, BATCH).astype(np.int32),
                       terminal=np.zeros(BATCH, bool))
    n = instances[0].num_uniforms
    uniforms = tuple(rng.uniform(0, 1, BATCH).astype(np.float32) for _ in range(n))
    stacked = jax.tree.map(lambda *leaves: np.stack(leaves), *instances)
    return instances, stacked, q, tables, contexts, uniforms, rng.integers(0, 7, BATCH).astype(np.int32)


def row(tree, i):
    return jax.tree.map(lambda leaf: jnp.asarray(leaf[i]), tree)


def assert_trees_equal(got, want):
    """Equal structures; integers exactly, floats to float32 rounding."""
    assert jax.tree.structure(got) == jax.tree.structure(want)
    for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        g, w = np.asarray(g), np.asarray(w)
        assert g.shape == w.shape and g.dtype == w.dtype, (g.shape, g.dtype, w.shape, w.dtype)
        if np.issubdtype(w.dtype, np.floating):
            np.testing.assert_allclose(g, w, rtol=1e-6, atol=1e-7)
        else:
            np.testing.assert_array_equal(g, w)


def learner_batch(name):
    rng = np.random.default_rng(100 + BUILTIN_LEARNERS.index(name))
    instances = [make_learner(name, alpha=float(rng.uniform(0.1, 1)), gamma=float(rng.uniform(0, 1)))
                 for _ in range(BATCH)]
    f = lambda *shape: rng.normal(size=(BATCH,) + shape).astype(np.float32)  # noqa: E731
    probs = rng.uniform(size=(BATCH, 5)).astype(np.float32)
    tables = {key: f() for key in instances[0].tables()}
    tables_next = {key: f(5) for key in instances[0].tables()}
    discount = np.where(rng.uniform(size=BATCH) < 0.3, 0.0, 0.9).astype(np.float32)
    transitions = Transition(
        q=f(), tables=tables, reward=f(), terminal=discount == 0, discount=discount,
        q_next=f(5), tables_next=tables_next, next_action=rng.integers(0, 5, BATCH).astype(np.int32),
        next_probabilities=probs / probs.sum(1, keepdims=True),
        uniforms=tuple(rng.uniform(size=BATCH).astype(np.float32)
                       for _ in range(instances[0].num_uniforms)))
    stacked = jax.tree.map(lambda *leaves: np.stack(leaves), *instances)
    return instances, stacked, transitions


class MethodVariantsTest(parameterized.TestCase):
    """Built-ins' methods and the new pure functions: the same results with and without
    jit (one agent), and vmapped over a batch of agents with different hyperparameters."""

    @chex.variants(with_jit=True, without_jit=True)
    @parameterized.named_parameters(*[(name, name) for name in BUILTIN_EXPLORERS])
    def test_explorer_methods(self, name):
        instances, stacked, q, tables, contexts, uniforms, actions = explorer_batch(name)
        delta_q = np.linspace(-1, 1, BATCH).astype(np.float32)

        def select(e, q, t, c, u):
            return e.select(q, t, c, u)

        def probabilities(e, q, t, c):
            return e.probabilities(q, t, c)

        def update(e, t, a, d, c):
            return e.update(t, a, d, c)

        reference = [
            (int(e.select(row(q, i), row(tables, i), row(contexts, i), row(uniforms, i))),
             np.asarray(e.probabilities(row(q, i), row(tables, i), row(contexts, i))),
             jax.tree.map(np.asarray, e.update(row(tables, i), jnp.int32(actions[i]),
                                               jnp.float32(delta_q[i]), row(contexts, i))))
            for i, e in enumerate(instances)]
        # A guard against a vacuous comparison: the batch does not pick one action only.
        assert len({r[0] for r in reference}) > 1
        variants = self.variant(select), self.variant(probabilities), self.variant(update)
        for i in range(4):
            e, args = row(stacked, i), (row(q, i), row(tables, i), row(contexts, i))
            assert int(variants[0](e, *args, row(uniforms, i))) == reference[i][0]
            assert_trees_equal(variants[1](e, *args), reference[i][1])
            assert_trees_equal(variants[2](e, args[1], jnp.int32(actions[i]), jnp.float32(delta_q[i]),
                                           args[2]), reference[i][2])
        batched = (jax.vmap(select)(stacked, q, tables, contexts, uniforms),
                   jax.vmap(probabilities)(stacked, q, tables, contexts),
                   jax.vmap(update)(stacked, tables, actions, delta_q, contexts))
        np.testing.assert_array_equal(batched[0], [r[0] for r in reference])
        assert_trees_equal(batched[1], np.stack([r[1] for r in reference]))
        assert_trees_equal(batched[2], jax.tree.map(lambda *x: np.stack(x), *[r[2] for r in reference]))
        np.testing.assert_allclose(np.asarray(batched[1]).sum(1), 1.0, rtol=1e-5)

    @chex.variants(with_jit=True, without_jit=True)
    @parameterized.named_parameters(*[(name, name) for name in BUILTIN_LEARNERS])
    def test_learner_update(self, name):
        instances, stacked, transitions = learner_batch(name)

        def update(l, t):
            return l.update(t)

        def behaviour(l, q, t):
            return l.behaviour(q, t)

        reference = [jax.tree.map(np.asarray, l.update(row(transitions, i)))
                     for i, l in enumerate(instances)]
        variant = self.variant(update)
        for i in range(4):
            assert_trees_equal(variant(row(stacked, i), row(transitions, i)), reference[i])
        batched = jax.vmap(update)(stacked, transitions)
        assert_trees_equal(batched, jax.tree.map(lambda *x: np.stack(x), *reference))
        got = jax.vmap(behaviour)(stacked, transitions.q_next, transitions.tables_next)
        want = np.stack([np.asarray(l.behaviour(row(transitions.q_next, i),
                                                row(transitions.tables_next, i)))
                         for i, l in enumerate(instances)])
        assert_trees_equal(got, want)

    @chex.variants(with_jit=True, without_jit=True)
    def test_pure_functions(self):
        rng = np.random.default_rng(0)
        qs = rng.normal(size=(BATCH, 5)).astype(np.float32)
        qs[:4, 1] = qs[:4, 3] = qs[:4].max(1) + 1.0  # ties
        q2s = rng.normal(size=(BATCH, 5)).astype(np.float32)
        probs = rng.uniform(size=(BATCH, 5)).astype(np.float32)
        probs /= probs.sum(1, keepdims=True)
        scalars = rng.uniform(0.05, 1, (BATCH,)).astype(np.float32)
        episodes = rng.integers(0, 100, BATCH).astype(np.int32)
        cases = [
            (lambda p, k: decayed(p, jnp.float32(0.95), jnp.float32(0.05), k), (scalars, episodes)),
            (lambda q: greedy_probabilities(q), (qs,)),
            (lambda q: greedy_probabilities(q, "first"), (qs,)),
            (lambda q, p: mixture_probabilities(q, p, None), (qs, scalars)),
            (lambda q, p: mixture_probabilities(q, p, jnp.float32(0.3), "first"), (qs, scalars)),
            (lambda q, t: softmax_probabilities(q, t), (qs, scalars)),
            (lambda r, q, p: expected_sarsa_target(r, jnp.float32(0.9), q, p), (scalars, qs, probs)),
            (lambda r, q, q2: double_q_learning_target(r, jnp.float32(0.9), q, q2), (scalars, qs, q2s)),
            (lambda q, c: UCB1(c=jnp.float32(1.5)).scores(q, c),
             (qs, rng.integers(0, 4, (BATCH, 5)).astype(np.float32))),
            (lambda q, u: greedy(q, u), (qs, scalars)),
        ]
        for fn, args in cases:
            reference = [jax.tree.map(np.asarray, fn(*(jnp.asarray(a[i]) for a in args)))
                         for i in range(BATCH)]
            variant = self.variant(fn)
            for i in range(4):
                assert_trees_equal(variant(*(jnp.asarray(a[i]) for a in args)), reference[i])
            assert_trees_equal(jax.vmap(fn)(*args), np.stack(reference))


# --------------------------------------------------------------------------- engine
def run_alone(setting, episodes, mdp=None, seed=0):
    """The agent of ``setting`` and seed index 0, run on its own: beside the agent of seed
    index 1 (which changes none of its bits), in the layout of the one-kind grids of
    :func:`test_all_builtin_kinds_in_one_grid_equal_each_alone` (2 agents, chunks of 5
    episodes), whose programs it shares; the result of the first agent."""
    mdp = make_mdp(max_steps=40) if mdp is None else mdp
    both = run_agents(mdp, broadcast_agents(stack_agents([make_agent(setting)]), 2),
                      agent_keys(seed, 2), episodes, EngineOptions(chunk_episodes=5))
    return dataclasses.replace(both, returns=both.returns[:1], lengths=both.lengths[:1],
                               nonfinite=both.nonfinite[:1],
                               final_state=jax.tree.map(lambda leaf: leaf[:1], both.final_state))


def test_expected_sarsa_with_greedy_first_equals_q_learning():
    # π(·|s') is one-hot on the first argmax, so Σ π Q(s', ·) = max Q(s', ·) bit for bit.
    mdp = make_mdp(max_steps=40)
    settings = [Setting("qlearning", "egreedy", 0.0, {"tie_break": "first"}),
                Setting("expected_sarsa", "egreedy", 0.0, {"tie_break": "first"})]
    grid = run_grid(mdp, settings, num_seeds=3, num_episodes=30)
    assert grid.returns[0].tobytes() == grid.returns[1].tobytes()
    assert grid.lengths[0].tobytes() == grid.lengths[1].tobytes()
    q = run_alone(settings[0], 30, mdp).final_state.q
    expected = run_alone(settings[1], 30, mdp).final_state.q
    assert np.count_nonzero(q) > 10  # it learned something
    assert q.tobytes() == expected.tobytes()
    # Not a vacuous comparison: with exploration the two learners differ.
    explore = [Setting(s.learner, "egreedy", 0.3, {"tie_break": "first"}) for s in settings]
    assert not np.array_equal(run_alone(explore[0], 30, mdp).final_state.q,
                              run_alone(explore[1], 30, mdp).final_state.q)


@pytest.mark.parametrize("learner_name", ["qlearning", "sarsa", "expected_sarsa", "double_qlearning"])
def test_ucb1_counts_every_learning_step_once(learner_name):
    result = run_alone(Setting(learner_name, "ucb1", 0.5), 25)
    counts = result.final_state.tables["counts"]
    assert counts.shape == (1, 108, 7)
    np.testing.assert_array_equal(counts, np.round(counts))
    assert counts.min() >= 0
    assert int(counts.sum()) == int(result.lengths.sum())
    assert not result.nonfinite.any()


def test_double_q_learning_keeps_its_second_table():
    result = run_alone(Setting("double_qlearning", "egreedy", 0.2), 30)
    q2, q = result.final_state.tables["q2"], result.final_state.q
    assert set(result.final_state.tables) == {"q2"}
    assert q2.shape == q.shape == (1, 108, 7)
    assert np.count_nonzero(q2) > 5  # moved away from q_init = 0
    assert np.count_nonzero(q) > 5
    assert not np.array_equal(q2, q)
    assert np.isfinite(q2).all() and not result.nonfinite.any()


def test_all_builtin_kinds_in_one_grid_equal_each_alone():
    mdp = make_mdp(max_steps=30)
    settings = [Setting(l, e) for l in BUILTIN_LEARNERS for e in BUILTIN_EXPLORERS]
    assert len(settings) == 36
    grid = run_grid(mdp, settings, num_seeds=2, num_episodes=5, seed=1)
    assert grid.returns.shape == (36, 2, 5)
    assert np.isfinite(grid.returns).all() and not grid.nonfinite.any()
    for c, setting in enumerate(settings):
        alone = run_grid(mdp, [setting], num_seeds=2, num_episodes=5, seed=1)
        assert alone.returns[0].tobytes() == grid.returns[c].tobytes(), setting
        assert alone.lengths[0].tobytes() == grid.lengths[c].tobytes(), setting


# --------------------------------------------------------------------------- bad plug-ins
def _greedy_select(self, q, tables, context, uniforms):
    return greedy(q, uniforms[0])


@explorer("tbm_float_select")
class FloatSelect(Explorer):
    def select(self, q, tables, context, uniforms):
        return jnp.max(q)  # a value, not an action


@explorer("tbm_wrong_update_shape")
class WrongUpdateShape(Explorer):
    def tables(self):
        return {"tbm_visits": Table("pair", 0.0)}

    select = _greedy_select

    def update(self, tables, action, delta_q, context):
        return {"tbm_visits": jnp.sum(tables["tbm_visits"])}  # a scalar for a [A] row


@explorer("tbm_not_a_table")
class NotATable(Explorer):
    def tables(self):
        return {"tbm_bonus": 0.0}

    select = _greedy_select


@explorer("tbm_prints")
class Prints(Explorer):
    def select(self, q, tables, context, uniforms):
        jax.debug.print("q = {}", q)
        return greedy(q, uniforms[0])


def assert_one_line_error(name, fn):
    with pytest.raises(ValueError) as info:
        fn()
    message = str(info.value)
    assert "\n" not in message.strip(), message
    assert f"explorer {name!r}" in message, message
    return message


@pytest.mark.parametrize("name, words", [
    ("tbm_float_select", "select()"),
    ("tbm_wrong_update_shape", "update()"),
    ("tbm_not_a_table", "tbm_bonus"),
    ("tbm_prints", "side effects"),
])
def test_bad_explorers_fail_before_training_in_run_grid(name, words):
    message = assert_one_line_error(
        name, lambda: run_grid(make_mdp(), [Setting("qlearning", name)], num_seeds=1, num_episodes=1))
    assert words in message


@pytest.mark.parametrize("name, words", [
    ("tbm_float_select", "select()"), ("tbm_wrong_update_shape", "update()"),
    ("tbm_not_a_table", "tbm_bonus"), ("tbm_prints", "side effects"),
])
def test_bad_explorers_fail_before_training_in_run_agents(name, words):
    params = stack_agents([make_agent(Setting("qlearning", name))])
    message = assert_one_line_error(name, lambda: run_agents(make_mdp(), params, agent_keys(0, 1), 1))
    assert words in message


def test_plugin_without_select_or_gamma_fails_at_decoration():
    with pytest.raises(ValueError, match="tbm_no_select.*must define select") as info:
        @explorer("tbm_no_select")
        class NoSelect(Explorer):
            epsilon: float = 0.1
    assert "\n" not in str(info.value)
    assert "tbm_no_select" not in EXPLORERS

    with pytest.raises(ValueError, match="tbm_no_gamma.*gamma") as info:
        @learner("tbm_no_gamma")
        class NoGamma(Learner):
            alpha: float = 0.5

            def update(self, t):
                new, delta_q = td_update(t.q, t.reward, self.alpha)
                return LearnerUpdate(new, {}, delta_q)
    assert "\n" not in str(info.value)
    assert "tbm_no_gamma" not in LEARNERS


@pytest.mark.parametrize("build", [
    lambda: make_explorer("softmax", 1e-39),
    lambda: make_explorer("egreedy", 1e-50),
    lambda: make_explorer("max_boltzmann", 0.1, tau=1e-40),
    lambda: make_learner("qlearning", q_init=1e39),
    lambda: make_learner("expected_sarsa", q_init=-1e39),
])
def test_values_float32_cannot_hold_are_refused(build):
    with pytest.raises(ValueError, match="float32") as info:
        build()
    assert "\n" not in str(info.value)
