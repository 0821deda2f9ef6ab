"""compile_env traces the environment as it is at the call (params baked in): a user's
subclass, an environment that needs concrete params and a patched constant all give the
tables they should."""
import jax
import jax.numpy as jnp
import numpy as np

from vdbejax.envs.compiled import compile_env
from vdbejax.envs.table_cleaning import core as table_core
from vdbejax.envs.table_cleaning import env as table_env
from vdbejax.envs.table_cleaning import make_mdp


def _tables(mdp):
    return [np.asarray(leaf) for leaf in jax.tree.leaves(mdp)]


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.dtype == y.dtype
        np.testing.assert_array_equal(x, y)


class UsersTableCleaning(table_env.TableCleaning):
    """The same task, defined outside vdbejax."""


class ParamsAsConstants(table_env.TableCleaning):
    """Python control flow on a params leaf: works because params are baked in."""

    def transition(self, fields, action, params):
        next_fields, reward, terminal = super().transition(fields, action, params)
        if params.max_steps > 50:  # needs a concrete max_steps
            reward = reward + jnp.float32(0.0)
        return next_fields, reward, terminal


class ShapesFromParams(table_env.TableCleaning):
    """A params leaf used as a shape: fine as a constant."""

    def transition(self, fields, action, params):
        next_fields, reward, terminal = super().transition(fields, action, params)
        return next_fields, reward + jnp.zeros(params.max_steps)[0], terminal


def test_a_users_subclass_gives_the_builtin_tables():
    users = compile_env(UsersTableCleaning(), table_core.make_params(100, "noop"),
                        name="table_cleaning")
    _same(_tables(make_mdp()), _tables(users))


def test_an_env_that_needs_concrete_params_compiles():
    mdp = compile_env(ParamsAsConstants(), table_core.make_params(100, "fail"),
                      name="table_cleaning")
    _same(_tables(make_mdp(invalid_action="fail")), _tables(mdp))


def test_an_env_whose_params_set_shapes_compiles():
    mdp = compile_env(ShapesFromParams(), table_core.make_params(100, "noop"),
                      name="table_cleaning")
    _same(_tables(make_mdp()), _tables(mdp))


def test_a_patched_environment_constant_is_seen_and_undone(monkeypatch):
    before = make_mdp()
    monkeypatch.setattr(table_core, "STEP_REWARD", -0.5)
    patched = make_mdp()
    step = ~np.asarray(patched.terminal)
    assert np.all(np.asarray(patched.reward)[step] == np.float32(-0.5))
    monkeypatch.undo()
    _same(_tables(before), _tables(make_mdp()))


def test_a_patched_environment_method_is_seen(monkeypatch):
    original = table_env.TableCleaning.transition

    def never_terminal(self, fields, action, params):
        next_fields, reward, _ = original(self, fields, action, params)
        return next_fields, reward, jnp.asarray(False)

    monkeypatch.setattr(table_env.TableCleaning, "transition", never_terminal)
    assert not np.asarray(make_mdp().terminal).any()
    monkeypatch.undo()
    assert np.asarray(make_mdp().terminal).any()
