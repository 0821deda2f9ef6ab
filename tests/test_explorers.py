"""Explorers: action frequencies against their formulas, under jit and vmap (chex.variants)."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from absl.testing import parameterized

from vdbejax._numerics import sample_categorical
from vdbejax.methods import explorers, selection

NUM_DRAWS = 20_000
Q = jnp.array([0.1, 0.5, -0.2, 0.3, 0.0, -1.0, 0.45])  # unique maximum: action 1


def frequencies(fn, key=0):
    """Empirical action distribution of ``fn(key)`` over NUM_DRAWS fixed keys."""
    keys = jax.random.split(jax.random.PRNGKey(key), NUM_DRAWS)
    actions = np.asarray(jax.jit(jax.vmap(fn))(keys))
    return np.bincount(actions, minlength=7) / NUM_DRAWS


def assert_matches(freq, probs):
    probs = np.asarray(probs, np.float64)
    # 5 binomial standard deviations (plus a floor for p ≈ 0): fixed keys, so no flakes.
    tolerance = 5 * np.sqrt(probs * (1 - probs) / NUM_DRAWS) + 1e-4
    np.testing.assert_array_less(np.abs(freq - probs), tolerance)


def greedy_onehot(q):
    return np.eye(7)[int(np.argmax(q))]


@pytest.mark.parametrize("epsilon", [0.0, 0.1, 0.3, 1.0])
def test_egreedy_frequencies(epsilon):
    freq = frequencies(lambda k: selection.egreedy(k, Q, epsilon))
    assert_matches(freq, (1 - epsilon) * greedy_onehot(Q) + epsilon / 7)


@pytest.mark.parametrize("tau", [0.05, 0.3, 1.0, 10.0])
def test_softmax_frequencies(tau):
    freq = frequencies(lambda k: selection.softmax(k, Q, tau))
    logits = np.asarray(Q, np.float64) / tau
    probs = np.exp(logits - logits.max())
    assert_matches(freq, probs / probs.sum())
    np.testing.assert_allclose(selection.softmax_probabilities(Q, tau), probs / probs.sum(), rtol=1e-5)


@pytest.mark.parametrize("state_epsilon", [0.0, 0.25, 0.9])
def test_vdbe_frequencies(state_epsilon):
    freq = frequencies(lambda k: selection.vdbe(k, Q, state_epsilon))
    assert_matches(freq, (1 - state_epsilon) * greedy_onehot(Q) + state_epsilon / 7)


@pytest.mark.parametrize("state_epsilon, tau", [(0.5, 0.2), (0.3, 1.0)])
def test_vdbe_softmax_frequencies(state_epsilon, tau):
    freq = frequencies(lambda k: selection.vdbe_softmax(k, Q, state_epsilon, tau))
    soft = np.asarray(selection.softmax_probabilities(Q, tau), np.float64)
    assert_matches(freq, (1 - state_epsilon) * greedy_onehot(Q) + state_epsilon * soft)


def test_random_tie_break_is_uniform_among_maxima_and_first_picks_lowest():
    q = jnp.array([0.0, 0.7, 0.2, 0.7, 0.7, -1.0, 0.0])
    freq = frequencies(lambda k: selection.egreedy(k, q, 0.0))
    assert_matches(freq, [0, 1 / 3, 0, 1 / 3, 1 / 3, 0, 0])
    freq = frequencies(lambda k: selection.egreedy(k, q, 0.0, tie_break="first"))
    assert_matches(freq, [0, 1, 0, 0, 0, 0, 0])


@pytest.mark.parametrize("tau", [0.0001, 0.001])
def test_tiny_tau_is_stable(tau):
    q = jnp.array([0.86, 0.8599, -1.0, 0.5, 0.86, 0.1, -0.01])
    weights = selection.softmax_weights(q, tau)
    assert bool(jnp.all(jnp.isfinite(weights)))
    probs = selection.softmax_probabilities(q, tau)
    assert bool(jnp.all(jnp.isfinite(probs))) and float(probs.sum()) == pytest.approx(1.0)
    freq = frequencies(lambda k: selection.softmax(k, q, tau))
    assert_matches(freq, np.asarray(probs, np.float64))
    # Huge value gaps: still finite, all mass on the maximum.
    assert int(selection.softmax(jax.random.PRNGKey(0), jnp.array([1e4, -1e4, 0.0]), tau)) == 0


def test_sample_categorical_never_returns_zero_weight():
    weights = jnp.array([0.0, 1.0, 0.0, 2.0, 0.0])
    edge_uniforms = jnp.array([0.0, 1 / 3 - 1e-7, 1 / 3, 1.0 - 2.0**-23])
    picks = jax.vmap(lambda u: sample_categorical(weights, u))(edge_uniforms)
    assert set(np.asarray(picks).tolist()) <= {1, 3}
    assert int(picks[-1]) == 3


def _numpy_draw(weights: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Inverse-CDF reference: float32 prefix sums left to right, ``n − #(cdf > u·total)``."""
    cdf = np.cumsum(weights.astype(np.float32), axis=0, dtype=np.float32)
    threshold = (u.astype(np.float32) * cdf[-1]).astype(np.float32)
    return (weights.shape[0] - np.sum(cdf > threshold, axis=0)).astype(np.int32)


class SampleCategoricalTest(parameterized.TestCase):
    """The categorical draw is the inverse-CDF draw bit for bit (both of its paths), with
    and without jit, under vmap, with batched weights and with weights shared by a batch
    of uniforms; degenerate weights give the invalid index ``n``."""

    @chex.variants(with_jit=True, without_jit=True)
    @parameterized.parameters(1, 2, 3, 7, 32, 33, 40)
    def test_matches_the_inverse_cdf_reference(self, n):
        rng = np.random.default_rng(n)
        weights = rng.exponential(size=(n, 256)).astype(np.float32)
        weights[:, ::5] = (weights[:, ::5] > 1.0)  # zero weights, ties of the sums
        weights[:, 1::7] = np.ldexp(weights[:, 1::7], rng.integers(-100, 100, (n, 1)))
        weights[rng.integers(n), 2::9] = 0.0
        weights[:, 2::9] += (weights[:, 2::9].sum(axis=0) == 0)  # keep a positive total
        u = (rng.integers(0, 2**23, 256) * 2.0**-23).astype(np.float32)
        u[:3] = [0.0, 0.5, 1.0 - 2.0**-23]
        draw = self.variant(sample_categorical)
        expected = _numpy_draw(weights, u)
        np.testing.assert_array_equal(draw(jnp.asarray(weights), jnp.asarray(u)), expected)
        per_column = jax.vmap(sample_categorical, in_axes=(1, 0))
        np.testing.assert_array_equal(per_column(jnp.asarray(weights), jnp.asarray(u)),
                                      expected)
        shared = draw(jnp.asarray(weights[:, 0]), jnp.asarray(u))  # [n] weights, [256] u
        np.testing.assert_array_equal(shared, _numpy_draw(weights[:, :1], u[None]))
        assert draw(jnp.asarray(weights[:, 0]), jnp.float32(u[5])).shape == ()

    @chex.variants(with_jit=True, without_jit=True)
    def test_weights_that_are_no_distribution_give_n(self):
        draw = self.variant(sample_categorical)
        for n in (4, 40):  # both paths
            bad = np.ones((n, 3), np.float32)
            bad[1, 0], bad[:, 1], bad[2, 2] = np.nan, 0.0, np.inf
            np.testing.assert_array_equal(
                draw(jnp.asarray(bad), jnp.full(3, 0.5, jnp.float32)), [n, n, n])


def test_vdbe_epsilon_update_hand_computed():
    # f = (1 − e^{−0.96}) / (1 + e^{−0.96}) = 0.446245; ε' = 0.1·f + 0.9·1
    assert float(selection.vdbe_epsilon_update(1.0, 0.096, 0.1, 0.1)) == pytest.approx(0.9446244, abs=1e-6)
    # Sign of ΔQ does not matter; σ = 1, ε = 0.5: f = tanh(0.24)
    assert float(selection.vdbe_epsilon_update(0.5, -0.48, 1.0, 0.1)) == pytest.approx(0.4735496, abs=1e-6)
    # No change → f = 0 → ε decays by (1 − δ); tiny σ → f = 1 without NaN.
    assert float(selection.vdbe_epsilon_update(0.5, 0.0, 0.01, 0.1)) == pytest.approx(0.45)
    assert float(selection.vdbe_epsilon_update(0.0, 0.5, 1e-30, 0.1)) == pytest.approx(0.1)


def test_make_explorer_builds_the_registered_classes():
    e = explorers.make_explorer("egreedy", 0.1)
    assert isinstance(e, explorers.EpsilonGreedy) and float(e.epsilon) == pytest.approx(0.1)
    assert e.tables() == {}
    s = explorers.make_explorer("softmax", 0.01)
    assert isinstance(s, explorers.Softmax) and float(s.tau) == pytest.approx(0.01)
    v = explorers.make_explorer("vdbe", 10.0)
    assert float(v.sigma) == 10.0 and v.tables()["epsilon"].per == "state"
    vs = explorers.make_explorer("vdbe_softmax", 0.1)
    assert isinstance(vs, explorers.VDBE) and float(vs.tau) == pytest.approx(0.001)
    for name, bad in [("egreedy", 1.5), ("softmax", 0.0), ("vdbe", -1.0), ("nope", 1.0)]:
        with pytest.raises(ValueError):
            explorers.make_explorer(name, bad)
    with pytest.raises(ValueError, match="has no field 'sigma'"):
        explorers.make_explorer("egreedy", 0.1, sigma=1.0)


class ExplorerVariantsTest(parameterized.TestCase):
    """Every explorer function gives the same result with and without jit, and under vmap."""

    @chex.variants(with_jit=True, without_jit=True)
    @parameterized.named_parameters(
        ("egreedy", lambda k, q: selection.egreedy(k, q, 0.2)),
        ("softmax", lambda k, q: selection.softmax(k, q, 0.3)),
        ("vdbe", lambda k, q: selection.vdbe(k, q, 0.4)),
        ("vdbe_softmax", lambda k, q: selection.vdbe_softmax(k, q, 0.4, 0.2)),
        ("greedy", lambda k, q: selection.greedy(q, jax.random.uniform(k))),
    )
    def test_jit_and_vmap_agree(self, fn):
        keys = jax.random.split(jax.random.PRNGKey(3), 64)
        qs = jax.random.normal(jax.random.PRNGKey(4), (64, 7))
        reference = np.array([int(fn(k, q)) for k, q in zip(keys, qs)])
        variant = self.variant(fn)
        single = np.array([int(variant(k, q)) for k, q in zip(keys[:8], qs[:8])])
        np.testing.assert_array_equal(single, reference[:8])
        batched = np.asarray(jax.vmap(fn)(keys, qs))
        np.testing.assert_array_equal(batched, reference)

    @chex.variants(with_jit=True, without_jit=True)
    def test_vdbe_update_variants(self):
        update = self.variant(selection.vdbe_epsilon_update)
        got = update(jnp.float32(1.0), jnp.float32(0.096), jnp.float32(0.1), jnp.float32(0.1))
        np.testing.assert_allclose(got, 0.9446244, atol=1e-6)
        batched = jax.vmap(selection.vdbe_epsilon_update)(
            jnp.array([1.0, 0.5]), jnp.array([0.096, -0.48]), jnp.array([0.1, 1.0]), jnp.array([0.1, 0.1])
        )
        np.testing.assert_allclose(batched, [0.9446244, 0.4735496], atol=1e-6)


@pytest.mark.parametrize("tau", [None, 0.05, 1.0])
def test_select_action_draws_the_action_of_the_two_draws_it_chooses_between(tau):
    """select_action makes one draw (weights and uniform chosen first): the very action of
    the exploratory draw where it explores and of the greedy draw elsewhere, bit for bit,
    ties and all, jitted and vmapped."""
    from vdbejax.methods.selection import (
        greedy,
        sample_categorical,
        select_action,
        softmax_weights,
    )

    rng = np.random.default_rng(3)
    q = jnp.asarray(rng.integers(0, 3, size=(7, 4000)) * 0.5, jnp.float32)  # many ties
    u = jnp.asarray(rng.integers(0, 2**23, size=(3, 4000)) * 2.0**-23, jnp.float32)
    epsilon = jnp.asarray(rng.random(4000), jnp.float32)

    def two_draws(q, epsilon, u):
        weights = jnp.ones_like(q) if tau is None else softmax_weights(q, tau)
        return jnp.where(u[0] < epsilon, sample_categorical(weights, u[1]),
                         greedy(q, u[2]))

    one = jax.jit(jax.vmap(lambda q, e, u: select_action(q, e, tau, u), in_axes=(1, 0, 1)))
    reference = jax.vmap(two_draws, in_axes=(1, 0, 1))(q, epsilon, u)
    np.testing.assert_array_equal(one(q, epsilon, u), reference)
    assert len(set(np.asarray(reference).tolist())) == 7
