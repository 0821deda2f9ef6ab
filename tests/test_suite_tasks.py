"""The task suite (vdbejax.envs.suite): each task as published, its exact optimum against
the published number or a property derived from the published definition, and the
registry's names."""
from __future__ import annotations

import dataclasses
import sys
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from vdbejax.envs import solvers
from vdbejax.envs.cruz2018 import STEP_CAP, make_authors_mdp
from vdbejax.envs.suite import (
    DEFAULT_SUITE,
    NAMES,
    TaskInfo,
    make_suite_task,
    suite_tasks,
    task_info,
)
from vdbejax.envs.suite.chain import chain_model, make_chain
from vdbejax.envs.suite.deep_sea import action_mapping, make_deep_sea
from vdbejax.envs.suite.gridworlds import make_cliff_walking, make_windy_gridworld
from vdbejax.envs.suite.river_swim import (
    make_river_swim,
    make_river_swim_normalised,
    make_six_arms,
    river_swim_model,
)
from vdbejax.envs.table_cleaning import make_mdp, make_variant_mdp

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

FIELDS = ("next_state", "probability", "reward", "terminal", "start_probability",
          "max_steps")
#: Registry names beyond the default suite (sizes, aliases).
EXTRA_NAMES = ("riverswim:8", "riverswim_normalised:12", "chain:8", "deepsea", "deepsea:5")


GYM_TASKS = {"frozenlake4", "frozenlake8", "taxi"}


class _Built(dict):
    """The tasks built once; a gymnasium task without gymnasium skips its test."""

    def __missing__(self, name: str):
        pytest.importorskip("gymnasium")
        raise KeyError(name)


@pytest.fixture(scope="module")
def built():
    """Every registry task of the tests, built once (the gymnasium ones if installed)."""
    try:
        import gymnasium  # noqa: F401
        names = DEFAULT_SUITE + EXTRA_NAMES
    except ImportError:
        names = tuple(n for n in DEFAULT_SUITE + EXTRA_NAMES if n not in GYM_TASKS)
    return _Built({name: make_suite_task(name) for name in names})


def _dense(mdp) -> tuple[np.ndarray, np.ndarray]:
    """``(P [S, A, S'], expected reward [S, A])`` of an MDP's outcome tables."""
    S, A = mdp.num_states, mdp.num_actions
    P = np.zeros((S, A, S))
    probability = np.asarray(mdp.probability, np.float64)
    next_state = np.asarray(mdp.next_state)
    for k in range(mdp.num_outcomes):
        np.add.at(P, (np.arange(S)[:, None], np.arange(A)[None, :], next_state[..., k]),
                  probability[..., k])
    return P, (probability * np.asarray(mdp.reward, np.float64)).sum(-1)


def _finite_horizon_best(P, R, start, horizon) -> float:
    """Optimal expected undiscounted return by backward induction on dense arrays (an
    implementation independent of vdbejax.envs.solvers; continuing tasks only)."""
    expected = R if R.ndim == 2 else (P * R).sum(-1)
    V = np.zeros(P.shape[0])
    for _ in range(horizon):
        V = (expected + P @ V).max(axis=1)
    return float(start @ V)


def _one_line_error(call, match: str) -> None:
    with pytest.raises(ValueError, match=match) as caught:
        call()
    assert "\n" not in str(caught.value)


# ------------------------------------------------------------------ every task
@pytest.mark.parametrize("name", DEFAULT_SUITE + EXTRA_NAMES)
def test_every_task_builds_with_valid_tables_and_its_horizon(built, name):
    mdp = built[name]
    info = task_info(name)
    assert int(mdp.max_steps) == info.horizon
    assert mdp.name == (name if not name.startswith("variant:") else "table_cleaning_n3_k1")
    probability = np.asarray(mdp.probability, np.float64)
    assert np.all(probability >= 0) and np.allclose(probability.sum(-1), 1.0, atol=1e-6)
    next_state = np.asarray(mdp.next_state)
    assert next_state.min() >= 0 and next_state.max() < mdp.num_states
    assert np.isclose(np.asarray(mdp.start_probability, np.float64).sum(), 1.0)
    assert np.all(np.isfinite(np.asarray(mdp.reward)))
    assert solvers.reachable_states(mdp).size >= 1


def test_the_sizes_of_the_default_suite(built):
    """(S, A, K) of every default task, as its source defines it."""
    pytest.importorskip("gymnasium")
    sizes = {name: (m.num_states, m.num_actions, m.num_outcomes) for name, m in built.items()}
    assert sizes["riverswim"] == sizes["riverswim_normalised"] == (6, 2, 3)
    assert sizes["sixarms"] == (7, 6, 2)
    assert sizes["chain"] == (5, 2, 2)
    assert sizes["deepsea:10"] == (100, 2, 1)
    assert sizes["windy_gridworld"] == (70, 4, 1)
    assert sizes["cliff_walking"] == (48, 4, 1)
    assert sizes["frozenlake4"] == (16, 4, 3) and sizes["frozenlake8"] == (64, 4, 3)
    assert sizes["taxi"] == (500, 6, 1)
    assert sizes["table_cleaning"] == (108, 7, 1) and sizes["cruz2018"] == (53, 7, 1)


# ------------------------------------------------------------------ RiverSwim, SixArms
def test_river_swim_is_strehl_and_littmans_figure():
    """Strehl & Littman 2008, the RiverSwim figure: right moves on with 0.3, stays with 0.6,
    drifts back with 0.1 (banks: 0.3 on / 0.7 stay; 0.3 stay paying 10000 / 0.7 back);
    left is sure and pays 5 at the left bank; start in state 1 or 2."""
    R, P = river_swim_model()
    right = np.array([[0.7, 0.3, 0, 0, 0, 0], [0.1, 0.6, 0.3, 0, 0, 0],
                      [0, 0.1, 0.6, 0.3, 0, 0], [0, 0, 0.1, 0.6, 0.3, 0],
                      [0, 0, 0, 0.1, 0.6, 0.3], [0, 0, 0, 0, 0.7, 0.3]])
    left = np.eye(6)[[0, 0, 1, 2, 3, 4]]
    np.testing.assert_array_equal(P[:, 1], right)
    np.testing.assert_array_equal(P[:, 0], left)
    assert R[0, 0, 0] == 5 and R[5, 1, 5] == 10000 and np.count_nonzero(R) == 2
    mdp = make_river_swim()
    np.testing.assert_array_equal(np.asarray(mdp.start_probability), [0, .5, .5, 0, 0, 0])
    assert mdp.num_outcomes == 3 and not np.asarray(mdp.terminal).any()


def test_river_swim_optimum_swims_right_and_matches_backward_induction():
    """The published property: the optimal policy swims right (upstream) in every state;
    its 20-step return, by an independent backward induction, dwarfs staying left."""
    R, P = river_swim_model()
    mdp = make_river_swim()
    start = np.asarray(mdp.start_probability, np.float64)
    best = solvers.best_return(mdp)
    assert best == pytest.approx(_finite_horizon_best(P, R, start, 20), rel=1e-5)
    assert best == pytest.approx(6511.5, abs=0.1)
    q = solvers.optimal_q_values(mdp, 1.0, 20)
    np.testing.assert_array_equal(q.argmax(axis=1), np.ones(6))
    assert solvers.policy_return(mdp, np.zeros(6, np.int64)) == pytest.approx(92.5)


def test_benchmark_river_swim_is_the_normalised_form_bit_for_bit():
    """benchmarks/rlberry_ucbvi.py's RiverSwim (Osband, Russo & Van Roy 2013, rlberry's
    layout) is the suite's, with the values it always had."""
    from benchmarks.rlberry_ucbvi import river_swim

    R, P = river_swim()
    expected_right = np.array([[0.6, 0.4, 0, 0, 0, 0], [0.05, 0.6, 0.35, 0, 0, 0],
                               [0, 0.05, 0.6, 0.35, 0, 0], [0, 0, 0.05, 0.6, 0.35, 0],
                               [0, 0, 0, 0.05, 0.6, 0.35], [0, 0, 0, 0, 0.4, 0.6]])
    assert R.dtype == P.dtype == np.float64 and R.shape == (6, 2) and P.shape == (6, 2, 6)
    assert np.array_equal(P[:, 1], expected_right) and np.array_equal(
        P[:, 0], np.eye(6)[[0, 0, 1, 2, 3, 4]])
    expected_R = np.zeros((6, 2))
    expected_R[0, 0], expected_R[5, 1] = 0.005, 1.0
    assert R.tobytes() == expected_R.tobytes()
    # the registry's MDP is the same model, starting at the left bank
    mdp = make_river_swim_normalised()
    dense_P, expected = _dense(mdp)
    np.testing.assert_allclose(dense_P, P, atol=1e-7)
    np.testing.assert_allclose(expected, R, atol=1e-7)
    np.testing.assert_array_equal(np.asarray(mdp.start_probability), np.eye(6)[0])
    best = solvers.best_return(mdp)
    assert best == pytest.approx(_finite_horizon_best(P, R, np.eye(6)[0], 20), rel=1e-5)
    np.testing.assert_array_equal(solvers.optimal_q_values(mdp, 1.0, 20).argmax(1), 1)


def test_six_arms_is_published_and_its_optimum_tries_for_room_six():
    """Strehl & Littman 2008's SixArms: entry probabilities 1, .15, .1, .05, .03, .01 and
    rewards 50, 133, 300, 800, 1660, 6000. Over 200 steps the optimal policy tries arm 6
    from the centre, leaves rooms 1-5 for it and stays in room 6; trying arm 6 until in,
    then staying, returns 6000 (H - (1 - 0.99^H) / 0.01) exactly."""
    mdp = make_six_arms()
    P, expected = _dense(mdp)
    np.testing.assert_allclose(P[0, np.arange(6), np.arange(1, 7)],
                               [1, .15, .1, .05, .03, .01], atol=1e-7)
    stays = [expected[1, a] for a in (0, 1, 2, 3, 5)]
    assert stays == [50] * 5 and P[1, 4, 0] == 1
    np.testing.assert_array_equal(expected[np.arange(2, 7), np.arange(1, 6)],
                                  [133, 300, 800, 1660, 6000])
    q = solvers.optimal_q_values(mdp, 1.0, 200)
    policy = q.argmax(1)
    assert policy[0] == 5 and policy[6] == 5
    np.testing.assert_array_equal(P[np.arange(1, 6), policy[1:6], 0], 1.0)  # back to try
    horizon = 200
    try_room_six = np.array([5, 0, 1, 2, 3, 4, 5])
    closed_form = 6000 * (horizon - (1 - 0.99**horizon) / 0.01)
    assert solvers.policy_return(mdp, try_room_six) == pytest.approx(closed_form, rel=1e-5)
    best = solvers.best_return(mdp)
    assert closed_form <= best * (1 + 1e-6)
    assert best == pytest.approx(_finite_horizon_best(P, expected, np.eye(7)[0], 200),
                                 rel=1e-5)


# ------------------------------------------------------------------ the chain
def test_chain_is_dearden_et_als():
    """Dearden, Friedman & Russell 1998: forward (a) pays 0 and 10 at the end, back (b)
    returns to the start paying 2, each with a 0.2 slip to the other action."""
    P, expected = _dense(make_chain())
    for s in range(5):
        ahead = min(s + 1, 4)
        assert P[s, 0, ahead] == pytest.approx(0.8) and P[s, 0, 0] == pytest.approx(0.2)
        assert P[s, 1, 0] == pytest.approx(0.8) and P[s, 1, ahead] == pytest.approx(0.2)
    np.testing.assert_allclose(expected[:4, 0], 0.4)  # the slip back pays 2
    assert expected[4, 0] == pytest.approx(0.8 * 10 + 0.2 * 2)
    np.testing.assert_allclose(expected[:4, 1], 1.6)
    assert make_chain(slip=0.0).num_outcomes == 1


def test_chain_long_run_rate_and_depth_threshold():
    """Going forward everywhere earns 2 slip + 10 (1 - slip)^n a step in the long run
    (3.6768: 3677 per 1000 steps); the optimal policy goes forward from the start for
    n <= 8 and back for longer chains."""
    R, P = chain_model()
    forward_P = P[:, 0]
    stationary = np.linalg.matrix_power(forward_P, 200)[0]  # the chain mixes fast
    np.testing.assert_allclose(stationary, [0.2, 0.16, 0.128, 0.1024, 0.4096], atol=1e-12)
    assert stationary @ (forward_P * R[:, 0]).sum(-1) == pytest.approx(3.6768, abs=1e-12)
    mdp = make_chain()
    forward = np.zeros(5, np.int64)
    rate = (solvers.policy_values(mdp, forward, horizon=3000)[0]
            - solvers.policy_values(mdp, forward, horizon=2000)[0]) / 1000
    assert rate == pytest.approx(3.6768, rel=1e-4)  # float32 probabilities
    assert solvers.best_return(mdp) == pytest.approx(3665.86, abs=0.01)
    first = {n: solvers.optimal_q_values(make_chain(n), 1.0, 1000)[0].argmax()
             for n in (4, 8, 9, 16)}
    assert first == {4: 0, 8: 0, 9: 1, 16: 1}


def test_chain_rejects_bad_parameters():
    _one_line_error(lambda: make_chain(1), r"num_states=1 is invalid: must be an integer >= 2")
    _one_line_error(lambda: make_chain(2.5), r"num_states=2.5 is invalid")
    _one_line_error(lambda: make_chain(5, 1.5), r"slip=1.5 is invalid: must be in \[0, 1\]")
    _one_line_error(lambda: make_suite_task("chain:1"), r"num_states=1 is invalid")


# ------------------------------------------------------------------ DeepSea
@pytest.mark.parametrize("size", [1, 5, 10, 20])
def test_deep_sea_optimum_and_random_policy(size):
    """bsuite's ``_optimal_return`` = 1 - unscaled_move_cost = 0.99; the uniformly random
    policy finds the treasure only by N right moves in a row, probability 2^-N (without
    the move cost its expected return is exactly that; with it, 2^-N - 0.005)."""
    mdp = make_deep_sea(size)
    assert solvers.best_return(mdp) == pytest.approx(0.99, abs=1e-6)
    assert solvers.uniform_random_return(mdp) == pytest.approx(2.0**-size - 0.005, abs=1e-7)
    free = make_deep_sea(size, unscaled_move_cost=0.0)
    assert solvers.uniform_random_return(free) == pytest.approx(2.0**-size, rel=1e-6)
    terminal = np.asarray(mdp.terminal)[..., 0]
    rows = np.arange(size * size) // size
    np.testing.assert_array_equal(terminal, np.broadcast_to((rows == size - 1)[:, None],
                                                            (size * size, 2)))


def test_deep_sea_action_mapping_is_bsuites_and_deterministic_given_the_seed():
    """bsuite draws ``RandomState(mapping_seed).binomial(1, 0.5, [N, N])`` and action
    ``mapping[row, column]`` is right; the optimal path follows the diagonal's mapping."""
    expected = np.random.RandomState(42).binomial(1, 0.5, [10, 10])
    np.testing.assert_array_equal(action_mapping(10), expected)
    mdp = make_deep_sea(10)
    path = solvers.shortest_solution(mdp, 0)
    np.testing.assert_array_equal(path, np.diag(expected))
    again, other = make_deep_sea(10), make_deep_sea(10, seed=7)
    for field in ("next_state", "reward"):
        assert np.array_equal(np.asarray(getattr(mdp, field)), np.asarray(getattr(again, field)))
    assert not np.array_equal(np.asarray(mdp.next_state), np.asarray(other.next_state))
    plain = make_deep_sea(10, randomize_actions=False)
    assert solvers.shortest_solution(plain, 0) == [1] * 10
    assert int(mdp.max_steps) == 10 and mdp.name == "deepsea:10"


def test_deep_sea_rejects_bad_parameters():
    _one_line_error(lambda: make_deep_sea(0), r"size=0 is invalid: must be an integer >= 1")
    _one_line_error(lambda: make_deep_sea(4, seed=-1), r"seed=-1 is invalid")
    _one_line_error(lambda: make_deep_sea(4, randomize_actions="yes"),
                    r"randomize_actions='yes' is invalid: must be True or False")
    _one_line_error(lambda: make_deep_sea(4, unscaled_move_cost=float("nan")),
                    r"unscaled_move_cost=nan is invalid")
    _one_line_error(lambda: make_suite_task("deepsea:0"), r"size=0 is invalid")


# ------------------------------------------------------------------ Sutton & Barto
def _greedy_episode(mdp, horizon: int = 100) -> list[float]:
    """The rewards of following the optimal policy from the start (deterministic)."""
    q = solvers.optimal_q_values(mdp, 1.0, horizon)
    s, rewards = int(solvers.start_states(mdp)[0]), []
    for _ in range(horizon):
        a = int(q[s].argmax())
        rewards.append(float(np.asarray(mdp.reward)[s, a, 0]))
        if np.asarray(mdp.terminal)[s, a, 0]:
            return rewards
        s = int(np.asarray(mdp.next_state)[s, a, 0])
    raise AssertionError("the optimal policy never reached the goal")


def test_windy_gridworld_optimal_episode_takes_15_steps():
    """Sutton & Barto 2018, Example 6.5: the shortest episode is 15 steps (return -15)."""
    mdp = make_windy_gridworld()
    assert solvers.best_return(mdp) == -15
    assert _greedy_episode(mdp) == [-1.0] * 15
    # the wind of column 6 (strength 2) lifts a rightward move from (3, 6) to (1, 7)
    assert int(np.asarray(mdp.next_state)[3 * 10 + 6, 1, 0]) == 1 * 10 + 7


def test_cliff_walking_optimum_is_minus_13_and_the_cliff_sends_back():
    """Sutton & Barto 2018, Example 6.6: the optimal path along the edge, 13 steps (return
    -13); stepping into the cliff costs 100 and returns to the start."""
    mdp = make_cliff_walking()
    assert solvers.best_return(mdp) == -13
    assert _greedy_episode(mdp) == [-1.0] * 13
    start = 36
    assert int(np.asarray(mdp.next_state)[start, 1, 0]) == start
    assert float(np.asarray(mdp.reward)[start, 1, 0]) == -100
    assert not np.asarray(mdp.terminal)[start, 1, 0]


def test_cliff_walking_equals_gymnasiums_tables():
    pytest.importorskip("gymnasium")
    from vdbejax.envs.gymnasium_adapter import from_gymnasium

    theirs = from_gymnasium("CliffWalking-v1", max_steps=10_000, name="cliff_walking")
    ours = make_cliff_walking()
    for field in FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(ours, field)),
                                      np.asarray(getattr(theirs, field)))


# ------------------------------------------------------------------ gymnasium toy text
def test_frozen_lake_optima_are_gymnasiums_stated_ones(built):
    """gymnasium's registry: FrozenLake-v1 (100 steps) "optimum = 0.74",
    FrozenLake8x8-v1 (200 steps) "optimum = 0.91"."""
    pytest.importorskip("gymnasium")
    assert solvers.best_return(built["frozenlake4"]) == pytest.approx(0.74, abs=0.005)
    assert solvers.best_return(built["frozenlake8"]) == pytest.approx(0.91, abs=0.005)


def test_taxi_optimum_is_the_mean_shortest_delivery(built):
    """Taxi pays -1 a step and +20 for the delivery, so the optimum from a start state is
    21 minus its shortest delivery: the mean over the 300 start states by a breadth-first
    search over gymnasium's own model P equals the solver's (7.93). gymnasium's registry
    comment states 8.46 for Taxi; the current map and start distribution give 7.93."""
    gymnasium = pytest.importorskip("gymnasium")

    env_id = "Taxi-v4" if "Taxi-v4" in gymnasium.envs.registry else "Taxi-v3"
    base = gymnasium.make(env_id).unwrapped
    starts = np.flatnonzero(base.initial_state_distrib)
    assert len(starts) == 300

    def shortest(start: int) -> int:
        seen, queue = {start: 0}, deque([start])
        while queue:
            s = queue.popleft()
            for a in range(6):
                ((_, nxt, reward, done),) = base.P[s][a]
                if done and reward == 20:
                    return seen[s] + 1
                if not done and nxt not in seen:
                    seen[nxt] = seen[s] + 1
                    queue.append(nxt)
        raise AssertionError("no delivery")

    mean = np.mean([21 - shortest(int(s)) for s in starts])
    assert solvers.best_return(built["taxi"]) == pytest.approx(mean, abs=1e-5)
    assert mean == pytest.approx(7.93, abs=1e-9)


def test_toy_text_without_gymnasium_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnasium", None)  # import gymnasium -> ImportError
    for name in ("frozenlake4", "taxi"):
        with pytest.raises(ImportError, match=r"pip install 'vdbejax\[gym\]'") as caught:
            make_suite_task(name)
        assert "\n" not in str(caught.value)


# ------------------------------------------------------------------ the registry
def test_table_cleaning_entries_are_the_existing_builders_mdps(built):
    """The registry's table-cleaning family is what vdbejax.studies.task_names.make_task has
    always built: the same arrays, horizons and names."""
    for name, theirs in (("table_cleaning", make_mdp()),
                         ("cruz2018", make_authors_mdp(STEP_CAP)),
                         ("variant:3x1", make_variant_mdp(3, 1))):
        ours = built[name]
        assert ours.name == theirs.name
        for field in (*FIELDS, "state_codes"):
            a, b = getattr(ours, field), getattr(theirs, field)
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    fail = make_suite_task("table_cleaning", invalid_action="fail", max_steps=50)
    reference = make_mdp(max_steps=50, invalid_action="fail")
    np.testing.assert_array_equal(np.asarray(fail.next_state), np.asarray(reference.next_state))
    assert int(fail.max_steps) == 50


def test_sweep_files_take_every_task_of_the_suite():
    """task_names.make_task (a sweep file's task key, vdbejax run --task) is the registry:
    suite names build there, and its errors name the parameter task."""
    from vdbejax.studies.task_names import make_task

    for name in ("deepsea:6", "chain:7", "cliff_walking"):
        ours, theirs = make_task(name), make_suite_task(name)
        assert ours.name == theirs.name == name
        np.testing.assert_array_equal(np.asarray(ours.next_state), np.asarray(theirs.next_state))
    assert int(make_task("riverswim", max_steps=30).max_steps) == 30
    with pytest.raises(ValueError, match=r"^task='nope' is invalid") as caught:
        make_task("nope")
    assert "\n" not in str(caught.value)
    with pytest.raises(ValueError, match=r"invalid_action='fail' is invalid with task='chain'"):
        make_task("chain", invalid_action="fail")


def test_registry_names_round_trip():
    tasks = suite_tasks()
    assert tuple(tasks) == DEFAULT_SUITE
    for name, info in tasks.items():
        assert isinstance(info, TaskInfo) and info.name == name
        assert info.title and info.source and info.tests and info.horizon_reason
        assert task_info(name) == info
    assert task_info("frozenlake8").extra == "gym" and task_info("chain").extra is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        tasks["chain"].horizon = 3  # type: ignore[misc]
    assert task_info("deepsea:20").horizon == 20
    assert make_suite_task("chain:7").name == "chain:7"
    assert int(make_suite_task("sixarms", max_steps=30).max_steps) == 30


@pytest.mark.parametrize("name", ["nope", "chain:05", "chain:x", "chain:", "deepsea:-3",
                                  "variant", "variant:3", "variant:3x", "frozenlake",
                                  "sixarms:2", "taxi:1", "", 7])
def test_unknown_names_are_one_line_errors_listing_the_allowed(name):
    _one_line_error(lambda: make_suite_task(name), r"is invalid: must be one of riverswim,")
    _one_line_error(lambda: task_info(name), r"variant:NxK")


def test_invalid_action_only_for_the_table_cleaning_tasks():
    _one_line_error(lambda: make_suite_task("chain", invalid_action="fail"),
                    r"invalid_action='fail' is invalid with name='chain'")
    _one_line_error(lambda: make_suite_task("cruz2018", invalid_action="fail"),
                    r"invalid_action='fail' is invalid with name='cruz2018'")
    _one_line_error(lambda: make_suite_task("sixarms", max_steps=0), r"max_steps=0 is invalid")
    assert set(NAMES) >= set(DEFAULT_SUITE) - {"deepsea:10", "variant:3x1"}


# ------------------------------------------------------------------ learner defaults by task
def test_a_suite_task_gets_the_benchmarks_rule_and_the_paper_tasks_keep_the_papers(
        tmp_path, capsys):
    from vdbejax import cli
    from vdbejax.methods.agents import AgentOptions, Setting
    from vdbejax.results import io
    from vdbejax.runs import RunOptions, prepare_grid
    from vdbejax.studies.catalog import catalog
    from vdbejax.studies.sweep_file import read_sweep_file, sweep_from_meta
    from vdbejax.studies.sweeps import Sweep, run_sweep

    quiet = RunOptions(progress=False)
    sweep = Sweep(learners=["qlearning", "ucbvi"], explorers=["egreedy"])
    result = run_sweep(tmp_path / "river", sweep, task="riverswim", seeds=2, episodes=3,
                       figures=False, run=quiet)
    horizon = int(make_suite_task("riverswim").max_steps)
    assert result.meta["learner_defaults"] == {
        "rule": "benchmark", "alpha": 0.1, "gamma": 1 - 1 / horizon,
        "finite_horizon": {"gamma": 1.0, "horizon": horizon}}
    q, ucbvi = result.meta["hyperparameters"]
    assert (q["learner.alpha"], q["learner.gamma"]) == (0.1, 1 - 1 / horizon)
    assert (ucbvi["learner.gamma"], ucbvi["learner.horizon"]) == (1.0, horizon)
    # a setting's own values take precedence
    own = run_sweep(tmp_path / "own", Sweep(learners=["qlearning"], explorers=["egreedy"],
                                            shared={"alpha": 0.5, "gamma": 0.8}),
                    task="riverswim", seeds=2, episodes=3, figures=False, run=quiet)
    assert (own.meta["hyperparameters"][0]["learner.alpha"],
            own.meta["hyperparameters"][0]["learner.gamma"]) == (0.5, 0.8)
    # the paper's tasks: the paper's values and the fingerprint of every earlier run
    for task in ("table_cleaning", "cruz2018", "variant:2x1"):
        paper = run_sweep(tmp_path / task.replace(":", "_"), Sweep(
            learners=["qlearning"], explorers=["egreedy"]), task=task, seeds=2, episodes=3,
            figures=False, run=quiet)
        assert paper.meta["learner_defaults"]["rule"] == "paper"
        assert (paper.meta["hyperparameters"][0]["learner.alpha"],
                paper.meta["hyperparameters"][0]["learner.gamma"]) == (0.8, 0.9)
        before = prepare_grid(make_suite_task(task), [Setting("qlearning", "egreedy", 0.1)],
                              num_seeds=2, num_episodes=3, options=AgentOptions())
        assert paper.meta["fingerprint"] == before.fingerprint
    # a rerun of a finished folder keeps its rule; a folder from before the rule: the paper's
    assert read_sweep_file(tmp_path / "river")["learner_defaults"] == "benchmark"
    old = io.load_json(tmp_path / "river" / io.META_FILE)
    del old["sweep"]["learner_defaults"]
    assert sweep_from_meta(old)["learner_defaults"] == "paper"
    # the command line: the first line and the closing lines say the values
    args = ["run", "--out", str(tmp_path / "cli"), "--task", "chain", "--learners",
            "qlearning", "--explorers", "egreedy", "--seeds", "2", "--episodes", "2",
            "--no-figures"]
    assert cli.main(args) == 0
    captured = capsys.readouterr()
    assert captured.err.startswith("learner defaults: alpha=0.1, gamma=0.999 = 1 − 1/H")
    assert "learner defaults (benchmark): alpha=0.1, gamma=0.999" in captured.out
    assert cli.main([*args[:2], str(tmp_path / "cli2"), *args[3:], "--learner-defaults",
                     "paper", "--quiet"]) == 0
    assert "learner defaults (paper): alpha=0.8, gamma=0.9" in capsys.readouterr().out
    # vdbejax list tasks
    tasks = {entry["name"]: entry for entry in catalog(["tasks"])["tasks"]}
    assert tasks["riverswim"]["learner_defaults"].startswith(
        f"alpha=0.1, gamma={1 - 1 / horizon:g} = 1 − 1/H")
    assert tasks["table_cleaning"]["learner_defaults"].endswith("the paper's values")
