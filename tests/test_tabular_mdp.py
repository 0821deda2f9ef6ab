"""Any finite MDP from arrays: validation messages, and stochastic MDPs through run_grid."""
import jax
import numpy as np
import pytest

import vdbejax
from vdbejax.envs import TabularMDP, make_tabular_mdp, solvers
from vdbejax.methods.agents import Setting


def chain(**overrides):
    """A valid 3-state, 2-action deterministic MDP's arguments, with overrides."""
    args = dict(
        next_state=[[1, 0], [2, 0], [2, 2]],
        reward=[[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]],
        terminal=[[False, False], [True, False], [True, True]],
        start_probability=[1.0, 0.0, 0.0],
    )
    args.update(overrides)
    return args


BAD_INPUTS = [
    # (overrides, parameter named first, text in the message)
    (dict(next_state=[1, 2, 0]), "next_state has shape (3,)", "must be [S, A] or [S, A, K]"),
    (dict(next_state=[[1.0, 0.0], [2, 0], [2, 2]]), "next_state has dtype float64",
     "must hold integers"),
    (dict(next_state=[[1, 0], [3, 0], [2, 2]]), "next_state[1, 0, 0] = 3",
     "must be a state index in [0, 2]"),
    (dict(next_state=[[1, 0], [2], [2, 2]]), "next_state cannot be read as an array",
     "must be a rectangular array"),
    (dict(next_state=np.zeros((0, 2), int)), "next_state has shape (0, 2, 1)",
     "every dimension must be >= 1"),
    (dict(reward=[[0.0, 0.0], [1.0, 0.0]]), "reward has shape (2, 2)", "must be [3, 2, 1] or [3, 2]"),
    (dict(reward=[[0.0, np.nan], [1.0, 0.0], [0.0, 0.0]]), "reward[0, 1, 0] = nan",
     "must be finite"),
    (dict(reward=[["a", "b"], ["c", "d"], ["e", "f"]]), "reward has dtype <U1", "must hold numbers"),
    (dict(terminal=[[0, 0], [2, 0], [1, 1]]), "terminal[1, 0, 0] = 2:", "must be a bool or 0/1"),
    (dict(terminal=[True, False]), "terminal has shape (2,)", "must be [3, 2, 1] or [3, 2]"),
    (dict(start_probability=[0.5, 0.5]), "start_probability has shape (2,)", "must be [3]"),
    (dict(start_probability=[0.5, 0.4, 0.0]), "start_probability sums to 0.9", "must sum to 1"),
    (dict(start_probability=[1.5, -0.5, 0.0]), "start_probability[1] = -0.5",
     "must be finite and >= 0"),
    (dict(max_steps=0), "max_steps=0 is invalid", "must be an integer >= 1"),
    (dict(max_steps=2.5), "max_steps=2.5 is invalid", "must be an integer >= 1"),
    (dict(name=""), "name='' is invalid", "must be a non-empty string"),
    (dict(atol=-1.0), "atol=-1.0 is invalid", "must be a number > 0"),
    (dict(state_codes=[0, 5]), "state_codes has shape (2,)", "must be [3] integers"),
    (dict(state_codes=[0, 5, 5]), "state_codes is not strictly increasing",
     "must list distinct non-negative codes"),
]

STOCHASTIC = dict(
    next_state=[[[0, 1]], [[1, 1]]],
    reward=[[[1.0, 0.0]], [[0.0, 0.0]]],
    terminal=[[[True, True]], [[True, True]]],
    start_probability=[1.0, 0.0],
)

BAD_PROBABILITIES = [
    (dict(STOCHASTIC), "probability is None but next_state has K=2 outcomes",
     "pass probability of shape [2, 1, 2]"),
    (dict(STOCHASTIC, probability=[[[0.5, 0.4]], [[0.5, 0.5]]]), "probability[0, 0] sums to 0.9",
     "must sum to 1"),
    (dict(STOCHASTIC, probability=[[[1.5, -0.5]], [[0.5, 0.5]]]), "probability[0, 0, 1] = -0.5",
     "must be finite and >= 0"),
    (dict(STOCHASTIC, probability=[[0.5, 0.5], [0.5, 0.5]]), "probability has shape (2, 2)",
     "must be [2, 1, 2]"),
]


CASES = [(chain(**o), n, a) for o, n, a in BAD_INPUTS] + BAD_PROBABILITIES


@pytest.mark.parametrize("args,named,allowed", CASES, ids=[c[1] for c in CASES])
def test_every_bad_input_raises_one_line_naming_parameter_value_and_rule(args, named, allowed):
    with pytest.raises(ValueError) as err:
        make_tabular_mdp(**args)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(named), message
    assert allowed in message, message


def test_valid_inputs_and_conventions():
    mdp = make_tabular_mdp(**chain(), max_steps=5, name="chain")
    assert (mdp.num_states, mdp.num_actions, mdp.num_outcomes) == (3, 2, 1)
    assert mdp.state_codes is None and mdp.name == "chain" and int(mdp.max_steps) == 5
    # Terminal *states* [S]: an outcome is terminal when its next state is.
    by_state = make_tabular_mdp(**chain(terminal=[False, False, True]))
    np.testing.assert_array_equal(by_state.terminal[:, :, 0],
                                  [[False, False], [True, False], [True, True]])
    # Without state codes, index = code; a None field adds no pytree leaf.
    np.testing.assert_array_equal(mdp.index_of([2, 0]), [2, 0])
    assert len(jax.tree.leaves(mdp)) == 6
    coded = make_tabular_mdp(**chain(), state_codes=[3, 10, 11])
    np.testing.assert_array_equal(coded.index_of([11, 3]), [2, 0])
    np.testing.assert_array_equal(coded.code_of([1]), [10])
    assert isinstance(coded, TabularMDP)
    assert solvers.best_return(mdp) == pytest.approx(1.0)


def test_stochastic_mdp_through_run_grid():
    # One action; the episode ends at once with return 1 (p = 0.3) or 0 (p = 0.7).
    mdp = make_tabular_mdp(**STOCHASTIC, probability=[[[0.3, 0.7]], [[0.5, 0.5]]], name="coin")
    assert solvers.best_return(mdp) == pytest.approx(0.3)
    grid = vdbejax.run_grid(mdp, [Setting("qlearning", "egreedy", 0.1),
                                  Setting("sarsa", "softmax", 1.0)],
                            num_seeds=4, num_episodes=500, chunk_episodes=250)
    assert grid.returns.shape == (2, 4, 500)
    assert set(np.unique(grid.returns)) <= {0.0, 1.0}
    assert np.all(grid.lengths == 1)
    # 4000 Bernoulli(0.3) draws: standard error 0.007.
    assert grid.returns.mean() == pytest.approx(0.3, abs=0.03)
    assert grid.meta["mdp"] == "coin"
