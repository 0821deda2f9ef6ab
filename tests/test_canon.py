"""The exploration canon's contract (model, planning, whole-table updates) and built-ins
(R-max, MBIE-EB, SARSA(λ), Watkins Q(λ), Dyna-Q, Dyna-Q+), each against its formula under
jit and vmap and against a plain-numpy implementation of the same algorithm."""
from __future__ import annotations

import hashlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vdbejax
from vdbejax import RunOptions, run_grid
from vdbejax.envs.tabular import make_tabular_mdp
from vdbejax.methods import model as model_lib
from vdbejax.methods.agents import AgentOptions, Setting
from vdbejax.methods.contract import Learner, LearnerUpdate
from vdbejax.methods.learners import pair_mask
from vdbejax.methods.plugin_check import check_plugin
from vdbejax.methods.registry import learner
from vdbejax.methods.traces import trace_update

F = np.float32


def chain(num_states: int = 6, max_steps: int = 30):
    """Right / left / stay on a line; reaching the last state ends with +1, a step costs
    0.01 (staying 0.05)."""
    S = num_states
    nxt = np.zeros((S, 3), np.int32)
    rew = np.full((S, 3), -0.01, np.float32)
    for s in range(S):
        nxt[s] = [min(s + 1, S - 1), max(s - 1, 0), s]
    rew[:, 2] = -0.05
    rew[S - 2, 0] = 1.0
    term = np.zeros((S, 3), bool)
    term[S - 2, 0] = True
    start = np.zeros(S, np.float32)
    start[0] = 1.0
    return make_tabular_mdp(nxt, rew, term, start, max_steps=max_steps, name="chain")


def stochastic_chain(num_states: int = 5, max_steps: int = 25):
    """The chain whose moves slip (stay put) with probability 0.3."""
    S = num_states
    nxt = np.zeros((S, 2, 2), np.int32)
    rew = np.full((S, 2, 2), -0.01, np.float32)
    prob = np.zeros((S, 2, 2), np.float32)
    term = np.zeros((S, 2, 2), bool)
    for s in range(S):
        nxt[s, 0] = [min(s + 1, S - 1), s]
        nxt[s, 1] = [max(s - 1, 0), s]
        prob[s, :, 0], prob[s, :, 1] = 0.7, 0.3
    rew[S - 2, 0, 0] = 1.0
    term[S - 2, 0, 0] = True
    start = np.zeros(S, np.float32)
    start[0] = 1.0
    return make_tabular_mdp(nxt, rew, term, start, prob, max_steps=max_steps, name="slip")


FIRST = AgentOptions(tie_break="first")


def grid(mdp, settings, seeds=2, episodes=40, options=FIRST, **run):
    return run_grid(mdp, settings, num_seeds=seeds, num_episodes=episodes, options=options,
                    run=RunOptions(**run))


# --- the model -------------------------------------------------------------------------

def test_observe_counts_like_a_dense_table_under_jit_and_vmap():
    K = 3
    rows = {name: (jnp.zeros(K) if per == "outcome" else jnp.float32(0))
            for name, per in model_lib.MODEL_TABLES.items()}
    outcomes = [(2, 0.5, False), (4, -1.0, False), (2, 0.5, False), (0, 1.0, True),
                (1, 0.0, False)]
    observe = jax.jit(model_lib.observe)
    for s_next, r, done in outcomes:
        rows = observe(rows, jnp.int32(s_next), jnp.float32(r), jnp.bool_(done))
    assert float(rows["model_visits"]) == 5
    assert float(rows["model_terminal"]) == 1
    assert float(rows["model_reward_sum"]) == pytest.approx(1.0)
    assert float(rows["model_reward_squares"]) == pytest.approx(2.5)
    np.testing.assert_array_equal(rows["model_next_state"], [2, 4, 1])  # first seen first
    np.testing.assert_array_equal(rows["model_next_count"], [2, 1, 1])
    batched = jax.vmap(model_lib.observe)(
        jax.tree.map(lambda x: jnp.stack([x, x]), rows), jnp.array([4, 3]),
        jnp.array([0.0, 0.0], jnp.float32), jnp.array([False, False]))
    np.testing.assert_array_equal(batched["model_next_count"], [[2, 2, 1], [2, 1, 1]])
    assert float(batched["model_visits"][1]) == 6  # the list is full: counted, not listed


def test_expected_is_the_dense_model_times_values():
    rng = np.random.default_rng(0)
    S, A, K = 5, 2, 3
    nxt = rng.integers(0, S, (S, A, K)).astype(F)
    counts = rng.integers(0, 4, (S, A, K)).astype(F)
    terminal = rng.integers(0, 2, (S, A)).astype(F)
    visits = counts.sum(-1) + terminal
    zeros = np.zeros((S, A), F)
    model = model_lib.Model(jnp.asarray(visits), jnp.asarray(zeros), jnp.asarray(zeros),
                            jnp.asarray(terminal), jnp.asarray(nxt), jnp.asarray(counts))
    values = rng.normal(size=S).astype(F)
    dense = np.zeros((S, A, S))
    for s in range(S):
        for a in range(A):
            for k in range(K):
                dense[s, a, int(nxt[s, a, k])] += counts[s, a, k]
    want = dense @ values / np.maximum(visits, 1)
    got = jax.jit(lambda m, v: m.expected(v))(model, jnp.asarray(values))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    # The estimated outcome distribution: terminal or a listed successor, summing to 1
    # where (s, a) was visited and 0 where it was not.
    ended, successors = jax.jit(lambda m: (m.terminal_probability(),
                                           m.successor_probabilities()))(model)
    np.testing.assert_allclose(ended, terminal / np.maximum(visits, 1), rtol=1e-6)
    np.testing.assert_allclose(ended + successors.sum(-1), (visits > 0).astype(F), rtol=1e-6)
    twice = jax.vmap(lambda m, v: m.expected(v))(
        jax.tree.map(lambda x: jnp.stack([x, x]), model), jnp.stack([values, values]))
    np.testing.assert_array_equal(twice[0], got)  # batched: the same bits


# --- numpy references (same semantics, float32, ties to the first action) --------------

def _np_value_iteration(q, known, reward_mean, prob, nxt, gamma, bonus, v_max, tol, sweeps):
    change, n = np.inf, 0
    while change > tol and n < sweeps:
        values = q.max(axis=1)
        future = np.zeros_like(q)
        for k in range(prob.shape[2]):
            future = future + prob[..., k] * values[nxt[..., k]]
        new = np.where(known, reward_mean + bonus + F(gamma) * future, F(v_max)).astype(F)
        change, q, n = np.abs(new - q).max(), new, n + 1
    return q


def _np_optimistic(mdp, episodes, method, m=2.0, beta=0.1, gamma=0.9, r_max=1.0):
    """R-max (plan when a pair's visits reach m) or MBIE-EB (plan every step), greedy."""
    S, A = mdp.num_states, mdp.num_actions
    nxt_true = np.asarray(mdp.next_state)[..., 0]
    rew_true, term_true = np.asarray(mdp.reward)[..., 0], np.asarray(mdp.terminal)[..., 0]
    v_max = F(r_max) / F(1.0 - F(gamma))
    q = np.full((S, A), v_max, F)
    visits, rsum = np.zeros((S, A), F), np.zeros((S, A), F)
    count, succ = np.zeros((S, A, 1), F), np.zeros((S, A, 1), F)
    returns, lengths = [], []
    start = int(np.argmax(np.asarray(mdp.start_probability)))
    for _ in range(episodes):
        s, a, total, length = start, int(np.argmax(q[start])), F(0), 0
        while True:
            s2, r, done = int(nxt_true[s, a]), F(rew_true[s, a]), bool(term_true[s, a])
            total, length = F(total + r), length + 1
            before = visits[s, a]
            visits[s, a] += 1
            rsum[s, a] += r
            if not done:
                succ[s, a, 0], count[s, a, 0] = s2, count[s, a, 0] + 1
            n = np.maximum(visits, 1)
            prob = count / n[..., None]
            if method == "rmax" and before < m <= visits[s, a]:
                q = _np_value_iteration(q, visits >= m, rsum / n, prob, succ.astype(int),
                                        gamma, np.zeros_like(q), v_max, 1e-4, 1000)
            if method == "mbie_eb":
                q = _np_value_iteration(q, visits > 0, rsum / n, prob, succ.astype(int),
                                        gamma, (F(beta) * np.sqrt(F(1) / n)).astype(F), v_max, 1e-4,
                                        1000)
            if done or length >= int(mdp.max_steps):
                break
            s, a = s2, int(np.argmax(q[s2]))
        returns.append(total)
        lengths.append(length)
    return np.array(returns, F), np.array(lengths)


@pytest.mark.parametrize("method", ["rmax", "mbie_eb"])
def test_optimistic_planners_match_numpy(method):
    mdp = chain()
    values = {"known_visits": 2.0} if method == "rmax" else {"beta": 0.1}
    result = grid(mdp, [Setting(method, "greedy", None, values)], seeds=1, episodes=25)
    want_returns, want_lengths = _np_optimistic(mdp, 25, method)
    np.testing.assert_array_equal(result.lengths[0, 0], want_lengths)
    np.testing.assert_allclose(result.returns[0, 0], want_returns, atol=1e-5)
    assert want_returns[-1] > 0.9  # they solve the chain


def _np_traces(mdp, episodes, method, alpha=0.5, gamma=0.9, lam=0.8, kind="replacing"):
    S, A = mdp.num_states, mdp.num_actions
    nxt, rew = np.asarray(mdp.next_state)[..., 0], np.asarray(mdp.reward)[..., 0]
    term = np.asarray(mdp.terminal)[..., 0]
    q = np.zeros((S, A), F)
    start = int(np.argmax(np.asarray(mdp.start_probability)))
    returns, lengths = [], []
    carried = None  # after a terminal step, a′ was chosen in the start state already
    for _ in range(episodes):
        s, e, total, length = start, np.zeros((S, A), F), F(0), 0
        a = int(np.argmax(q[s])) if carried is None else carried
        carried = None
        while True:
            s2, r, done = int(nxt[s, a]), F(rew[s, a]), bool(term[s, a])
            total, length = F(total + r), length + 1
            act = start if done else s2
            a2 = int(np.argmax(q[act]))  # chosen before the update
            discount = F(0) if done else F(gamma)
            if method == "sarsa_lambda":
                target, decay = F(r + discount * q[act, a2]), F(F(gamma) * F(lam))
            else:
                best = q[act].max()
                target = F(r + discount * best)
                decay = F(F(gamma) * F(lam)) if q[act, a2] == best else F(0)
            e[s, a] = e[s, a] + 1 if kind == "accumulating" else 1
            step = F(F(alpha) * F(target - q[s, a]))
            q = (q + step * e).astype(F)
            e = (decay * e).astype(F)
            if done:
                carried = a2
            if done or length >= int(mdp.max_steps):
                break
            s, a = s2, a2
        returns.append(total)
        lengths.append(length)
    return np.array(returns, F), np.array(lengths)


@pytest.mark.parametrize("method", ["sarsa_lambda", "q_lambda"])
@pytest.mark.parametrize("kind", ["replacing", "accumulating"])
def test_traces_match_numpy(method, kind):
    mdp = chain()
    values = {"alpha": 0.5, "lam": 0.8, "trace": kind}
    result = grid(mdp, [Setting(method, "greedy", None, values)], seeds=1, episodes=30)
    want_returns, want_lengths = _np_traces(mdp, 30, method, kind=kind)
    np.testing.assert_array_equal(result.lengths[0, 0], want_lengths)
    np.testing.assert_allclose(result.returns[0, 0], want_returns, atol=1e-5)


def test_trace_update_formula_under_jit_and_vmap():
    q = jnp.arange(6, dtype=jnp.float32).reshape(3, 2)
    trace = jnp.full((3, 2), 0.5, jnp.float32)
    args = (jnp.int32(1), jnp.int32(0), jnp.float32(2.0), 0.5, 0.25, "accumulating",
            jnp.bool_(False))
    new_q, new_e = jax.jit(trace_update, static_argnums=7)(q, trace, *args)
    e = np.full((3, 2), 0.5, F)
    e[1, 0] = 1.5
    np.testing.assert_allclose(new_q, np.asarray(q) + 0.5 * 2.0 * e)
    np.testing.assert_allclose(new_e, 0.25 * e)
    cleared = trace_update(q, trace, *args[:-1], jnp.bool_(True))[1]
    assert float(cleared.sum()) == pytest.approx(0.25)  # only (s, a), once cleared
    batched = jax.vmap(lambda qq: trace_update(qq, trace, *args)[0])(jnp.stack([q, q]))
    np.testing.assert_array_equal(batched[1], new_q)


# --- equivalences and strategies --------------------------------------------------------

#: Three one-step methods and canon twins of them (λ = 0, no planning) on the chain, ties
#: broken at random: one grid, run once (:func:`one_step_grid`), which two tests read.
ONE_STEP = [Setting("sarsa", "egreedy", 0.2), Setting("sarsa_lambda", "egreedy", 0.2,
                                                     {"lam": 0.0}),
            Setting("qlearning", "egreedy", 0.2),
            Setting("dyna_q", "egreedy", 0.2, {"planning_steps": 0}),
            Setting("dyna_q_plus", "egreedy", 0.2, {"planning_steps": 0})]


@pytest.fixture(scope="module")
def one_step_grid():
    return grid(chain(), ONE_STEP, seeds=3, episodes=40, options=AgentOptions())


def test_no_lambda_and_no_planning_are_the_one_step_methods(one_step_grid):
    r = one_step_grid.returns
    np.testing.assert_array_equal(r[0], r[1])
    np.testing.assert_array_equal(r[2], r[3])
    np.testing.assert_array_equal(r[2], r[4])


CANON = [Setting("rmax", "greedy"), Setting("mbie_eb", "greedy"),
         Setting("sarsa_lambda", "egreedy", 0.1), Setting("q_lambda", "softmax", 0.5),
         Setting("dyna_q", "egreedy", 0.1, {"planning_steps": 3}),
         Setting("dyna_q_plus", "vdbe", 1.0, {"planning_steps": 2}),
         Setting("qlearning", "egreedy", 0.1)]


def test_strategies_chunks_and_lane_widths_give_the_same_bits():
    mdp = stochastic_chain()
    base = grid(mdp, CANON, seeds=3, episodes=20, options=AgentOptions())
    # Chunks of 17 episodes: a chunk ends mid-run, and a chunk's buffers keep the length
    # of the run's one chunk (32 episodes), so the sequential programs are the base run's.
    for run in ({"strategy": "lockstep"}, {"chunk_episodes": 17, "threads": 1}):
        other = grid(mdp, CANON, seeds=3, episodes=20, options=AgentOptions(), **run)
        np.testing.assert_array_equal(other.returns, base.returns, err_msg=str(run))
        np.testing.assert_array_equal(other.lengths, base.lengths, err_msg=str(run))
    assert vdbejax.engine.native_step_loops() is True


def _np_task(mdp):
    """The task's tables as numpy arrays, for :func:`_np_step`."""
    return tuple(np.asarray(table) for table in (mdp.probability, mdp.next_state,
                                                  mdp.reward, mdp.terminal))


def _np_step(task, s, a, rng):
    """One outcome of (s, a) drawn with numpy's ``rng``: ``(s′, r, terminal)``."""
    probability, next_state, reward, terminal = task
    k = rng.choice(probability.shape[2], p=probability[s, a])
    return int(next_state[s, a, k]), float(reward[s, a, k]), bool(terminal[s, a, k])


def _assert_same_mean(ours, theirs):
    """Per-agent means of two implementations agree within 4 standard errors (+ 0.02)."""
    spread = np.sqrt(ours.var(ddof=1) / ours.size + theirs.var(ddof=1) / theirs.size)
    assert abs(ours.mean() - theirs.mean()) < 4 * spread + 0.02, (ours.mean(), theirs.mean())


def _np_dyna(mdp, episodes, rng, n=5, alpha=0.5, gamma=0.9, epsilon=0.1):
    """Dyna-Q (Sutton & Barto Fig. 8.2) with a count model, ε-greedy, random ties."""
    S, A = mdp.num_states, mdp.num_actions
    task = _np_task(mdp)
    q = np.zeros((S, A))
    outcomes: dict = {}
    out = []

    def act(s):
        if rng.random() < epsilon:
            return int(rng.integers(A))
        best = np.flatnonzero(q[s] == q[s].max())
        return int(rng.choice(best))

    for _ in range(episodes):
        s, total, length = 0, 0.0, 0
        while True:
            a = act(s)
            s2, r, done = _np_step(task, s, a, rng)
            total, length = total + r, length + 1
            q[s, a] += alpha * (r + (0 if done else gamma * q[s2].max()) - q[s, a])
            outcomes.setdefault((s, a), []).append((s2, r, done))
            pairs = list(outcomes)
            for _ in range(n):
                ps, pa = pairs[rng.integers(len(pairs))]
                seen = outcomes[ps, pa]
                ms2, _, mdone = seen[rng.integers(len(seen))]
                mr = np.mean([o[1] for o in seen])
                q[ps, pa] += alpha * (mr + (0 if mdone else gamma * q[ms2].max()) - q[ps, pa])
            if done or length >= int(mdp.max_steps):
                break
            s = s2
        out.append(total)
    return np.array(out)


def test_dyna_q_agrees_with_numpy_statistically():
    mdp = stochastic_chain()
    agents, episodes = 60, 12
    ours = grid(mdp, [Setting("dyna_q", "egreedy", 0.1, {"alpha": 0.5})], seeds=agents,
                episodes=episodes, options=AgentOptions()).returns[0].mean(axis=1)
    rng = np.random.default_rng(7)
    theirs = np.array([_np_dyna(mdp, episodes, rng).mean() for _ in range(agents)])
    _assert_same_mean(ours, theirs)
    long = chain(12, max_steps=200)  # planning speeds learning up
    first = [grid(long, [Setting(name, "egreedy", 0.1, {"alpha": 0.5})], seeds=20,
                  episodes=3, options=AgentOptions()).lengths[0].sum()
             for name in ("dyna_q", "qlearning")]
    assert first[0] < first[1], first


def test_plain_plugins_keep_their_program(one_step_grid):
    """A grid without the canon is the same program as before (the paper grid's bits are
    checked elsewhere); canon kinds next to it (a model, traces) change nothing of the
    others."""
    qlearning = ONE_STEP[2]
    alone = grid(chain(), [qlearning], seeds=3, options=AgentOptions()).returns
    np.testing.assert_array_equal(alone[0], one_step_grid.returns[2])
    digest = hashlib.sha256(alone.tobytes()).hexdigest()
    assert digest == hashlib.sha256(grid(chain(), [qlearning], seeds=3,
                                         options=AgentOptions()).returns.tobytes()).hexdigest()


# --- the plug-in check ------------------------------------------------------------------

def _learner(**attributes):
    base = {"gamma": 0.9}

    def update(self, t):
        return LearnerUpdate(t.q, {}, t.q * 0)

    def plan(self, q, tables, model, context, uniforms):
        return q, {}

    namespace = {"__annotations__": {"gamma": float}, "update": update, "plan": plan,
                 **base, **attributes}
    return type("Probe", (Learner,), namespace)


@pytest.mark.parametrize("attributes, message", [
    ({"plan_at": "sometimes"}, "plan_at='sometimes' is invalid"),
    ({"plan_at": "known"}, "needs a field 'known_visits'"),
    ({"plan_at": "known", "known_visits": 2.0}, "needs uses_model = True"),
    ({"plan_at": "every"}, "needs a field 'plan_every'"),
    ({"plan_at": "step", "uses_next_action": True}, "a′ would be chosen before the plan"),
    ({"plan_at": "step", "plan": lambda self, q, t, m, c, u: (q[0], {})}, "plan() q returned"),
])
def test_plugin_check_refuses_what_the_engine_cannot_honour(attributes, message):
    cls = learner("probe_canon", replace=True)(_learner(**attributes))
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        check_plugin(cls(), vdbejax.methods.explorers.make_explorer("greedy"), 3)


def test_model_tables_are_counted_and_reserved():
    from vdbejax.engine.agent_state import state_bytes, table_shape
    from vdbejax.methods.agents import make_agent, stack_agents, table_layout

    mdp = stochastic_chain()
    layout = table_layout(stack_agents([make_agent(Setting("rmax", "greedy"))]))
    assert set(layout) == set(model_lib.MODEL_TABLES)
    assert table_shape(mdp, "outcome") == (5, 2, 2)
    assert state_bytes(mdp, layout) == 4 * (5 * 2) * (1 + 4) + 4 * (5 * 2 * 2) * 2


# --- finite-horizon methods -------------------------------------------------------------

def _np_ucbvi(mdp, episodes, horizon, bonus_kind, scale=0.1, delta=0.1, r_max=1.0,
              convention="paper"):
    S, A = mdp.num_states, mdp.num_actions
    at_visit = np.zeros((horizon, S, A), F)  # rlberry: the visits of the last visit at h
    nxt, rew = np.asarray(mdp.next_state)[..., 0], np.asarray(mdp.reward)[..., 0]
    term = np.asarray(mdp.terminal)[..., 0]
    visits, rsum = np.zeros((S, A), F), np.zeros((S, A), F)
    count, succ = np.zeros((S, A), F), np.zeros((S, A), int)
    returns, lengths = [], []
    if convention == "rlberry":  # rlberry's v_max: the task's reward range, not r_max
        r_max = F(float(rew.max()) - float(rew.min()))
    cap = F(0)
    for _ in range(horizon):
        cap = F(F(r_max) + F(1) * cap)  # v_max_0, where rlberry caps every stage's values
    for episode in range(episodes):
        n = np.maximum(visits, F(1))
        inverse_root = np.sqrt(F(1) / n).astype(F)
        stages = np.zeros((horizon, S, A), F)
        values, v_next = np.zeros(S, F), F(0)
        log_term = np.log(F(5 * S * A) * F(horizon * (episode + 1)) / F(delta)).astype(F)
        for h in range(horizon - 1, -1, -1):
            v_max = F(F(r_max) + F(1) * v_next)
            if convention == "rlberry":
                m = np.maximum(at_visit[h], F(1))
                bonus = np.where(at_visit[h] > 0, np.minimum(
                    F(scale) * np.sqrt(F(1) / m) + v_max / m, v_max), v_max).astype(F)
            elif bonus_kind == "bernstein":
                bonus = np.minimum(F(scale) * inverse_root + v_max / n, v_max).astype(F)
            else:
                bonus = (F(scale) * F(7.0) * F(horizon) * log_term * inverse_root).astype(F)
            future = (count / n) * values[succ]
            if convention == "rlberry":  # unclipped; unvisited: r̂ = 0, uniform successors
                future = np.where(visits > 0, future, values.mean())
                stages[h] = (rsum / n + bonus + future).astype(F)
            else:
                backed = np.minimum(rsum / n + bonus + future, v_max)
                stages[h] = np.where(visits > 0, backed, v_max)
            values, v_next = stages[h].max(axis=1), v_max
            if convention == "rlberry":
                values = np.minimum(values, cap)
        s, total, length = 0, F(0), 0
        while True:
            a = int(np.argmax(stages[min(length, horizon - 1), s]))
            s2, r, done = int(nxt[s, a]), F(rew[s, a]), bool(term[s, a])
            total, length = F(total + r), length + 1
            visits[s, a] += 1
            at_visit[min(length - 1, horizon - 1), s, a] = visits[s, a]
            rsum[s, a] += r
            if not done:
                succ[s, a], count[s, a] = s2, count[s, a] + 1
            if done or length >= int(mdp.max_steps):
                break
            s = s2
        returns.append(total)
        lengths.append(length)
    return np.array(returns, F), np.array(lengths)


@pytest.mark.parametrize("bonus, convention", [("bernstein", "paper"), ("hoeffding", "paper"),
                                               ("bernstein", "rlberry")])
def test_ucbvi_matches_numpy(bonus, convention):
    mdp = chain(max_steps=12)
    scale = 0.1 if bonus == "bernstein" else 0.001
    values = {"horizon": 12, "bonus": bonus, "bonus_scale": scale, "gamma": 1.0,
              "convention": convention}
    result = grid(mdp, [Setting("ucbvi", "greedy", None, values)], seeds=1, episodes=30)
    want_returns, want_lengths = _np_ucbvi(mdp, 30, 12, bonus, scale=scale,
                                           convention=convention)
    np.testing.assert_array_equal(result.lengths[0, 0], want_lengths)
    np.testing.assert_allclose(result.returns[0, 0], want_returns, atol=1e-5)
    assert want_returns[-10:].max() > 0.9  # it finds the goal's shortest path


def _np_ucb_h(mdp, episodes, horizon, scale=0.01, iota=1.0, r_max=1.0):
    S, A = mdp.num_states, mdp.num_actions
    nxt, rew = np.asarray(mdp.next_state)[..., 0], np.asarray(mdp.reward)[..., 0]
    term = np.asarray(mdp.terminal)[..., 0]
    v_max = F(horizon * r_max)
    q = np.full((horizon, S, A), v_max, F)
    n = np.zeros((horizon, S, A), F)
    returns, lengths = [], []
    for _ in range(episodes):
        s, total, length = 0, F(0), 0
        while True:
            h = min(length, horizon - 1)
            a = int(np.argmax(q[h, s]))
            s2, r, done = int(nxt[s, a]), F(rew[s, a]), bool(term[s, a])
            total, length = F(total + r), length + 1
            n[h, s, a] += 1
            t = n[h, s, a]
            rate = F((horizon + 1.0) / (horizon + t))
            bonus = F(F(scale) * np.sqrt(F(horizon ** 3) * F(iota) / t))
            later = 0.0 if h + 1 >= horizon or done else min(v_max, q[h + 1, s2].max())
            target = F(F(r + F(later)) + bonus)
            q[h, s, a] = F(q[h, s, a] + F(rate * F(target - q[h, s, a])))
            if done or length >= int(mdp.max_steps):
                break
            s = s2
        returns.append(total)
        lengths.append(length)
    return np.array(returns, F), np.array(lengths)


def test_ucb_h_matches_numpy():
    mdp = chain(max_steps=12)
    values = {"horizon": 12, "bonus_scale": 0.01, "gamma": 1.0}
    result = grid(mdp, [Setting("ucb_h", "greedy", None, values)], seeds=1, episodes=60)
    want_returns, want_lengths = _np_ucb_h(mdp, 60, 12)
    np.testing.assert_array_equal(result.lengths[0, 0], want_lengths)
    np.testing.assert_allclose(result.returns[0, 0], want_returns, atol=1e-5)


def test_ucb_h_takes_a_horizon_whose_cube_exceeds_int32():
    # H = 10,000 (the gridworlds' and cruz2018's step limit): H³ = 10¹² once overflowed
    # JAX's int32 in the bonus, a traceback in the middle of `vdbejax bench`.
    mdp = chain(max_steps=30)
    values = {"horizon": 10_000, "bonus_scale": 0.01, "gamma": 1.0}
    result = grid(mdp, [Setting("ucb_h", "greedy", None, values)], seeds=1, episodes=8)
    want_returns, want_lengths = _np_ucb_h(mdp, 8, 10_000)
    np.testing.assert_array_equal(result.lengths[0, 0], want_lengths)
    np.testing.assert_allclose(result.returns[0, 0], want_returns, atol=1e-5)


def test_finite_horizon_methods_keep_their_bits_across_strategies():
    mdp = stochastic_chain()
    settings = [Setting("ucbvi", "greedy", None, {"horizon": 25}),
                Setting("ucbvi", "greedy", None, {"horizon": 25, "bonus": "hoeffding",
                                                  "bonus_scale": 0.01}),
                Setting("ucbvi", "greedy", None, {"horizon": 25, "convention": "rlberry"}),
                Setting("ucb_h", "egreedy", 0.1, {"horizon": 25, "bonus_scale": 0.01})]
    base = grid(mdp, settings, seeds=3, episodes=25, options=AgentOptions())
    for run in ({"strategy": "lockstep"}, {"chunk_episodes": 17}):  # the base run's programs
        other = grid(mdp, settings, seeds=3, episodes=25, options=AgentOptions(), **run)
        np.testing.assert_array_equal(other.returns, base.returns, err_msg=str(run))
    assert vdbejax.engine.native_step_loops() is True


def test_long_stage_tables_keep_the_step_loop_native():
    # Four lanes of SixArms' [S, A, 200] stage tables: XLA offloaded their reductions to
    # YNNPACK, which a native loop cannot hold, and the run fell back to lockstep.
    from vdbejax.envs.suite import make_suite_task
    mdp = make_suite_task("sixarms")
    settings = [Setting("ucb_h", "greedy", None, {"horizon": 200, "bonus_scale": 0.1})]
    base = grid(mdp, settings, seeds=4, episodes=2, options=AgentOptions())
    assert vdbejax.engine.native_step_loops() is True
    other = grid(mdp, settings, seeds=4, episodes=2, options=AgentOptions(), strategy="lockstep")
    np.testing.assert_array_equal(other.returns, base.returns)


# --- the planning moments, counted ------------------------------------------------------

@pytest.mark.parametrize("moment", ["step", "episode", "every"])
def test_planning_moments_are_kept(moment):
    from vdbejax.engine import run_agents
    from vdbejax.engine.agent_state import agent_keys, broadcast_agents
    from vdbejax.methods.agents import make_agent, stack_agents
    from vdbejax.methods.contract import Table

    class Counting(Learner):
        gamma: float = 0.9
        plan_every: float = 3.0
        plan_at = moment

        def tables(self):
            return {"plans": Table("pair", 0.0)}

        def update(self, t):
            return LearnerUpdate(t.q, dict(t.tables), t.q * 0)

        def plan(self, q, tables, model, context, uniforms):
            first = jnp.zeros_like(tables["plans"]).at[0, 0].set(1.0)
            return q, {"plans": tables["plans"] + first}

    learner(f"probe_{moment}", replace=True)(Counting)
    mdp = chain(max_steps=100_000)  # no truncation: every episode ends at the goal
    episodes = 6
    params = broadcast_agents(stack_agents([make_agent(Setting(f"probe_{moment}", "egreedy",
                                                               0.5))]), 3)
    done = run_agents(mdp, params, agent_keys(0, 3), episodes)
    plans = done.final_state.tables["plans"][:, 0, 0]
    steps = done.lengths.sum(axis=1)
    want = {"step": steps, "episode": np.full(3, episodes + 1),
            "every": (steps + 1) // 3}[moment]
    np.testing.assert_array_equal(plans, want)


def test_the_model_based_example_runs(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / "model_based_plugin.py"
    done = subprocess.run([sys.executable, str(example), "--seeds", "2", "--episodes", "20",
                           "--out", str(tmp_path)], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stdout.splitlines() if "final return" in line]
    assert len(lines) == 5 and lines[0].startswith("ucb_vi/greedy/beta=0.05")
    assert (tmp_path / "returns.npz").exists()


# --- PSRL ---------------------------------------------------------------------------------

def test_posterior_sample_has_the_posterior_mean_under_jit_and_vmap():
    from vdbejax.methods.posterior import posterior_sample

    S, A = 3, 2
    visits = jnp.array([[4.0, 0.0], [2.0, 1.0], [0.0, 0.0]])
    model = model_lib.Model(visits, jnp.array([[2.0, 0.0], [1.0, -1.0], [0.0, 0.0]]),
                            jnp.zeros((S, A)), jnp.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]),
                            jnp.array([[[2.0], [0.0]], [[0.0], [0.0]], [[0.0], [0.0]]]),
                            jnp.array([[[3.0], [0.0]], [[2.0], [0.0]], [[0.0], [0.0]]]))
    keys = jax.random.split(jax.random.key(0), 4000)
    rewards, transitions = jax.jit(jax.vmap(lambda k: posterior_sample(model, k, 0.5, 0.0)))(
        keys)
    want = np.full((S, A, S + 1), 0.5)
    want[0, 0, 2] += 3
    want[0, 0, 3] += 1
    want[1, 0, 0] += 2
    want[1, 1, 3] += 1
    want /= want.sum(-1, keepdims=True)
    np.testing.assert_allclose(transitions.mean(0), want.transpose(2, 0, 1), atol=0.02)
    np.testing.assert_allclose(rewards.mean(0), np.asarray(model.reward_sum) / (1 + visits),
                               atol=0.05)
    np.testing.assert_allclose(rewards.std(0), 1 / np.sqrt(1 + np.asarray(visits)), rtol=0.1)


@jax.jit
def _gamma_draw(key, shape):
    from vdbejax.methods.posterior import gamma_variates

    return gamma_variates(key, shape)


_gamma_draws = jax.jit(jax.vmap(_gamma_draw, in_axes=(0, None)))


@pytest.mark.parametrize("alpha", [0.1, 0.5, 1.0, 3.7, 60.0])
def test_gamma_variates_have_the_gamma_distribution_under_jit_and_vmap(alpha):
    """Marsaglia–Tsang (with the α < 1 boost) against numpy's Gamma: mean, variance and
    the two-sample Kolmogorov–Smirnov distance; and per-key bits under vmap."""
    n = 100_000
    keys = jax.random.split(jax.random.key(3), 4)
    shape = jnp.full(n, alpha, jnp.float32)  # an argument: one program for every alpha
    ours = np.asarray(_gamma_draws(keys, shape))
    assert ours.dtype == np.float32 and np.all(ours >= 0) and np.all(np.isfinite(ours))
    flat = ours.ravel().astype(np.float64)
    se = np.sqrt(alpha / flat.size)
    assert abs(flat.mean() - alpha) < 5 * se
    assert abs(flat.var() / alpha - 1) < 0.03
    theirs = np.sort(np.random.default_rng(0).gamma(alpha, size=flat.size))
    grid = np.sort(flat)
    both = np.concatenate([grid, theirs])
    distance = np.max(np.abs(np.searchsorted(grid, both, "right") / grid.size
                             - np.searchsorted(theirs, both, "right") / theirs.size))
    assert distance < 1.63 * np.sqrt(2 / flat.size) * 1.5  # KS at p = 0.01, with slack
    one = np.asarray(_gamma_draw(keys[2], shape))
    np.testing.assert_array_equal(one, ours[2])


def test_gamma_variates_take_a_shape_per_entry():
    # 100,000 entries: the program of the test above (one program for every shape vector).
    alpha = jnp.tile(jnp.array([0.2, 1.0, 7.0], jnp.float32), 33_334)[:100_000]
    draws = np.asarray(_gamma_draw(jax.random.key(5), alpha))[:99_999].reshape(-1, 3)
    np.testing.assert_allclose(draws.mean(0), [0.2, 1.0, 7.0], rtol=0.03)


def _np_psrl(mdp, episodes, rng, horizon, prior=1.0):
    S, A = mdp.num_states, mdp.num_actions
    counts, visits, rsum = np.zeros((S, A, S + 1)), np.zeros((S, A)), np.zeros((S, A))
    task = _np_task(mdp)
    out = []
    for _ in range(episodes):
        # Dirichlet(prior + counts) per (s, a): independent Gamma variates, normalised
        gammas = rng.standard_gamma(prior + counts)
        p = gammas / gammas.sum(axis=-1, keepdims=True)
        r = (rsum / (1 + visits)) + rng.normal(size=(S, A)) / np.sqrt(1 + visits)
        q, v = np.zeros((horizon, S, A)), np.zeros(S)
        for h in range(horizon - 1, -1, -1):
            q[h] = r + p[..., :S] @ v
            v = q[h].max(axis=1)
        s, total = 0, 0.0
        for h in range(int(mdp.max_steps)):
            a = int(np.argmax(q[min(h, horizon - 1), s]))
            s2, reward, done = _np_step(task, s, a, rng)
            total += reward
            visits[s, a] += 1
            rsum[s, a] += reward
            counts[s, a, S if done else s2] += 1
            if done:
                break
            s = s2
        out.append(total)
    return np.array(out)


#: PSRL with the default prior (1), then priors below and above one: the posterior's Gamma
#: draws take the α < 1 boost. One grid per strategy (:func:`psrl_grids`), which the two
#: tests below read.
PSRL = [Setting("psrl", "greedy", None, {"horizon": 25, "gamma": 1.0})] + [
    Setting("psrl", "greedy", None, {"horizon": 25, "prior": prior}) for prior in (0.1, 2.5)]


@pytest.fixture(scope="module")
def psrl_grids():
    """``(sequential, lockstep)``: the PSRL settings, 40 agents × 15 episodes each."""
    mdp = stochastic_chain()
    return tuple(grid(mdp, PSRL, seeds=40, episodes=15, strategy=strategy)
                 for strategy in ("sequential", "lockstep"))


def test_psrl_agrees_with_numpy_statistically_and_keeps_its_bits(psrl_grids):
    mdp = stochastic_chain()
    ours, other = psrl_grids
    agents, episodes = ours.returns.shape[1:]
    rng = np.random.default_rng(11)
    theirs = np.array([_np_psrl(mdp, episodes, rng, 25).mean() for _ in range(agents)])
    _assert_same_mean(ours.returns[0].mean(axis=1), theirs)
    np.testing.assert_array_equal(other.returns[0], ours.returns[0])


def test_psrl_keeps_its_bits_across_strategies_with_a_prior_below_one(psrl_grids):
    """The posterior's Gamma draws take the α < 1 boost: the same bits in both engines."""
    ours, other = psrl_grids
    assert [dict(s.hyperparameters)["prior"] for s in ours.settings[1:]] == [0.1, 2.5]
    np.testing.assert_array_equal(other.returns, ours.returns)
    np.testing.assert_array_equal(other.lengths, ours.lengths)
    # not a vacuous comparison: the priors change what the agents do
    assert not np.array_equal(ours.returns[1], ours.returns[2])


# --- Delayed Q-learning -------------------------------------------------------------------

def _np_delayed_q(mdp, episodes, m=3.0, eps1=0.01, gamma=0.9, r_max=1.0):
    """Strehl et al. 2006, Alg. 1, on a deterministic task, greedy with first ties."""
    S, A = mdp.num_states, mdp.num_actions
    nxt, rew = np.asarray(mdp.next_state)[..., 0], np.asarray(mdp.reward)[..., 0]
    term = np.asarray(mdp.terminal)[..., 0]
    q = np.full((S, A), F(r_max) / F(1 - F(gamma)), F)
    u, n = np.zeros((S, A), F), np.zeros((S, A), F)
    learn, attempted, changed = np.ones((S, A), bool), np.zeros((S, A), F), F(0)
    clock, returns, lengths = 1, [], []  # the engine's first iteration is the first reset
    a = None
    for _ in range(episodes):
        s, total, length = 0, F(0), 0
        a = int(np.argmax(q[s]))
        while True:
            s2, r, done = int(nxt[s, a]), F(rew[s, a]), bool(term[s, a])
            total, length = F(total + r), length + 1
            now = F(clock + 1)
            if learn[s, a]:
                u[s, a] = F(u[s, a] + F(r + (F(0) if done else F(gamma) * q[s2].max())))
                n[s, a] += 1
                if n[s, a] >= m:
                    mean = F(u[s, a] / F(m))
                    if q[s, a] - mean >= F(2 * eps1):
                        q[s, a], changed = F(mean + F(eps1)), now
                    elif attempted[s, a] >= changed:
                        learn[s, a] = False
                    attempted[s, a], u[s, a], n[s, a] = now, 0, 0
            elif attempted[s, a] < changed:
                learn[s, a] = True
            clock += 1
            if done:
                break
            s, a = s2, int(np.argmax(q[s2]))
        returns.append(total)
        lengths.append(length)
    return np.array(returns, F), np.array(lengths)


def test_delayed_q_matches_numpy():
    mdp = chain(max_steps=100_000)
    values = {"updates": 3.0, "epsilon1": 0.01}
    result = grid(mdp, [Setting("delayed_q", "greedy", None, values)], seeds=1, episodes=40)
    want_returns, want_lengths = _np_delayed_q(mdp, 40)
    np.testing.assert_array_equal(result.lengths[0, 0], want_lengths)
    np.testing.assert_allclose(result.returns[0, 0], want_returns, atol=1e-5)
    assert want_returns[-5:].max() > 0.9
    other = grid(mdp, [Setting("delayed_q", "egreedy", 0.2, values)], seeds=3, episodes=20,
                 options=AgentOptions())
    lockstep = grid(mdp, [Setting("delayed_q", "egreedy", 0.2, values)], seeds=3,
                    episodes=20, options=AgentOptions(), strategy="lockstep")
    np.testing.assert_array_equal(other.returns, lockstep.returns)


def test_a_whole_table_learner_writes_its_stage_tables_back_to_its_own_rows():
    """Every agent's stage table, updated whole each step, stays its own: a count of its
    visits per (s, a, stage) adds up to its own steps (a block written at another agent's
    rows would not)."""
    from vdbejax.engine import EngineOptions, run_agents
    from vdbejax.engine.agent_state import agent_keys, broadcast_agents
    from vdbejax.methods.agents import make_agent, stack_agents
    from vdbejax.methods.contract import Table

    class StageCounts(Learner):
        gamma: float = 0.9
        updates_whole_table = True

        def tables(self):
            return {"seen": Table("stage", 0.0, length=4)}

        def update(self, t):
            raise NotImplementedError

        def update_table(self, q, tables, t):
            stage = jnp.minimum(jnp.asarray(t.step) - 1, 3)
            here = (pair_mask(q, t.state, t.action)[..., None]
                    & (jnp.arange(4) == stage))
            return LearnerUpdate(q, {"seen": tables["seen"] + here}, t.q * 0)

    learner("probe_stage_counts", replace=True)(StageCounts)
    mdp = chain(max_steps=30)
    params = broadcast_agents(stack_agents([make_agent(Setting("probe_stage_counts",
                                                               "egreedy", 0.5))]), 5)
    for strategy in ("sequential", "lockstep"):
        done = run_agents(mdp, params, agent_keys(0, 5), 6, EngineOptions(strategy=strategy))
        seen = done.final_state.tables["seen"]
        np.testing.assert_array_equal(seen.sum(axis=(1, 2, 3)), done.lengths.sum(axis=1))
        first_steps = seen[..., 0].sum(axis=(1, 2))
        np.testing.assert_array_equal(first_steps, np.full(5, 6))  # one per episode
