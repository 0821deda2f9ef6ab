"""The authors' task table (vdbejax.envs.cruz2018) against its published data, by search."""
from collections import deque

import numpy as np
import pytest

from vdbejax.envs import solvers
from vdbejax.envs.cruz2018 import ACTION_NAMES, STEP_CAP, make_authors_mdp, table
from vdbejax.methods import Setting
from vdbejax.runs import run_grid
from vdbejax.studies.task_names import make_task


@pytest.fixture(scope="module")
def mdp():
    return make_authors_mdp()


def _distances():
    """Breadth-first search over the published table itself (failures end the search)."""
    transitions = table()["transitions"]
    distance = {0: 0}
    queue = deque([0])
    while queue:
        s = queue.popleft()
        if s in table()["goal_states"]:
            continue  # entering a goal ends the episode
        for nxt in transitions[s]:
            if nxt >= 0 and nxt not in distance:
                distance[nxt] = distance[s] + 1
                queue.append(nxt)
    return distance


def test_every_state_is_reachable_and_the_goals_are_15_and_16_actions_away():
    distance = _distances()
    assert sorted(distance) == list(range(53))
    assert distance[52] == 15 and distance[51] == 16


def test_the_mdp_follows_the_published_table(mdp):
    data = table()
    transitions = np.asarray(data["transitions"])
    assert (mdp.num_states, mdp.num_actions) == (53, 7) and len(ACTION_NAMES) == 7
    assert mdp.max_steps == STEP_CAP and mdp.start_probability[0] == 1.0
    next_state = np.asarray(mdp.next_state)[..., 0]
    reward = np.asarray(mdp.reward)[..., 0]
    terminal = np.asarray(mdp.terminal)[..., 0]
    acting = transitions[:51]
    failure = acting == -1
    goal = np.isin(acting, [51, 52])
    np.testing.assert_array_equal(terminal[:51], failure | goal)
    np.testing.assert_allclose(reward[:51], np.where(failure, -1.0, np.where(goal, 1.0, -0.01)))
    np.testing.assert_array_equal(next_state[:51][~failure], acting[~failure])
    # 75 of the 357 pairs fail: clean in 37 states, get and drop in 19 each; moves and
    # abort never fail, abort returns home and the episode goes on.
    assert failure.sum() == 75
    assert failure.sum(axis=0).tolist() == [19, 19, 0, 0, 0, 37, 0]
    assert (acting[:, 6] == 0).all() and not terminal[:51, 6].any()


def test_best_return_is_086_in_15_actions(mdp):
    assert solvers.best_return(mdp) == pytest.approx(0.86)
    assert solvers.steps_to_goal(mdp)[0] == 15
    path = solvers.shortest_solution(mdp, 0)
    assert len(path) == 15
    s, total = 0, 0.0
    for a in path:
        total += float(mdp.reward[s, a, 0])
        done = bool(mdp.terminal[s, a, 0])
        s = int(mdp.next_state[s, a, 0])
    assert done and s == 52 and total == pytest.approx(0.86)


def test_the_task_runs_through_run_grid_and_by_name(mdp):
    assert make_task("cruz2018").name == "cruz2018"
    grid = run_grid(make_authors_mdp(max_steps=200), [Setting("qlearning", "vdbe_softmax", 1.0)],
                    num_seeds=2, num_episodes=30)
    assert grid.meta["mdp"] == "cruz2018" and np.isfinite(grid.returns).all()
    assert grid.returns.max() <= 0.86 + 1e-6
