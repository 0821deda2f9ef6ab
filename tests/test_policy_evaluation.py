"""The learned policy's value (issue 47, point 3): exact greedy-policy evaluation every K
episodes (vdbejax.runs.evaluation), beside the returns, without changing them."""
from __future__ import annotations

import jax
import numpy as np
import pytest
from small_grid import interrupt_then_resume

from vdbejax import cli
from vdbejax.engine.agent_state import init_agents
from vdbejax.envs.solvers import best_return, optimal_q_values
from vdbejax.envs.tabular import make_tabular_mdp
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.results.analysis import summarize
from vdbejax.results.grid_result import GridResult
from vdbejax.results.policy import policy_gaps, policy_summary
from vdbejax.runs import RunOptions, UntilSolved, prepare_grid, run_grid, run_prepared
from vdbejax.runs.evaluation import greedy_returns
from vdbejax.runs.plan import evaluation_chunk


def two_states(max_steps: int = 3):
    """s0: a0 → s1 (reward 0), a1 ends the episode with 0.5; s1: a0 ends it with 1, a1 →
    s0 (reward 0). Within 3 steps the optimum is a0, a0: return 1."""
    return make_tabular_mdp([[1, 0], [0, 0]], [[0.0, 0.5], [1.0, 0.0]],
                            [[False, True], [True, False]], [1.0, 0.0], max_steps=max_steps)


def evaluate(mdp, settings, q=None, tables=None):
    params = stack_agents([make_agent(s) for s in settings])
    agents = jax.jit(init_agents)(mdp, params, np.zeros((len(settings), 2), np.uint32))
    q = np.asarray(agents.q) if q is None else np.asarray(q, np.float32)
    tables = {k: np.asarray(v) for k, v in agents.tables.items()} | (tables or {})
    return greedy_returns(mdp, params, q, tables, np.zeros(len(settings), np.int32))


def test_exact_values_on_a_two_state_task_by_hand():
    mdp = two_states()
    assert best_return(mdp) == 1.0
    q = np.zeros((3, 2, 2), np.float32)
    q[0] = [[1, 0], [1, 0]]  # a0, a0: 1
    q[1] = [[0, 1], [1, 0]]  # a1 at once: 0.5
    # q[2] ties everywhere, split uniformly: V(s0) = ½·0.5 + ½·V₂(s1), V₂(s1) = ½·1 +
    # ½·V₁(s0), V₁(s0) = ½·0.5 → 0.25 + ½·(0.5 + 0.125) = 0.5625.
    values = evaluate(mdp, [Setting("qlearning", "egreedy", 0.1)] * 3, q)
    np.testing.assert_allclose(values, [1.0, 0.5, 0.5625], rtol=1e-6)


def test_ties_split_as_the_explorer_splits_them():
    mdp = two_states()
    first = Setting("qlearning", "greedy", hyperparameters={"tie_break": "first"})
    values = evaluate(mdp, [Setting("qlearning", "greedy"), first])
    # Zero Q: uniform over both actions; "first": always a0 → a0 → the goal.
    np.testing.assert_allclose(values, [0.5625, 1.0], rtol=1e-6)


def test_stage_values_give_a_policy_per_step():
    mdp = two_states()
    settings = [Setting("ucbvi", "greedy", hyperparameters={"horizon": 3})] * 2
    stage = np.zeros((2, 2, 2, 3), np.float32)
    stage[0, 0, 0, 0] = stage[0, 1, 1, 1] = 1.0  # step 0: a0 (to s1); step 1 in s1: a1 (back)
    stage[0, 0, 1, 2] = 1.0  # step 2 in s0: a1 → 0.5
    stage[1, 0, 0, :] = stage[1, 1, 0, :] = 1.0  # a0 at every step: the goal
    values = evaluate(mdp, settings, tables={"q_stage": stage})
    np.testing.assert_allclose(values, [0.5, 1.0], rtol=1e-6)


def test_an_optimal_q_has_no_gap():
    mdp = two_states(max_steps=6)
    # Greedy on the discounted Q* (γ = 0.9): a0, a0, optimal within the step limit.
    discounted = optimal_q_values(mdp, gamma=0.9).astype(np.float32)
    # UCBVI's stage table holding the finite-horizon Q*: step t acts on Q* with 6 − t
    # steps to go (ties there are between optimal actions).
    stage = np.stack([optimal_q_values(mdp, gamma=1.0, horizon=6 - t) for t in range(6)],
                     axis=-1).astype(np.float32)
    settings = [Setting("qlearning", "egreedy", 0.1),
                Setting("ucbvi", "greedy", hyperparameters={"horizon": 6})]
    q = np.stack([discounted, np.zeros_like(discounted)])
    values = evaluate(mdp, settings, q, {"q_stage": np.stack([stage, stage])})
    np.testing.assert_allclose(best_return(mdp) - values, 0.0, atol=1e-6)


def test_evaluation_changes_no_return_and_is_kept_beside_them(tmp_path):
    from vdbejax.studies.task_names import make_task

    mdp = make_task("chain:5")
    settings = [Setting("qlearning", "egreedy", 0.1), Setting("ucbvi", "greedy"),
                Setting("double_qlearning", "ucb1")]
    plain = run_grid(mdp, settings, num_seeds=2, num_episodes=30)
    evaluated = run_grid(mdp, settings, num_seeds=2, num_episodes=30, evaluate_every=10)
    assert np.array_equal(plain.returns, evaluated.returns)
    assert np.array_equal(plain.lengths, evaluated.lengths)
    assert evaluated.policy_values.shape == (3, 2, 3)
    assert np.isfinite(evaluated.policy_values).all()
    assert list(evaluated.evaluation_episodes) == [10, 20, 30]
    gaps = policy_gaps(evaluated)
    assert (gaps >= -evaluated.meta["optimal_tolerance"]).all()
    assert evaluated.meta["optimal_return"] == best_return(mdp)
    # The same values whatever the chunking and strategy.
    again = run_grid(mdp, settings, num_seeds=2, num_episodes=30, evaluate_every=10,
                     strategy="lockstep", chunk_episodes=5)
    assert np.array_equal(again.policy_values, evaluated.policy_values)
    evaluated.save(tmp_path)
    loaded = GridResult.load(tmp_path)
    assert np.array_equal(loaded.policy_values, evaluated.policy_values)
    rows = summarize(loaded)
    table = policy_summary(loaded)
    assert [r.policy_gap for r in rows] == [t["policy_gap"] for t in table]
    for row in rows:
        assert row.optimal_ci_low <= row.optimal_fraction <= row.optimal_ci_high
        assert row.policy_gap_ci_low <= row.policy_gap <= row.policy_gap_ci_high


def test_a_stop_policy_and_a_resume_keep_the_evaluations(tmp_path):
    from vdbejax.studies.task_names import make_task

    mdp = make_task("chain:4")
    settings = [Setting("qlearning", "greedy"), Setting("rmax", "greedy")]
    stop = UntilSolved(window=5)
    plain = run_grid(mdp, settings, num_seeds=2, num_episodes=40, stop=stop, chunk_episodes=5)
    evaluated = run_grid(mdp, settings, num_seeds=2, num_episodes=40, stop=stop,
                         chunk_episodes=5, evaluate_every=10)
    assert np.array_equal(plain.returns, evaluated.returns, equal_nan=True)
    ran = evaluated.episodes_run if evaluated.episodes_run is not None else np.full((2, 2), 40)
    # Evaluated up to each agent's stop, NaN after it.
    assert np.array_equal(~np.isnan(evaluated.policy_values),
                          evaluated.evaluation_episodes <= ran[..., None])
    # Under a stop policy the chunks decide where agents stop: they are not realigned.
    with pytest.raises(ValueError, match="evaluate_every=10 is invalid with chunk_episodes=4"):
        prepare_grid(mdp, settings, num_seeds=2, num_episodes=40,
                     run=RunOptions(stop=stop, chunk_episodes=4, evaluate_every=10))
    # Killed after a chunk and resumed: the evaluations before the stop are kept.
    run = RunOptions(evaluate_every=10, checkpoint=tmp_path / "c.npz")
    prepared = prepare_grid(mdp, settings, num_seeds=2, num_episodes=40, run=run)
    whole = run_prepared(prepared)
    resumed = interrupt_then_resume(mdp, settings, run, 2 * 2 * 20, num_seeds=2,
                                    num_episodes=40)
    assert resumed.meta["resumed_from_agent_episodes"] > 0
    assert np.array_equal(resumed.policy_values, whole.policy_values)


def test_the_chunks_end_on_every_evaluation():
    assert evaluation_chunk(100, 50) == 50
    assert evaluation_chunk(100, 1000) == 100
    assert evaluation_chunk(100, 300) == 100
    assert evaluation_chunk(100, 101) == 101  # a prime: its own chunk, not chunks of 1
    assert evaluation_chunk(7, 7) == 7


@pytest.mark.parametrize("value, message", [
    ("0", "evaluate_every=0 is invalid"),
    ("2.5", "evaluate_every=2.5 is invalid"),
    ("31", "evaluate_every=31 is invalid with num_episodes=30"),
])
def test_a_bad_evaluate_every_is_one_line_and_exit_2(tmp_path, capsys, value, message):
    code = cli.main(["run", "--out", str(tmp_path / "x"), "--task", "chain:4", "--learners",
                     "qlearning", "--explorers", "greedy", "--seeds", "1", "--episodes", "30",
                     "--evaluate-every", value, "--quiet"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and message in lines[0], lines
    assert not (tmp_path / "x").exists()
    with pytest.raises(ValueError, match="evaluate_every"):
        RunOptions(evaluate_every=True)


def test_the_plan_states_the_evaluations_cost():
    from vdbejax.runs.estimate import estimate_prepared
    from vdbejax.studies.task_names import make_task

    mdp = make_task("chain:4")
    settings = [Setting("qlearning", "greedy"), Setting("ucb_h", "greedy")]
    plain = estimate_prepared(prepare_grid(mdp, settings, num_seeds=2, num_episodes=40))
    estimate = estimate_prepared(prepare_grid(mdp, settings, num_seeds=2, num_episodes=40,
                                              run=RunOptions(evaluate_every=10)))
    assert plain.evaluations == 0 and "policy evaluation" not in plain.describe()
    assert estimate.evaluations == 4 and estimate.long
    assert "policy evaluation" in estimate.describe() and "4 evaluations" in estimate.describe()
    H, S, A, K = int(mdp.max_steps), mdp.num_states, mdp.num_actions, mdp.num_outcomes
    stage = make_agent(settings[1]).learner.horizon
    assert estimate.evaluation_operations == 4 * H * S * A * (2 * K + 2 * (K + stage))
