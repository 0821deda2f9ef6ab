"""compile_env: vdbejax's own stateless environments go through the stored-program path
(no tracing in a warm process); every other environment is traced with its params baked
in. Both give the same tables."""
import jax
import jax.numpy as jnp
import numpy as np

from vdbejax import _executables
from vdbejax.envs import tabular
from vdbejax.envs.table_cleaning import env as table_env
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.envs.tabular import compile_env


def _stored_steps() -> int:
    return sum(1 for key in _executables._EXECUTABLES if key[0] is tabular._stateless_env_step)


def _tables(mdp):
    return [np.asarray(leaf) for leaf in jax.tree.leaves(mdp)]


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.dtype == y.dtype
        np.testing.assert_array_equal(x, y)


class UsersTableCleaning(table_env.TableCleaning):
    """The same task, defined outside vdbejax: its code is the user's, so it is traced."""


class ParamsAsConstants(table_env.TableCleaning):
    """Python control flow on a params leaf: it must be traced with params baked in."""

    def transition(self, fields, action, params):
        next_fields, reward, terminal = super().transition(fields, action, params)
        if params.max_steps > 50:  # needs a concrete max_steps
            reward = reward + jnp.float32(0.0)
        return next_fields, reward, terminal


def test_builtin_stateless_env_uses_a_stored_program_with_the_same_tables():
    params = table_env.make_params(100, "noop")
    builtin = make_mdp()
    assert _stored_steps() >= 1  # the built-in went through the program table
    before = _stored_steps()
    users = compile_env(UsersTableCleaning(), params, name="table_cleaning")
    assert _stored_steps() == before  # the user's class was traced, not stored
    _same(_tables(builtin), _tables(users))


def test_an_env_that_needs_concrete_params_is_traced(monkeypatch):
    # Pretend the class is vdbejax's own, so the stored path is tried first.
    monkeypatch.setattr(ParamsAsConstants, "__module__", table_env.__name__)
    monkeypatch.setattr(table_env, "ParamsAsConstants", ParamsAsConstants, raising=False)
    params = table_env.make_params(100, "fail")
    mdp = compile_env(ParamsAsConstants(), params, name="table_cleaning")
    _same(_tables(make_mdp(invalid_action="fail")), _tables(mdp))


def test_an_env_with_state_of_its_own_is_traced():
    env = table_env.TableCleaning()
    env.note = "instance state"  # could change what the step does: never keyed by class
    before = _stored_steps()
    mdp = compile_env(env, table_env.make_params(100, "noop"), name="table_cleaning")
    assert _stored_steps() == before
    _same(_tables(make_mdp()), _tables(mdp))


def test_a_patched_environment_is_traced_anew(monkeypatch):
    """The stored step is keyed by vdbejax's live code: a patched constant (or an edited,
    reloaded module) gives its own program, and undoing the patch the first one again."""
    before = make_mdp()
    monkeypatch.setattr(table_env, "STEP_REWARD", -0.5)
    patched = make_mdp()
    step = ~np.asarray(patched.terminal)
    assert np.all(np.asarray(patched.reward)[step] == np.float32(-0.5))
    monkeypatch.undo()
    _same(_tables(before), _tables(make_mdp()))


class ShapesFromParams(table_env.TableCleaning):
    """A params leaf used as a shape: a plain TypeError under a trace, fine as a constant."""

    def transition(self, fields, action, params):
        next_fields, reward, terminal = super().transition(fields, action, params)
        return next_fields, reward + jnp.zeros(params.max_steps)[0], terminal


def test_an_env_whose_params_set_shapes_is_traced(monkeypatch):
    monkeypatch.setattr(ShapesFromParams, "__module__", table_env.__name__)
    monkeypatch.setattr(table_env, "ShapesFromParams", ShapesFromParams, raising=False)
    mdp = compile_env(ShapesFromParams(), table_env.make_params(100, "noop"), name="table_cleaning")
    _same(_tables(make_mdp()), _tables(mdp))


def test_only_integer_params_and_stateless_importable_classes_take_the_stored_path():
    assert tabular._keeps_no_state(table_env.TableCleaning())
    assert not tabular._keeps_no_state(UsersTableCleaning())  # not vdbejax's module

    class Local(table_env.TableCleaning):  # not importable by its name
        pass

    Local.__module__ = table_env.__name__
    assert not tabular._keeps_no_state(Local())
    assert tabular._integer_leaves(table_env.make_params(100, "noop"))
    assert not tabular._integer_leaves({"p": 0.5})
