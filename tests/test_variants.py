"""Generated table-cleaning variants: the paper's task as n=2, k=1, rules, state counts, starts.

``oracle`` is the reference: the generalised rules (the generator's docstring) written out in
plain Python; ``tests/test_table_cleaning.py`` checks the paper's task against the spec."""
import itertools
from collections import Counter, deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax.envs import compile_env, solvers
from vdbejax.envs.table_cleaning import (
    TableCleaning,
    TableCleaningGenerator,
    TableCleaningVariant,
    make_mdp,
    make_params,
    make_variant,
    make_variant_mdp,
)
from vdbejax.envs.table_cleaning import core as table_core


def oracle(state, action, n, k, invalid_action="noop"):
    """The generalised rules written out in plain Python (independent of the package).

    ``state = (hand_obj, hand_pos, goblets (sorted tuple), cleans (tuple))``.
    """
    hand_obj, hand_pos, goblets, cleans = state
    home = n
    goblets, cleans = list(goblets), list(cleans)
    fail = False
    at_section = hand_pos < n
    if action == 0:  # get
        if hand_obj == 0 and not at_section:
            hand_obj = 1
        elif hand_obj == 0 and at_section and hand_pos in goblets:
            goblets[goblets.index(hand_pos)] = home
            hand_obj = 2
    elif action == 1:  # drop
        if hand_obj == 1 and not at_section:
            hand_obj = 0
        elif hand_obj == 2 and at_section:
            goblets[goblets.index(home)] = hand_pos
            hand_obj = 0
    elif 2 <= action <= n + 2:
        hand_pos = action - 2
    elif action == n + 3:  # clean
        if hand_obj == 2 or (at_section and hand_pos in goblets):
            fail = True
        elif hand_obj == 1 and at_section:
            cleans[hand_pos] = 1
    else:
        fail = True
    new = (hand_obj, hand_pos, tuple(sorted(goblets)), tuple(cleans))
    if invalid_action == "fail" and new == state and not 2 <= action <= n + 2:
        fail = True
    if fail:
        return new, -1.0, True
    if hand_obj == 0 and hand_pos == home and all(cleans):
        return new, 1.0, True
    return new, -0.01, False


def to_fields(state):
    hand_obj, hand_pos, goblets, cleans = state
    return np.array([hand_obj, hand_pos, *goblets, *cleans], np.int32)


def encode_all(env, fields):
    """Mixed-radix codes of field vectors ``[..., F]`` (numpy, independent of env.encode)."""
    fields = np.asarray(fields)
    return np.ravel_multi_index(tuple(np.moveaxis(fields, -1, 0)), env.generator.radices)


def oracle_closure(n, k, invalid_action="noop"):
    """Plain-Python BFS of the oracle from every initial placement: {state: [(next, r, t)]}."""
    starts = {(0, n, tuple(sorted(p)), (0,) * n) for p in itertools.product(range(n), repeat=k)}
    table, queue = {}, deque(starts)
    while queue:
        state = queue.popleft()
        if state in table:
            continue
        table[state] = [oracle(state, a, n, k, invalid_action) for a in range(n + 5)]
        queue.extend(nxt for nxt, _, _ in table[state] if nxt not in table)
    return table


@pytest.mark.parametrize("invalid_action,max_steps", [("noop", 100), ("fail", 7)])
def test_n2_k1_is_exactly_the_papers_task(invalid_action, max_steps):
    paper = make_mdp(max_steps, invalid_action)
    variant = make_variant_mdp(2, 1, max_steps=max_steps, invalid_action=invalid_action,
                               reachable_only=False)
    assert variant.state_codes is None
    for field in ("next_state", "probability", "reward", "terminal", "start_probability",
                  "max_steps"):
        np.testing.assert_array_equal(getattr(variant, field), getattr(paper, field), field)
    assert (paper.name, variant.name) == ("table_cleaning", "table_cleaning_n2_k1")
    # Same state encoding as the paper's environment; the moves have the variant's names.
    env, papers = make_variant(2, 1), TableCleaning()
    assert env.action_names == ("get", "drop", "go_0", "go_1", "go_home", "clean", "abort")
    assert env.num_codes() == papers.num_codes() == 108
    assert env.generator == papers.generator
    codes = jnp.arange(108)
    np.testing.assert_array_equal(jax.vmap(env.decode)(codes), jax.vmap(papers.decode)(codes))


def test_a_patched_reward_constant_is_seen_by_every_variant(monkeypatch):
    """The rewards are the core module's constants, read when a variant is traced."""
    monkeypatch.setattr(table_core, "GOAL_REWARD", 2.0)
    for mdp in (make_mdp(), make_variant_mdp(3, 2)):
        reward, terminal = np.asarray(mdp.reward), np.asarray(mdp.terminal)
        assert (reward == 2.0).any() and not (reward == 1.0).any()
        assert np.all(reward[~terminal] == np.float32(-0.01))


def test_reachable_compilation_is_the_dense_table_restricted():
    paper = make_mdp()
    small = make_variant_mdp(2, 1, reachable_only=True)
    codes = np.asarray(small.state_codes)
    assert small.num_states == 60 and np.all(np.diff(codes) > 0)
    np.testing.assert_array_equal(codes[np.asarray(small.next_state)],
                                  np.asarray(paper.next_state)[codes])
    np.testing.assert_array_equal(small.reward, np.asarray(paper.reward)[codes])
    np.testing.assert_array_equal(small.terminal, np.asarray(paper.terminal)[codes])
    np.testing.assert_array_equal(small.start_probability,
                                  np.asarray(paper.start_probability)[codes])
    assert len(solvers.reachable_states(small)) == len(solvers.reachable_states(paper)) == 51
    np.testing.assert_array_equal(small.index_of(small.code_of([0, 5, 59])), [0, 5, 59])
    with pytest.raises(ValueError, match="codes holds 8"):
        small.index_of(8)  # free hand, yet the goblet is "in the hand": unreachable


@pytest.mark.parametrize("invalid_action", ["noop", "fail"])
@pytest.mark.parametrize("n,k", [(2, 1), (3, 2)])
def test_the_plain_python_rules_hold_on_every_reachable_state(n, k, invalid_action):
    table = oracle_closure(n, k, invalid_action)
    mdp = make_variant_mdp(n, k, invalid_action=invalid_action)
    env = make_variant(n, k)
    assert mdp.num_states == len(table)
    codes = encode_all(env, [to_fields(s) for s in table])
    assert int(env.encode(to_fields(next(iter(table))))) == codes[0]
    index = mdp.index_of(codes)
    expected_next = encode_all(env, [[to_fields(o[0]) for o in row] for row in table.values()])
    np.testing.assert_array_equal(mdp.code_of(np.asarray(mdp.next_state)[index, :, 0]),
                                  expected_next)
    np.testing.assert_allclose(np.asarray(mdp.reward)[index, :, 0],
                               [[o[1] for o in row] for row in table.values()], atol=1e-7)
    np.testing.assert_array_equal(np.asarray(mdp.terminal)[index, :, 0],
                                  [[o[2] for o in row] for row in table.values()])


@pytest.mark.parametrize("n,k", [(2, 1), (2, 2), (3, 1), (4, 2)])
def test_state_counts_match_the_oracle_closure(n, k):
    mdp = make_variant_mdp(n, k)
    assert mdp.num_states == len(oracle_closure(n, k))
    assert make_variant(n, k).num_codes() == 3 * (n + 1) ** (k + 1) * 2**n
    assert mdp.num_actions == n + 5


def test_start_distribution_is_independent_uniform_placement():
    gen = TableCleaningGenerator(num_sections=3, num_goblets=2)
    codes, probs = gen.start_distribution()
    env = TableCleaningVariant(gen)
    decoded = [tuple(np.asarray(env.decode(c))[2:4]) for c in codes]
    # 3^2 placements: a shared section has 1 placement, two distinct sections have 2.
    expected = {(a, b): (1 if a == b else 2) / 9 for a in range(3) for b in range(a, 3)}
    assert dict(zip(decoded, probs)) == pytest.approx(expected)
    # The generator's samples follow it, and reset() uses the generator.
    keys = jax.random.split(jax.random.PRNGKey(0), 4000)
    obs, states = jax.vmap(lambda key: env.reset(key, make_params()))(keys)
    assert np.all(np.asarray(states.time) == 0)
    counts = Counter(encode_all(env, np.asarray(obs)).tolist())
    for code, p in zip(codes, probs):
        assert counts[int(code)] / 4000 == pytest.approx(p, abs=0.03)
    mdp = make_variant_mdp(3, 2)
    np.testing.assert_allclose(np.asarray(mdp.start_probability)[mdp.index_of(codes)], probs,
                               rtol=1e-6)


def _step(env, fields, action, invalid_action="noop"):
    next_fields, reward, terminal = env.transition(jnp.asarray(fields, jnp.int32), action,
                                                   make_params(invalid_action=invalid_action))
    return list(np.asarray(next_fields)), float(reward), bool(terminal)


def test_rules_on_six_sections_three_goblets():
    env = make_variant(6, 3)
    get, drop, clean, abort, home = 0, 1, env.clean_action, env.abort_action, 6
    go = lambda i: 2 + i  # noqa: E731
    dirty = [0] * 6
    # Sponge at section 4 (holding goblets 1, 1, 5): cleaning fails on 1, works on 4.
    state = [1, 1, 1, 1, 5, *dirty]
    assert _step(env, state, clean)[1:] == (-1.0, True)
    state[1] = 4
    nxt, r, t = _step(env, state, clean)
    assert nxt[5 + 4] == 1 and (r, t) == (pytest.approx(-0.01), False)
    # Holding a goblet: cleaning fails even on a section without goblets.
    assert _step(env, [2, 3, 1, 5, home, *dirty], clean)[1:] == (-1.0, True)
    # Free hand on a section with two goblets: get takes one, the other stays.
    nxt, _, _ = _step(env, [0, 1, 1, 1, 5, *dirty], get)
    assert nxt[:5] == [2, 1, 1, 5, home]
    # Drop beside another goblet is allowed; at home it does nothing (or fails with "fail").
    assert _step(env, [2, 5, 1, 5, home, *dirty], drop)[0][:5] == [0, 5, 1, 5, 5]
    assert _step(env, [2, home, 1, 5, home, *dirty], drop)[0][:5] == [2, home, 1, 5, home]
    assert _step(env, [2, home, 1, 5, home, *dirty], drop, "fail")[1:] == (-1.0, True)
    # Moves carry what the hand holds; abort fails.
    assert _step(env, [1, home, 0, 0, 0, *dirty], go(3))[0][:2] == [1, 3]
    assert _step(env, [0, home, 0, 0, 0, *dirty], abort)[1:] == (-1.0, True)
    # Goal: all clean, sponge put back at home.
    all_clean = [1] * 6
    assert _step(env, [1, home, 0, 0, 2, *all_clean], drop)[1:] == (1.0, True)
    almost = [1, 1, 1, 1, 1, 0]
    assert _step(env, [1, home, 0, 0, 2, *almost], drop)[1:] == (pytest.approx(-0.01), False)
    # Taking a goblet with free hand at home is impossible: get takes the sponge.
    assert _step(env, [0, home, 0, 0, 2, *dirty], get)[0][0] == 1


def test_variant_optimal_return_matches_the_shortest_solution():
    mdp = make_variant_mdp(6, 3)
    starts = solvers.start_states(mdp)
    assert len(starts) == 56  # multisets of 3 sections among 6
    values = solvers.optimal_values(mdp, gamma=1.0)
    steps = solvers.steps_to_goal(mdp)
    for start in starts[:3]:
        path = solvers.shortest_solution(mdp, int(start))
        assert len(path) == steps[start]
        # Replay the path: non-terminal steps, then the goal.
        state = int(start)
        for action in path:
            reward, terminal = float(mdp.reward[state, action, 0]), bool(mdp.terminal[state, action, 0])
            state = int(mdp.next_state[state, action, 0])
        assert (reward, terminal) == (1.0, True)
    # Each step costs 0.01 and the goal pays 1, so the best return is 1 − 0.01·(L − 1).
    np.testing.assert_allclose(values[starts], 1 - 0.01 * (steps[starts] - 1), atol=1e-6)
    assert solvers.best_return(mdp) == pytest.approx(
        float(np.asarray(mdp.start_probability)[starts] @ values[starts]))


def test_generator_and_compile_validation():
    with pytest.raises(ValueError, match=r"^num_sections=1 is invalid"):
        TableCleaningGenerator(num_sections=1)
    with pytest.raises(ValueError, match=r"^num_goblets=0 is invalid"):
        TableCleaningGenerator(num_sections=3, num_goblets=0)
    with pytest.raises(ValueError, match=r"num_codes\(params\)=\d+ is invalid"):
        compile_env(make_variant(12, 6), make_params(), reachable_only=True)


def test_gymnax_style_reset_and_step_truncate_at_max_steps():
    env = make_variant(4, 2)
    params = make_params(max_steps=2)
    obs, state = env.reset(jax.random.PRNGKey(3), params)
    assert obs.shape == (2 + 2 + 4,) and list(np.asarray(obs[:2])) == [0, 4]
    obs, state, reward, done, info = env.step(jax.random.PRNGKey(0), state, 0, params)  # get sponge
    assert int(obs[0]) == 1 and not bool(done) and float(reward) == pytest.approx(-0.01)
    obs, state, reward, done, info = env.step(jax.random.PRNGKey(0), state, 2 + 4, params)  # stay home
    assert bool(done) and bool(info["truncated"]) and not bool(info["terminal"])


def test_batch_size_does_not_change_the_compiled_tables():
    env, params = make_variant(3, 2), make_params()
    a = compile_env(env, params, reachable_only=True)
    b = compile_env(env, params, reachable_only=True, batch_size=7)
    for leaf_a, leaf_b in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(leaf_a, leaf_b)
