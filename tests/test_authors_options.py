"""The authors' agent details as options of the built-ins, each against a hand-computed step."""
import numpy as np
import pytest

from vdbejax.engine import agent_keys, run_agents
from vdbejax.envs import make_tabular_mdp
from vdbejax.envs.cruz2018 import make_authors_mdp
from vdbejax.methods import AgentOptions, Setting, make_agent, stack_agents
from vdbejax.runs import RunOptions, run_grid


def one_step_mdp(first_reward: float):
    """State 0: action 0 ends the episode with ``first_reward``; action 1 loops (−0.01)."""
    return make_tabular_mdp(next_state=[[0, 0], [1, 1]], reward=[[first_reward, -0.01], [0, 0]],
                            terminal=[[True, False], [False, False]],
                            start_probability=[1.0, 0.0], max_steps=10)


def run_one(mdp, setting, episodes=1, seed=0):
    params = stack_agents([make_agent(setting, AgentOptions(tie_break="first"))])
    return run_agents(mdp, params, agent_keys(seed, 1), episodes)


@pytest.mark.parametrize("learner", ["qlearning", "sarsa"])
def test_a_failure_overwrites_q_instead_of_a_td_update(learner):
    # Greedy, first index: action 0 fails at once. TD: 0.8·(−1 − 0) = −0.8; authors: −0.1.
    td = run_one(one_step_mdp(-1.0), Setting(learner, "egreedy", 0.0))
    authors = run_one(one_step_mdp(-1.0), Setting(learner, "egreedy", 0.0,
                                                  {"failure_update": "overwrite"}))
    assert td.final_state.q[0, 0, 0] == pytest.approx(-0.8)
    assert authors.final_state.q[0, 0, 0] == pytest.approx(-0.1)
    assert td.returns[0, 0] == authors.returns[0, 0] == -1.0


def test_a_goal_is_never_written_with_goal_update_skip():
    td = run_one(one_step_mdp(1.0), Setting("qlearning", "egreedy", 0.0))
    authors = run_one(one_step_mdp(1.0), Setting("qlearning", "egreedy", 0.0,
                                                 {"goal_update": "skip"}), episodes=3)
    assert td.final_state.q[0, 0, 0] == pytest.approx(0.8)
    assert authors.final_state.q[0, 0, 0] == 0.0 and authors.returns[0].tolist() == [1, 1, 1]


def test_vdbe_can_leave_epsilon_alone_on_terminal_steps():
    setting = Setting("qlearning", "vdbe", 1.0, {"epsilon_init": 0.1})
    textbook = run_one(one_step_mdp(-1.0), setting)
    authors = run_one(one_step_mdp(-1.0), Setting("qlearning", "vdbe", 1.0, {
        "epsilon_init": 0.1, "update_on_terminal": False}))
    # ΔQ = −0.8: f = (1 − e^{−0.8})/(1 + e^{−0.8}) = 0.379949; ε ← 0.1·f + 0.9·0.1.
    assert textbook.lengths[0, 0] == 1  # greedy (seed 0 does not explore): the failing step
    assert textbook.final_state.tables["epsilon"][0, 0] == pytest.approx(0.1 * 0.379949 + 0.09,
                                                                          abs=1e-6)
    assert authors.final_state.tables["epsilon"][0, 0] == pytest.approx(0.1)


def test_uniform_initial_q_per_entry_and_agent():
    mdp = make_authors_mdp(max_steps=50)
    setting = Setting("qlearning", "egreedy", 0.1, {"q_init_distribution": "uniform"})
    params = stack_agents([make_agent(setting)] * 2)
    run = run_agents(mdp, params, agent_keys(4, 2), 1)
    again = run_agents(mdp, params, agent_keys(4, 2), 1)
    q = run.final_state.q
    np.testing.assert_array_equal(q, again.final_state.q)  # a function of the key
    untouched = q[:, 40:, :]  # far from the start: not visited in one episode
    assert (untouched >= 0).all() and (untouched < 0.01).all()
    assert len(np.unique(untouched)) > untouched.size // 2  # independent entries
    assert not np.array_equal(q[0], q[1])  # and agents


def test_bad_option_values_are_one_line():
    for values, name in [({"failure_update": "maybe"}, "failure_update"),
                         ({"goal_update": 1}, "goal_update"),
                         ({"q_init_distribution": "normal"}, "q_init_distribution")]:
        with pytest.raises(ValueError, match=name):
            make_agent(Setting("sarsa", "egreedy", 0.1, values))
    with pytest.raises(ValueError, match="update_on_terminal"):
        make_agent(Setting("qlearning", "vdbe", 1.0, {"update_on_terminal": "no"}))


def test_run_grid_reports_the_longest_and_the_cut_episodes():
    grid = run_grid(make_authors_mdp(max_steps=30), [Setting("qlearning", "egreedy", 0.0,
                                                             {"tie_break": "first"})],
                    num_seeds=2, num_episodes=3)
    assert grid.meta["longest_episode"] == int(grid.lengths.max()) <= 30
    assert grid.meta["truncated_episodes"] == int((grid.lengths >= 30).sum())


def test_sarsa_can_redraw_the_action_it_takes():
    # State 0: action 0 loops (−0.01), action 1 ends with +1; greedy, first index.
    mdp = make_tabular_mdp(next_state=[[0, 1], [1, 1]], reward=[[-0.01, 1.0], [0.0, 0.0]],
                           terminal=[[False, True], [False, False]],
                           start_probability=[1.0, 0.0], max_steps=100)
    # Textbook: a' = 0 (tie, before the update) is also the action taken: it loops twice.
    executed = run_one(mdp, Setting("sarsa", "egreedy", 0.0))
    assert executed.lengths[0, 0] == 3
    # Authors: a' = 0 serves the target only (Q(0,0) = 0.8·(−0.01 + 0.9·0) = −0.008); the
    # action taken is drawn afresh from the updated row: action 1, the goal in 2 steps.
    redrawn = run_one(mdp, Setting("sarsa", "egreedy", 0.0, {"next_action": "redrawn"}))
    assert redrawn.lengths[0, 0] == 2 and redrawn.returns[0, 0] == pytest.approx(0.99)
    np.testing.assert_allclose(redrawn.final_state.q[0, 0], [-0.008, 0.8], rtol=1e-6)
    with pytest.raises(ValueError, match="next_action"):
        make_agent(Setting("sarsa", "egreedy", 0.1, {"next_action": "twice"}))


def test_reproduce_under_the_authors_reading(tmp_path):
    import vdbejax
    from vdbejax.paper.reproduce import AUTHORS_DETAILS, is_paper_grid, reading_settings, replot

    rep = vdbejax.reproduce(tmp_path, reading="authors", seeds=2, episodes=20,
                            run=RunOptions(progress=False))
    grid = rep.result
    assert grid.meta["reading"] == "authors" and grid.meta["mdp"] == "cruz2018"
    assert grid.meta["options"]["tie_break"] == "first" and grid.meta["max_steps"] == 10_000
    assert grid.settings == reading_settings("authors") and len(grid.settings) == 46
    sarsa_vdbe = grid.hyperparameters(grid.select("sarsa", "vdbe")[0])
    sarsa_softmax = grid.hyperparameters(grid.select("sarsa", "softmax")[0])
    for name, value in AUTHORS_DETAILS.items():
        values = sarsa_softmax if name == "softmax_numerics" else sarsa_vdbe
        assert values[[k for k in values if k.endswith("." + name)][0]] == value
    assert "explorer.softmax_numerics" not in sarsa_vdbe  # VDBE draws uniformly: no softmax
    assert len(rep.claims) == 6 and (tmp_path / "report.md").exists()
    assert is_paper_grid(vdbejax.GridResult.load(tmp_path))
    (tmp_path / "report.md").unlink()
    replot(tmp_path)
    assert (tmp_path / "report.md").exists()  # the authors' grid is the paper's grid too
    assert grid.meta["longest_episode"] <= 10_000
    # The cap is reported: in meta, as summary columns and in the report.
    assert grid.meta["step_cap"] is True
    header = (tmp_path / "summary.csv").read_text().splitlines()[0].split(",")
    assert header[-2:] == ["episodes_cut", "agents_cut"]
    assert (tmp_path / "fig3_authors.png").stat().st_size > 10_000  # as the authors plot it


@pytest.mark.parametrize("args, message", [
    (["--reading", "novel"], "reading='novel'"),
    (["--reading", "authors", "--invalid-action", "fail"], "invalid_action='fail'"),
])
def test_reproduce_reading_errors_are_one_line(tmp_path, args, message):
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "vdbejax", "reproduce", "--out", str(tmp_path),
                           "--seeds", "1", "--episodes", "2", "--quiet", *args],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines
    assert not (tmp_path / "returns.npz").exists()


# ------------------------------------------------------------- 8: float64 softmax numerics
def test_float64_softmax_draw_by_hand():
    import jax.numpy as jnp

    from vdbejax.methods.selection import float64_softmax_draw

    stable = jnp.array([2, 2, 2, 1], jnp.int32)
    q = jnp.array([
        [-0.08, -0.09, -0.10],  # every Q/τ < −745: all weights 0, 0/0 = NaN → action 0
        [-0.08, 0.00, 0.20],    # 0.2/τ = 2000 > 709.8: inf/inf = NaN, the first such → 2
        [0.05, 0.08, 0.09],     # 800 and 900 overflow: the *first* one wins (1), not the max
        [-0.01, 0.0, -0.02],    # a proper distribution: the stable draw stands
    ]).T
    np.testing.assert_array_equal(float64_softmax_draw(q, 1e-4, stable), [0, 2, 1, 1])


def test_float64_softmax_loops_a_state_that_the_stable_one_leaves():
    # State 0: action 0 loops (−0.01), action 1 reaches the goal (+1). With every Q at −0.5
    # and τ = 1e-4, the authors' weights all vanish, the draw is always action 0, and
    # Q(0, 0) climbs only to −0.1 (< −0.0745): the episode never ends but at the cap.
    mdp = make_tabular_mdp(np.array([[0, 0]]), np.array([[-0.01, 1.0]], np.float32),
                           np.array([[False, True]]), np.array([1.0]), max_steps=60)
    settings = [Setting("qlearning", "softmax", 1e-4, {"softmax_numerics": numerics})
                for numerics in ("float64", "stable")]
    grid = run_grid(mdp, settings, num_seeds=3, num_episodes=20,
                    options=AgentOptions(q_init=-0.5))
    assert (grid.lengths[0] == 60).all()  # every episode cut at the cap
    # The stable draw is uniform at first: agents whose first action is the goal keep
    # taking it (one whose first action is the loop is trapped there: Q(0,0) > Q(0,1)).
    stable = grid.lengths[1]
    assert (stable[:, 0] == 1).any() and ((stable == 1).all(axis=1) | (stable == 60).all(axis=1)).all()
    assert grid.meta["truncated_episodes_by_config"][0] == 60
