"""The benchmark harness's peers: multi-threaded Numba, MushroomRL, and the report rows.

numba and mushroom-rl belong to the ``benchmarks`` extra; without them these tests skip.
Small sizes only (a few seeds × tens of episodes).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


# --------------------------------------------------------------------------- Numba
@pytest.fixture(scope="module")
def numba_loop():
    pytest.importorskip("numba")
    from benchmarks import numba_loop

    return numba_loop


@pytest.fixture(scope="module")
def small_settings():
    from vdbejax.methods.agents import paper_settings

    settings = paper_settings()
    # one of each learner × explorer (8 kinds), so every branch of the step runs
    seen, picked = set(), []
    for s in settings:
        if (s.learner, s.explorer) not in seen:
            seen.add((s.learner, s.explorer))
            picked.append(s)
    return picked


def test_interleaved_order_is_a_permutation_mixing_the_agents(numba_loop):
    order = numba_loop.interleaved_order(10, 3)
    assert sorted(order.tolist()) == list(range(10))
    assert order.tolist() == [0, 3, 6, 9, 1, 4, 7, 2, 5, 8]
    assert numba_loop.interleaved_order(5, 1).tolist() == list(range(5))


def test_prange_loop_is_deterministic_across_thread_counts(numba_loop, small_settings):
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("Numba has fewer than 2 threads here (NUMBA_NUM_THREADS)")
    seeds, episodes = [0, 1, 2], 60
    r1, l1 = numba_loop.run_grid_parallel(small_settings, seeds, episodes, threads=1)
    r2, l2 = numba_loop.run_grid_parallel(small_settings, seeds, episodes, threads=2)
    np.testing.assert_array_equal(r1, r2)
    np.testing.assert_array_equal(l1, l2)
    again, _ = numba_loop.run_grid_parallel(small_settings, seeds, episodes, threads=2)
    np.testing.assert_array_equal(r2, again)
    assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS  # restored


def test_prange_loop_returns_the_one_thread_loops_curves(numba_loop, small_settings):
    """Same per-agent function and per-agent streams: identical, not merely alike."""
    seeds, episodes = [3, 4], 80
    r, l = numba_loop.run_grid(small_settings, seeds, episodes)
    rp, lp = numba_loop.run_grid_parallel(small_settings, seeds, episodes, threads=1)
    np.testing.assert_array_equal(r, rp)
    np.testing.assert_array_equal(l, lp)
    assert r.shape == (len(small_settings) * len(seeds), episodes)
    assert (l >= 1).all() and (l <= 100).all()
    # different seeds are different streams
    assert not np.array_equal(r[0], r[1])


def test_prange_loop_rejects_more_threads_than_numba_has(numba_loop, small_settings):
    import numba

    with pytest.raises(ValueError, match="NUMBA_NUM_THREADS"):
        numba_loop.run_grid_parallel(small_settings[:1], [0], 1,
                                     threads=numba.config.NUMBA_NUM_THREADS + 1)


# --------------------------------------------------------------------------- MushroomRL
@pytest.fixture(scope="module")
def mushroom():
    pytest.importorskip("mushroom_rl")
    from benchmarks import mushroom_loop

    return mushroom_loop


@pytest.fixture(scope="module")
def mdp():
    from vdbejax.envs.table_cleaning import make_mdp

    return make_mdp()


def test_finite_mdp_reproduces_the_transition_table(mushroom, mdp):
    env = mushroom.make_environment(mdp)
    next_state = np.asarray(mdp.next_state)[..., 0]
    reward = np.asarray(mdp.reward)[..., 0]
    terminal = np.asarray(mdp.terminal)[..., 0]
    num_states, num_actions = next_state.shape
    assert env.info.observation_space.n == 2 * num_states
    assert env.info.action_space.n == num_actions
    for s in range(num_states):
        for a in range(num_actions):
            env.reset(np.array([s]))
            s2, r, absorbing, _ = env.step(np.array([a]))
            assert s2[0] % num_states == next_state[s, a], (s, a)
            assert bool(absorbing) == bool(terminal[s, a]), (s, a)
            assert (s2[0] >= num_states) == bool(terminal[s, a]), (s, a)
            assert r == reward[s, a], (s, a)
    assert terminal.any() and not terminal.all()
    # the start distribution: vdbejax's, none on the absorbing copies
    np.testing.assert_allclose(env.mu[:num_states], np.asarray(mdp.start_probability))
    assert env.mu[num_states:].sum() == 0
    for _ in range(20):
        assert np.asarray(mdp.start_probability)[env.reset()[0]] > 0


def test_core_truncates_at_max_steps_and_bootstraps(mushroom, mdp):
    """An agent that never ends an episode: 100 steps each, last step not absorbing."""
    from mushroom_rl.core import Core
    from mushroom_rl.policy import EpsGreedy

    go_home = 4  # a move: never terminal, reward -0.01

    class AlwaysHome(EpsGreedy):
        def draw_action(self, state):
            return np.array([go_home])

    env = mushroom.make_environment(mdp)
    assert env.info.horizon == int(mdp.max_steps) == 100
    agent = mushroom.make_agent(env, "sarsa", "egreedy", 0.1)
    agent.policy = AlwaysHome(epsilon=0.0)
    agent.policy.set_q(agent.Q)
    record, flags = mushroom.EpisodeReturns(), []
    core = Core(agent, env, callback_step=lambda samples: (record(samples), flags.extend(
        (bool(x[4]), bool(x[5])) for x in samples)))
    core.learn(n_episodes=3, n_steps_per_fit=1, quiet=True)
    assert record.lengths == [100, 100, 100]
    np.testing.assert_allclose(record.returns, 100 * np.float32(-0.01), rtol=1e-6)
    assert flags[99] == (False, True) and flags[98] == (False, False)
    assert not any(absorbing for absorbing, _ in flags)
    # every SARSA update bootstrapped on Q(s', GO_HOME) (GO_HOME at home stays in s, none
    # absorbing, the truncated last steps included): Q(start, GO_HOME) → -0.01 / (1 - 0.9)
    start = np.flatnonzero(np.asarray(mdp.start_probability))
    visited = agent.Q.table[start, go_home]
    assert (visited < -0.09).any() and (visited > -0.1 - 1e-6).all(), visited


def test_agents_map_the_explorers_and_learners(mushroom, mdp):
    from mushroom_rl.algorithms.value import SARSA, QLearning
    from mushroom_rl.policy import Boltzmann, EpsGreedy

    env = mushroom.make_environment(mdp)
    a = mushroom.make_agent(env, "qlearning", "softmax", 0.01)
    assert isinstance(a, QLearning) and isinstance(a.policy, Boltzmann)
    assert a.policy._beta.get_value() == pytest.approx(100.0)  # β = 1/τ
    assert a._alpha.get_value() == pytest.approx(0.8)
    assert env.info.gamma == pytest.approx(0.9)
    b = mushroom.make_agent(env, "sarsa", "egreedy", 0.05)
    assert isinstance(b, SARSA) and isinstance(b.policy, EpsGreedy)
    assert b.policy._epsilon.get_value() == pytest.approx(0.05)
    with pytest.raises(ValueError, match="vdbe"):
        mushroom.make_agent(env, "qlearning", "vdbe", 1.0)
    # Boltzmann(1/τ) gives vdbejax's softmax probabilities exp((q - max q) / τ), normalised
    q = np.array([0.1, -0.2, 0.3, 0.3, 0.0, -1.0, 0.05])
    a.Q.table[5] = q
    tau = 0.01
    want = np.exp((q - q.max()) / tau)
    np.testing.assert_allclose(a.policy(np.array([5])), want / want.sum(), rtol=1e-9)
    from vdbejax.methods.agents import paper_settings

    cov = mushroom.covered(paper_settings())
    assert len(cov) == 22 and {s.explorer for s in cov} == {"egreedy", "softmax"}


def test_train_agent_is_seeded_and_records_every_episode(mushroom, mdp):
    env = mushroom.make_environment(mdp)
    r1, l1 = mushroom.train_agent("sarsa", "softmax", 1.0, 5, 30, env=env)
    r2, l2 = mushroom.train_agent("sarsa", "softmax", 1.0, 5, 30, env=env)
    assert r1 == r2 and l1 == l2 and len(r1) == 30
    assert all(1 <= n <= 100 for n in l1)
    # every return is a sum of this task's rewards: -0.01 per non-final step, ±1 at the end
    for ret, n in zip(r1, l1):
        assert any(abs(ret - ((n - 1) * np.float32(-0.01) + end)) < 1e-4
                   for end in (np.float32(-0.01), 1.0, -1.0))


# --------------------------------------------------------------------------- harness
@pytest.mark.benchmark  # minutes of every peer: left out by .ci/run (README: the two commands)
def test_harness_end_to_end_writes_every_peer_row(tmp_path):
    pytest.importorskip("numba")
    pytest.importorskip("mushroom_rl")
    out = tmp_path / "RESULTS.md"
    out.write_text("# old\n\n## Analysis\n\nhand-written text kept\n")
    cmd = [sys.executable, "-m", "benchmarks.compare", "--out", str(out),
           "--tmp", str(tmp_path / "work"), "--episodes", "20", "--seeds", "2",
           "--python-seeds", "1", "--mushroom-seeds", "1", "--scaling", "",
           "--skip-lockstep", "--threads", "2", "--warm-runs", "2"]
    subprocess.run(cmd, check=True, cwd=ROOT, capture_output=True)
    text = out.read_text()
    assert text.count("median of 2 warm runs (") == 3  # vdbejax, numba-2t, numba-1t
    for row in ("| vdbejax sequential (warm JAX cache) | 2 |", "| numba-2t (warm cache=True) | 2 |",
                "| numba-2t (cold) | 2 |", "| numba-1t (warm cache=True) | 1 |",
                "| mushroom (22 agents measured) | 1 |",
                "| mushroom (extrapolated to the grid) | 1 |",
                "| python (46 agents measured) | 1 |", "| python (extrapolated to the grid) | 1 |"):
        assert row in text, row
    assert "fastest peer on the same cores" in text
    assert "Returns of numba-2t and numba-1t bit-identical: True" in text
    assert "MushroomRL (`mushroom`) measured: 22 of the 46 settings" in text
    assert text.rstrip().endswith("hand-written text kept")  # the Analysis section is kept
    assert text.count("## Analysis") == 1
    assert "\n- Commit: `" in text and "<details>" not in text
    # each setting's differences on the page beside it, under the same header lines
    agreement = (tmp_path / "AGREEMENT.md").read_text()
    assert "| qlearning/egreedy/epsilon=0.01 |" in agreement and "- Commit: `" in agreement
    assert "[`AGREEMENT.md`](AGREEMENT.md)" in text


@pytest.mark.parametrize("flag, value", [("--warm-runs", "0"), ("--scaling", "10,0"),
                                         ("--scaling", "ten")])
def test_harness_bad_counts_are_one_line_errors_before_any_run(tmp_path, flag, value):
    done = subprocess.run([sys.executable, "-m", "benchmarks.compare", "--out",
                           str(tmp_path / "R.md"), "--tmp", str(tmp_path / "work"), flag, value],
                          cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert f"{flag}=" in done.stderr and "is invalid" in done.stderr
    assert "Traceback" not in done.stderr
    assert not (tmp_path / "R.md").exists()
