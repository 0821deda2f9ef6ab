"""Q-learning and SARSA updates against hand-computed numbers, under jit and vmap."""
import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from absl.testing import parameterized

from vdbejax.methods import learners

Q_NEXT = jnp.array([0.2, 0.7, -0.1])


def test_q_learning_hand_computed():
    # target = −0.01 + 0.9·max(0.2, 0.7, −0.1) = 0.62; ΔQ = 0.8·(0.62 − 0.5) = 0.096
    target = learners.q_learning_target(-0.01, 0.9, Q_NEXT)
    assert float(target) == pytest.approx(0.62)
    new, dq = learners.td_update(0.5, target, 0.8)
    assert (float(new), float(dq)) == (pytest.approx(0.596), pytest.approx(0.096))


def test_sarsa_hand_computed():
    # a' = 2: target = −0.01 + 0.9·(−0.1) = −0.1; ΔQ = 0.8·(−0.1 − 0.5) = −0.48
    target = learners.sarsa_target(-0.01, 0.9, Q_NEXT, 2)
    assert float(target) == pytest.approx(-0.1)
    new, dq = learners.td_update(0.5, target, 0.8)
    assert (float(new), float(dq)) == (pytest.approx(0.02), pytest.approx(-0.48))


def test_terminal_transition_uses_reward_only():
    assert float(learners.q_learning_target(1.0, 0.0, Q_NEXT)) == 1.0
    assert float(learners.sarsa_target(-1.0, 0.0, Q_NEXT, 1)) == -1.0


def test_make_learner_validates():
    assert learners.make_learner("sarsa").uses_next_action
    assert not learners.make_learner("qlearning").uses_next_action
    for kwargs in [dict(alpha=0.0), dict(alpha=1.5), dict(gamma=-0.1), dict(gamma=1.1), dict(q_init=float("nan"))]:
        with pytest.raises(ValueError):
            learners.make_learner("qlearning", **kwargs)
    with pytest.raises(ValueError, match="learner='td'"):
        learners.make_learner("td")


class LearnerVariantsTest(parameterized.TestCase):
    @chex.variants(with_jit=True, without_jit=True)
    def test_targets_and_update(self):
        q_target = self.variant(learners.q_learning_target)
        s_target = self.variant(learners.sarsa_target)
        update = self.variant(learners.td_update)
        np.testing.assert_allclose(q_target(jnp.float32(-0.01), jnp.float32(0.9), Q_NEXT), 0.62, rtol=1e-6)
        np.testing.assert_allclose(s_target(jnp.float32(-0.01), jnp.float32(0.9), Q_NEXT, jnp.int32(2)), -0.1, rtol=1e-6)
        new, dq = update(jnp.float32(0.5), jnp.float32(0.62), jnp.float32(0.8))
        np.testing.assert_allclose([new, dq], [0.596, 0.096], rtol=1e-6)

    def test_vmap(self):
        rewards = jnp.array([-0.01, 1.0])
        discounts = jnp.array([0.9, 0.0])
        q_next = jnp.stack([Q_NEXT, Q_NEXT])
        np.testing.assert_allclose(jax.vmap(learners.q_learning_target)(rewards, discounts, q_next), [0.62, 1.0], rtol=1e-6)
        np.testing.assert_allclose(
            jax.vmap(learners.sarsa_target)(rewards, discounts, q_next, jnp.array([2, 0])), [-0.1, 1.0], rtol=1e-6
        )
