"""The paper's table-cleaning task (the generated variant n=2, k=1) against the spec: every
transition, encoding, optimal solution.

``spec_oracle`` is the reference: the spec (``docs/task.md``) written out in plain Python,
independently of the package, and every one of the 108 codes × 7 actions of ``make_mdp()``
is checked against it.
"""
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax.envs import solvers
from vdbejax.envs.table_cleaning import (
    ACTION_NAMES,
    TableCleaning,
    TableCleaningVariant,
    decode,
    encode,
    make_mdp,
    make_params,
)

GET, DROP, GO_LEFT, GO_RIGHT, GO_HOME, CLEAN, ABORT = range(7)


def spec_oracle(state, action, invalid_action):
    """The spec's table, written out independently of the package (plain Python)."""
    hand_obj, hand_pos, goblet_pos, left, right = state
    new = list(state)
    fail = False
    if action == GET:
        if hand_obj == 0 and hand_pos == 2:
            new[0] = 1
        elif hand_obj == 0 and hand_pos in (0, 1) and goblet_pos == hand_pos:
            new[0], new[2] = 2, 2
    elif action == DROP:
        if hand_obj == 1 and hand_pos == 2:
            new[0] = 0
        elif hand_obj == 2 and hand_pos in (0, 1):
            new[0], new[2] = 0, hand_pos
    elif action in (GO_LEFT, GO_RIGHT, GO_HOME):
        new[1] = {GO_LEFT: 0, GO_RIGHT: 1, GO_HOME: 2}[action]
    elif action == CLEAN:
        if hand_obj == 2 or (hand_pos in (0, 1) and hand_pos == goblet_pos):
            fail = True
        elif hand_obj == 1 and hand_pos in (0, 1):
            new[3 + hand_pos] = 1
    else:
        fail = True
    new = tuple(new)
    if invalid_action == "fail" and new == tuple(state) and action not in (GO_LEFT, GO_RIGHT, GO_HOME):
        fail = True
    if fail:
        return new, -1.0, True
    if new[0] == 0 and new[1] == 2 and new[3] == 1 and new[4] == 1:
        return new, 1.0, True
    return new, -0.01, False


ALL_STATES = list(itertools.product(range(3), range(3), range(3), range(2), range(2)))


def test_encoding_is_mixed_radix_and_bijective():
    codes = [int(encode(jnp.array(s))) for s in ALL_STATES]
    assert codes == list(range(108))  # hand_obj most significant, right_clean least
    for s in ALL_STATES:
        assert tuple(np.asarray(decode(encode(jnp.array(s))))) == s


@pytest.mark.parametrize("invalid_action", ["noop", "fail"])
def test_every_transition_matches_the_spec(invalid_action):
    mdp = make_mdp(invalid_action=invalid_action)
    assert mdp.name == "table_cleaning" and mdp.num_states == 108 and mdp.num_actions == 7
    assert np.all(np.asarray(mdp.probability) == 1.0)  # deterministic
    next_state = np.asarray(mdp.next_state[:, :, 0])
    reward = np.asarray(mdp.reward[:, :, 0])
    terminal = np.asarray(mdp.terminal[:, :, 0])
    assert (next_state.dtype, reward.dtype, terminal.dtype) == (np.int32, np.float32, np.bool_)
    for code, state in enumerate(ALL_STATES):
        for action in range(7):
            expected_next, expected_reward, expected_terminal = spec_oracle(state, action, invalid_action)
            got = tuple(np.asarray(decode(next_state[code, action])))
            context = (state, ACTION_NAMES[action])
            assert got == expected_next, context
            assert reward[code, action] == np.float32(expected_reward), context  # exact
            assert bool(terminal[code, action]) == expected_terminal, context


def test_the_papers_task_is_the_2x1_variant():
    env = TableCleaning()
    assert isinstance(env, TableCleaningVariant)
    assert (env.num_sections, env.num_goblets, env.num_actions, env.num_codes()) == (2, 1, 7, 108)
    assert TableCleaning.transition is TableCleaningVariant.transition  # one rule, not a copy
    assert env.action_names == ACTION_NAMES == TableCleaning.action_names
    assert env.field_names == ("hand_obj", "hand_pos", "goblet_pos", "left_clean", "right_clean")
    assert (env.clean_action, env.abort_action) == (CLEAN, ABORT)


@pytest.mark.parametrize(
    "state, action, expected",
    [
        # get: sponge at home; goblet where it stands; otherwise nothing.
        ((0, 2, 0, 0, 0), GET, ((1, 2, 0, 0, 0), -0.01, False)),
        ((0, 1, 1, 0, 0), GET, ((2, 1, 2, 0, 0), -0.01, False)),
        ((0, 0, 1, 0, 0), GET, ((0, 0, 1, 0, 0), -0.01, False)),
        # drop: sponge at home; goblet at a side; never the sponge on the table.
        ((1, 2, 0, 1, 0), DROP, ((0, 2, 0, 1, 0), -0.01, False)),
        ((2, 0, 2, 0, 1), DROP, ((0, 0, 0, 0, 1), -0.01, False)),
        ((1, 0, 1, 0, 0), DROP, ((1, 0, 1, 0, 0), -0.01, False)),
        ((2, 2, 2, 0, 0), DROP, ((2, 2, 2, 0, 0), -0.01, False)),
        # moves carry what the hand holds.
        ((2, 0, 2, 0, 0), GO_RIGHT, ((2, 1, 2, 0, 0), -0.01, False)),
        # clean: the free side; failures while holding the goblet or at the goblet's side.
        ((1, 1, 0, 0, 0), CLEAN, ((1, 1, 0, 0, 1), -0.01, False)),
        ((1, 0, 0, 0, 0), CLEAN, ((1, 0, 0, 0, 0), -1.0, True)),
        ((2, 1, 2, 0, 0), CLEAN, ((2, 1, 2, 0, 0), -1.0, True)),
        ((0, 0, 0, 0, 0), CLEAN, ((0, 0, 0, 0, 0), -1.0, True)),
        ((0, 1, 0, 0, 0), CLEAN, ((0, 1, 0, 0, 0), -0.01, False)),
        # abort always fails; the goal needs a free hand at home and both sides clean.
        ((0, 2, 0, 0, 0), ABORT, ((0, 2, 0, 0, 0), -1.0, True)),
        ((1, 2, 1, 1, 1), DROP, ((0, 2, 1, 1, 1), 1.0, True)),
        ((0, 0, 0, 1, 1), GO_HOME, ((0, 2, 0, 1, 1), 1.0, True)),
    ],
)
def test_named_transitions(state, action, expected):
    env, params = TableCleaning(), make_params()
    next_fields, reward, terminal = env.transition(jnp.array(state), action, params)
    expected_next, expected_reward, expected_terminal = expected
    assert tuple(np.asarray(next_fields)) == expected_next
    assert float(reward) == pytest.approx(expected_reward)
    assert bool(terminal) == expected_terminal


def test_fail_option_fails_on_no_change_but_not_on_moves_in_place():
    env, params = TableCleaning(), make_params(invalid_action="fail")
    _, r, t = env.transition(jnp.array((0, 0, 1, 0, 0)), GET, params)  # nothing to get
    assert (float(r), bool(t)) == (-1.0, True)
    _, r, t = env.transition(jnp.array((0, 0, 1, 0, 0)), GO_LEFT, params)  # already left
    assert (float(r), bool(t)) == (pytest.approx(-0.01), False)


def test_reset_and_step_gymnax_api_and_truncation():
    env = TableCleaning()
    params = make_params(max_steps=3)
    starts = set()
    for i in range(40):
        obs, state = env.reset(jax.random.PRNGKey(i), params)
        starts.add(tuple(np.asarray(obs)))
    assert starts == {(0, 2, 0, 0, 0), (0, 2, 1, 0, 0)}
    _, state = env.reset(jax.random.PRNGKey(0), params)
    for t in range(3):
        _, state, reward, done, info = env.step(jax.random.PRNGKey(t), state, GO_HOME, params)
    assert bool(done) and bool(info["truncated"]) and not bool(info["terminal"])
    step = jax.jit(env.step, static_argnums=())
    obs, state2, *_ = step(jax.random.PRNGKey(0), state, jnp.int32(GET), params)
    assert tuple(np.asarray(obs)) == (1, 2, int(state.fields[2]), 0, 0)


def test_start_distribution_and_reachable_states():
    mdp = make_mdp()
    start = np.asarray(mdp.start_probability)
    assert start.sum() == pytest.approx(1.0)
    starts = solvers.start_states(mdp)
    assert {tuple(np.asarray(decode(s))) for s in starts} == {(0, 2, 0, 0, 0), (0, 2, 1, 0, 0)}
    np.testing.assert_allclose(start[starts], [0.5, 0.5])
    assert len(solvers.reachable_states(mdp)) == 51


@pytest.mark.parametrize("invalid_action", ["noop", "fail"])
def test_shortest_solution_is_15_actions_and_best_return_086(invalid_action):
    mdp = make_mdp(invalid_action=invalid_action)
    values = solvers.optimal_values(mdp, gamma=1.0)
    for start in solvers.start_states(mdp):
        path = solvers.shortest_solution(mdp, int(start))
        assert len(path) == 15
        # Replay: 14 steps of −0.01 then the goal.
        s, total = int(start), 0.0
        for a in path:
            total += float(mdp.reward[s, a, 0])
            s = int(mdp.next_state[s, a, 0])
        assert total == pytest.approx(0.86)
        assert values[start] == pytest.approx(0.86)
    assert solvers.best_return(mdp) == pytest.approx(0.86)
