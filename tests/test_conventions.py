"""Conventions that follow their references (docs/canon.md): UCBVI's rlberry convention
(rlberry-scool 0.7.3's ``UCBVIAgent``), PSRL's prior (Osband, Russo & Van Roy 2013), each
method's own γ; and the task facts the engine hands a learner (``TaskFacts``,
``Learner.for_task``). The comparison with rlberry itself is a benchmark
(``benchmarks/rlberry_ucbvi.py``), not a test: it needs rlberry's own venv."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax import RunOptions, run_grid
from vdbejax.engine.agent_state import task_facts
from vdbejax.envs.tabular import make_tabular_mdp
from vdbejax.methods.agents import (
    AgentOptions,
    Setting,
    make_agent,
    paper_settings,
    recorded_options,
)
from vdbejax.methods.contract import Context, TaskFacts
from vdbejax.methods.finite_horizon import UCBVI
from vdbejax.methods.model import Model
from vdbejax.methods.posterior import PSRL, posterior_sample

FIRST = AgentOptions(tie_break="first")


def wander(terminal: bool = False, max_steps: int = 8):
    """Three states, two actions, two outcomes each (0.6 / 0.4); rewards in [−1, 2] (an
    impossible outcome pays 5); with ``terminal``, action 1 in state 2 may end the
    episode."""
    S, A = 3, 2
    nxt = np.array([[[1, 0], [2, 0]], [[2, 1], [0, 1]], [[0, 2], [1, 2]]], np.int32)
    rew = np.array([[[0.5, 0.5], [-1.0, -1.0]], [[0.0, 0.0], [2.0, 2.0]],
                    [[1.0, 1.0], [0.25, 5.0]]], np.float32)
    prob = np.tile(np.array([0.6, 0.4], np.float32), (S, A, 1))
    prob[2, 1] = [1.0, 0.0]  # the outcome paying 5 never happens
    term = np.zeros((S, A, 2), bool)
    term[2, 1, 0] = terminal
    start = np.eye(S, dtype=np.float32)[0]
    return make_tabular_mdp(nxt, rew, term, start, prob, max_steps=max_steps, name="wander")


def grid(mdp, settings, seeds=3, episodes=12):
    return run_grid(mdp, settings, num_seeds=seeds, num_episodes=episodes, options=FIRST,
                    run=RunOptions())


# --- the task facts -------------------------------------------------------------------------

def test_the_engine_tells_the_reward_range_and_terminal_outcomes_of_possible_outcomes():
    assert task_facts(wander()) == TaskFacts(-1.0, 2.0, False)
    assert task_facts(wander(terminal=True)) == TaskFacts(-1.0, 2.0, True)
    assert TaskFacts(-1.0, 2.0, False).reward_range == 3.0


def test_learners_take_what_their_convention_needs_from_the_facts():
    facts = TaskFacts(-1.0, 2.0, False)
    assert UCBVI(convention="rlberry").for_task(facts).reward_range == 3.0
    assert UCBVI(convention="rlberry").for_task(TaskFacts(1.0, 1.0, False)).reward_range == 1.0
    assert UCBVI(convention="rlberry", reward_range=0.5).for_task(facts).reward_range == 0.5
    assert UCBVI().for_task(facts).reward_range is None  # the paper's bounds with r_max
    assert PSRL().for_task(facts).terminal_outcome == "never"
    assert PSRL().for_task(TaskFacts(0.0, 1.0, True)).terminal_outcome == "always"
    assert PSRL(terminal_outcome="always").for_task(facts).terminal_outcome == "always"
    with pytest.raises(ValueError, match="terminal_outcome='never' is invalid"):
        PSRL(terminal_outcome="never").for_task(TaskFacts(0.0, 1.0, True))


@pytest.mark.parametrize("setting, message", [
    (Setting("ucbvi", "greedy", None, {"reward_range": 2.0}), "reward_range=2.0 is invalid"),
    (Setting("ucbvi", "greedy", None, {"convention": "rlberry", "reward_range": -1.0}),
     "reward_range=-1.0 is invalid"),
    (Setting("psrl", "greedy", None, {"terminal_outcome": "sometimes"}),
     "terminal_outcome='sometimes' is invalid"),
])
def test_bad_convention_values_get_one_line(setting, message):
    with pytest.raises(ValueError, match=message):
        make_agent(setting)


def test_unresolved_conventions_refuse_to_plan_outside_the_engine():
    S, A, H = 2, 2, 3
    zeros = jnp.zeros((S, A))
    model = Model(zeros, zeros, zeros, zeros, jnp.zeros((S, A, S)), jnp.zeros((S, A, S)))
    context = Context(jnp.int32(0), jnp.int32(0), jnp.bool_(False))
    tables = {"q_stage": jnp.zeros((S, A, H)), "bonus_visits": jnp.zeros((S, A, H)),
              "visits": zeros}
    with pytest.raises(ValueError, match="needs the task's reward range"):
        UCBVI(horizon=H, convention="rlberry").plan(zeros, tables, model, context, ())
    with pytest.raises(ValueError, match="needs to know whether the task"):
        PSRL(horizon=H).plan(zeros, tables, model, context, (jnp.float32(0.1),) * 2)


# --- UCBVI's rlberry convention ------------------------------------------------------------

def _rlberry_backward_induction(R, P, visits, at_visit, scale, spread, horizon):
    """rlberry-scool 0.7.3's ``UCBVIAgent`` planning (``backward_induction_reward_sd`` on
    ``R_hat + B_sa``), in float64: v_max[h] = spread · (H − h); B_sa[h] the simplified
    Bernstein bonus of the visits at the pair's last visit at stage h (v_max[h] before
    one); unvisited pairs r̂ = 0, P̂ uniform; V_h = min(max_a Q_h, v_max[0])."""
    S, A = R.shape
    v_max = spread * (horizon - np.arange(horizon))
    R_hat = np.where(visits > 0, R, 0.0)
    P_hat = np.where(visits[..., None] > 0, P, 1.0 / S)
    Q, V = np.zeros((horizon, S, A)), np.zeros((horizon + 1, S))
    for h in range(horizon - 1, -1, -1):
        m = at_visit[..., h]
        bonus = np.where(m > 0, np.minimum(scale * np.sqrt(1.0 / np.maximum(m, 1.0))
                                           + v_max[h] / np.maximum(m, 1.0), v_max[h]),
                         v_max[h])
        Q[h] = R_hat + bonus + P_hat @ V[h + 1]
        V[h] = np.minimum(Q[h].max(axis=1), v_max[0])
    return Q, V


def test_ucbvi_rlberry_caps_state_values_at_v_max_like_rlberry():
    S, A, H, scale, spread = 3, 2, 4, 0.5, 3.0
    visits = np.array([[3.0, 1.0], [0.0, 2.0], [5.0, 4.0]])
    R = np.array([[0.5, -1.0], [0.0, 2.0], [1.0, 0.25]])
    P = np.zeros((S, A, S))
    P[0, 0, [1, 0]], P[0, 1, 2] = [2 / 3, 1 / 3], 1.0
    P[1, 1, [0, 1]] = [0.5, 0.5]
    P[2, 0, [0, 2]], P[2, 1, [1, 2]] = [0.4, 0.6], [0.75, 0.25]
    at_visit = np.zeros((S, A, H))
    at_visit[0, 0, [0, 2]], at_visit[1, 1, 1], at_visit[2, :, 3] = [1.0, 3.0], 2.0, [5.0, 4.0]
    listed = np.tile(np.arange(S, dtype=np.float32), (S, A, 1))
    model = Model(jnp.asarray(visits, jnp.float32), jnp.asarray(R * visits, jnp.float32),
                  jnp.zeros((S, A)), jnp.zeros((S, A)), jnp.asarray(listed),
                  jnp.asarray(P * visits[..., None], jnp.float32))
    learner = UCBVI(horizon=H, bonus_scale=scale, convention="rlberry", reward_range=spread)
    tables = {"q_stage": jnp.zeros((S, A, H)), "bonus_visits": jnp.asarray(at_visit, jnp.float32),
              "visits": jnp.asarray(visits, jnp.float32)}
    context = Context(jnp.int32(4), jnp.int32(0), jnp.bool_(False))
    plan = jax.jit(lambda tables, model: learner.plan(tables["visits"], tables, model, context,
                                                      ()))
    q0, planned = plan(tables, model)
    want_q, want_v = _rlberry_backward_induction(R, P, visits, at_visit, scale, spread, H)
    np.testing.assert_allclose(np.asarray(planned["q_stage"]), want_q.transpose(1, 2, 0),
                               rtol=1e-5)
    np.testing.assert_allclose(np.asarray(q0), want_q[0], rtol=1e-5)
    v_max_0 = spread * H
    assert want_q.max(axis=2).max() > v_max_0  # the cap binds here: values would exceed it
    assert want_v.max() == v_max_0


def test_ucbvi_rlberry_takes_the_task_reward_range_through_the_engine():
    mdp = wander()
    values = {"horizon": 8, "bonus_scale": 0.1, "convention": "rlberry"}
    result = grid(mdp, [Setting("ucbvi", "greedy", None, values),
                        Setting("ucbvi", "greedy", None, {**values, "reward_range": 3.0})])
    np.testing.assert_array_equal(result.returns[0], result.returns[1])


# --- PSRL's prior -------------------------------------------------------------------------

def test_psrl_posterior_has_no_terminal_outcome_on_a_task_without_one():
    S, A = 3, 2
    visits = jnp.array([[4.0, 0.0], [2.0, 1.0], [0.0, 0.0]])
    model = Model(visits, jnp.zeros((S, A)), jnp.zeros((S, A)), jnp.zeros((S, A)),
                  jnp.array([[[2.0], [0.0]], [[0.0], [0.0]], [[1.0], [0.0]]]),
                  jnp.array([[[4.0], [0.0]], [[2.0], [0.0]], [[0.0], [0.0]]]))
    keys = jax.random.split(jax.random.key(1), 4000)
    draw = jax.jit(jax.vmap(lambda k: posterior_sample(model, k, 0.5, 0.0, False)[1]))
    transitions = np.asarray(draw(keys))
    assert transitions.shape == (4000, S, S, A)  # successor-major, no "terminal" row
    np.testing.assert_allclose(transitions.sum(axis=1), 1.0, atol=1e-5)
    want = np.full((S, A, S), 0.5)
    want[0, 0, 2] += 4
    want[1, 0, 0] += 2
    want /= want.sum(-1, keepdims=True)
    np.testing.assert_allclose(transitions.mean(0), want.transpose(2, 0, 1), atol=0.02)


def test_psrl_default_prior_follows_whether_the_task_terminates():
    for terminal, outcome in ((False, "never"), (True, "always")):
        settings = [Setting("psrl", "greedy", None, {"horizon": 8}),
                    Setting("psrl", "greedy", None, {"horizon": 8, "terminal_outcome": outcome})]
        result = grid(wander(terminal), settings)
        np.testing.assert_array_equal(result.returns[0], result.returns[1])
        np.testing.assert_array_equal(result.lengths[0], result.lengths[1])


# --- γ: each method's own ------------------------------------------------------------------

def test_a_setting_without_gamma_gives_each_method_its_class_default():
    for name in ("ucbvi", "psrl", "ucb_h"):
        assert float(make_agent(Setting(name, "greedy")).learner.gamma) == 1.0
    for name, explorer in (("qlearning", "egreedy"), ("sarsa", "vdbe"), ("rmax", "greedy")):
        assert float(make_agent(Setting(name, explorer)).learner.gamma) == np.float32(0.9)
    shared = AgentOptions(gamma=0.95)
    assert float(make_agent(Setting("ucbvi", "greedy"), shared).learner.gamma) == np.float32(
        0.95)
    own = Setting("psrl", "greedy", None, {"gamma": 0.5})
    assert float(make_agent(own, shared).learner.gamma) == 0.5


def test_runs_whose_agents_keep_their_gamma_keep_their_fingerprint_record():
    """The paper's grid gets γ = 0.9 as before: its options are recorded as before."""
    assert recorded_options(AgentOptions(), paper_settings())["gamma"] == 0.9
    assert recorded_options(AgentOptions(), [Setting("ucbvi", "greedy")])["gamma"] is None
    assert recorded_options(AgentOptions(gamma=0.5), paper_settings())["gamma"] == 0.5
