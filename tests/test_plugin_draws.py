"""Random draws a plug-in asks for through the contract (Draws: uniforms, normals, keys,
sized from the task), the Thompson-sampling explorer, and the plug-in check's run of
select on sample states (an action outside the task's)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vdbejax
from vdbejax import engine
from vdbejax.envs.suite import make_suite_task
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods import Explorer, Setting, Table, explorer, greedy
from vdbejax.methods.agents import make_agent, stack_agents
from vdbejax.methods.contract import Draws, as_draws
from vdbejax.methods.explorers import make_explorer
from vdbejax.methods.learners import make_learner
from vdbejax.methods.plugin_check import check_plugin
from vdbejax.methods.selection import count_visit


def test_as_draws_gives_uniforms_standard_normals_and_keys():
    rng = np.random.default_rng(0)
    mantissas = rng.integers(0, 2**23, size=(5, 100_000))
    uniforms = tuple(jnp.asarray(m * 2.0**-23, jnp.float32) for m in mantissas)
    assert as_draws(Draws(uniforms=5), uniforms) == uniforms  # the default: as they are
    draws = Draws(uniforms=1, normals=2, keys=1)
    assert draws.slots() == 5
    u, z1, z2, key = as_draws(draws, uniforms)
    assert u is uniforms[0] and key.shape == (100_000, 2) and key.dtype == jnp.uint32
    np.testing.assert_array_equal(np.asarray(key), mantissas[3:].T)
    for z in (np.asarray(z1, np.float64), np.asarray(z2, np.float64)):
        assert np.isfinite(z).all()  # the open interval: never ±inf
        assert abs(z.mean()) < 0.02 and z.std() == pytest.approx(1.0, abs=0.02)


def _grid_of(settings, seeds=2):
    params = engine.broadcast_agents(stack_agents([make_agent(s) for s in settings]), seeds)
    keys = np.tile(engine.agent_keys(2, seeds), (len(settings), 1))
    return params, keys


@pytest.mark.parametrize("task", ["bernoulli_bandit:6", "table_cleaning"])
def test_thompson_sampling_gives_the_same_bits_in_both_strategies(task):
    mdp = make_suite_task(task, max_steps=4 if task.startswith("bern") else 25)
    settings = [Setting("sample_average", "thompson", 1.0,
                        (("posterior", "beta"),)),
                Setting("qlearning", "thompson", 0.5),
                Setting("qlearning", "egreedy", 0.1)]
    params, keys = _grid_of(settings)
    lockstep = engine.run_agents(mdp, params, keys, 30, engine.EngineOptions(strategy="lockstep"))
    sequential = engine.run_agents(mdp, params, keys, 30,
                                   engine.EngineOptions(strategy="sequential", threads=2,
                                                        chunk_episodes=11))
    np.testing.assert_array_equal(lockstep.returns, sequential.returns)
    np.testing.assert_array_equal(lockstep.lengths, sequential.lengths)
    for a, b in zip(jax.tree.leaves(lockstep.final_state), jax.tree.leaves(sequential.final_state),
                    strict=True):
        np.testing.assert_array_equal(a, b)
    assert not lockstep.nonfinite.any()
    visits = np.asarray(lockstep.final_state.tables["visits"])
    assert visits[: 2 * len(keys) // 3].sum() > 0  # the explorer counts its visits


def test_thompson_sampling_finds_the_best_arm_of_a_bernoulli_bandit():
    mdp = make_suite_task("bernoulli_bandit:5")
    means = np.asarray(mdp.reward)[0, :, 0]
    grid = vdbejax.run_grid(mdp, [Setting("sample_average", "thompson", 1.0,
                                          (("posterior", "beta"),)),
                                  Setting("sample_average", "thompson", 0.5)],
                            num_seeds=4, num_episodes=1500, chunk_episodes=1500)
    late = grid.returns[:, :, -500:].mean(axis=(1, 2))
    assert np.all(late > means.max() - 0.08), (late, means)


def test_thompson_rejects_bad_fields_in_one_line():
    with pytest.raises(ValueError, match="posterior='poisson' is invalid"):
        make_explorer("thompson", 1.0, posterior="poisson")
    with pytest.raises(ValueError, match=r"scale=-1\.0 is invalid"):
        make_explorer("thompson", -1.0)


@explorer("test_draws_per_action", parameter="scale")
class PerActionNoise(Explorer):
    """A user plug-in sized from the task: one normal per action."""

    scale: float = 0.3

    def draws(self, num_actions):
        return Draws(uniforms=1, normals=num_actions)

    def select(self, q, tables, context, uniforms):
        return greedy(q + self.scale * jnp.stack(uniforms[1:]), uniforms[0])


@explorer("test_ten_armed_only")
class TenArmedOnly(Explorer):
    """A newcomer's explorer that hard-codes ten actions."""

    num_uniforms = 10

    def tables(self):
        return {"visits": Table("pair", 0.0)}

    def select(self, q, tables, context, uniforms):
        return jnp.argmax(jnp.stack(uniforms)).astype(jnp.int32)

    def update(self, tables, action, delta_q, context):
        return {"visits": count_visit(tables["visits"], action)}


def test_a_plug_in_sized_from_the_task_runs_on_any_number_of_actions():
    for task in ("gaussian_bandit:3", "testbed:12"):
        mdp = make_suite_task(task)
        grid = vdbejax.run_grid(mdp, [Setting("sample_average", "test_draws_per_action", 0.3)],
                                num_seeds=2, num_episodes=20)
        assert grid.returns.shape == (1, 2, 20) and not grid.nonfinite.any()


def test_an_action_outside_the_task_is_caught_at_the_plug_in_check():
    learner = make_learner("qlearning")
    check_plugin(learner, make_explorer("test_ten_armed_only"), num_actions=10)  # fits
    with pytest.raises(ValueError) as err:
        check_plugin(learner, make_explorer("test_ten_armed_only"), num_actions=7)
    message = str(err.value)
    assert "\n" not in message and message.startswith(
        "explorer 'test_ten_armed_only' select() returned action")
    assert "task with 7 actions: must be in [0, 6]" in message
    with pytest.raises(ValueError, match="task with 7 actions"):  # before any training
        vdbejax.run_grid(make_mdp(max_steps=10), [Setting("qlearning", "test_ten_armed_only")],
                         num_seeds=1, num_episodes=2)


@pytest.mark.parametrize("answer, message", [
    ((1, 2), "draws(7) returned tuple: must return Draws(uniforms, normals, keys)"),
    (Draws(normals=-1), "draws(7).normals=-1 is invalid: must be an integer in [0, 4096]"),
    (Draws(keys=3000), "draws(7) in all=6000 is invalid"),
])
def test_bad_draws_are_one_line_errors(answer, message):
    @explorer("test_bad_draws", replace=True)
    class BadDraws(Explorer):
        def draws(self, num_actions):
            return answer

        def select(self, q, tables, context, uniforms):
            return jnp.int32(0)

    with pytest.raises(ValueError) as err:
        check_plugin(make_learner("qlearning"), make_explorer("test_bad_draws"), num_actions=7)
    assert message in str(err.value) and "\n" not in str(err.value)
