"""The engine's programs (vdbejax.engine.programs): traced once per process for the same
plug-in classes, methods, static fields and shapes, compiled once per lowered program; a
patched learner or explorer method, a class attribute, an environment constant or a
reloaded module runs its new code, never a stale program; a patched module-level helper is
fixed when traced (as under jax.jit) until forget_traced_programs()."""
import importlib
import sys
import textwrap
from collections import OrderedDict

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax.engine import EngineOptions, programs, run_agents
from vdbejax.envs.table_cleaning import core as table_core
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods import explorers, learners, selection
from vdbejax.methods.agents import Setting
from vdbejax.runs import grid_agents

SETTINGS = [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0)]


def _run(mdp=None, settings=SETTINGS, **options):
    params, keys = grid_agents(settings, 2)
    return run_agents(mdp or make_mdp(), params, keys, 5,
                      EngineOptions(chunk_episodes=5, **options)).returns


@pytest.fixture(params=["sequential", "lockstep"])
def strategy(request):
    return request.param


def _count_traces(monkeypatch) -> list:
    traced: list = []
    real = programs._lower
    monkeypatch.setattr(programs, "_lower", lambda call: traced.append(call) or real(call))
    return traced


def test_the_same_code_reuses_its_compiled_programs(monkeypatch, strategy):
    # Empty tables of its own: full ones (other tests) would hide a program traced or
    # compiled again under a new key.
    monkeypatch.setattr(programs, "_TABLE", OrderedDict())
    monkeypatch.setattr(programs, "_TRACED", OrderedDict())
    traced = _count_traces(monkeypatch)
    first = _run(strategy=strategy)
    compiled = dict(programs._TABLE)
    assert compiled and traced
    traced.clear()
    again = _run(strategy=strategy)
    assert traced == []  # the second call traces nothing
    assert programs._TABLE.keys() == compiled.keys()  # and compiles nothing
    np.testing.assert_array_equal(first, again)
    programs.forget_traced_programs()
    traced_again = _run(strategy=strategy)
    assert traced  # traced afresh: the same lowered programs, none compiled again
    assert all(programs._TABLE[key] is program for key, program in compiled.items())
    np.testing.assert_array_equal(first, traced_again)


def test_runs_of_a_few_more_or_fewer_episodes_share_their_programs(monkeypatch, strategy):
    # The chunk buffers' length is a power of two (at least 8): 5 and 7 episodes are one
    # program, with the episodes of each run as it alone gives them.
    monkeypatch.setattr(programs, "_TABLE", type(programs._TABLE)())
    params, keys = grid_agents(SETTINGS, 2)
    five = run_agents(make_mdp(), params, keys, 5, EngineOptions(strategy=strategy))
    compiled = dict(programs._TABLE)
    seven = run_agents(make_mdp(), params, keys, 7, EngineOptions(strategy=strategy))
    assert programs._TABLE.keys() == compiled.keys()
    assert seven.returns.shape == (4, 7) and five.returns.shape == (4, 5)
    assert seven.returns[:, :5].tobytes() == five.returns.tobytes()
    assert seven.lengths[:, :5].tobytes() == five.lengths.tobytes()
    assert (seven.lengths > 0).all()


def test_a_patched_learner_method_gets_a_new_program(monkeypatch, strategy):
    before = _run(strategy=strategy)
    monkeypatch.setattr(learners.QLearning, "target", lambda self, t: t.reward + 5.0)
    patched = _run(strategy=strategy)
    assert not np.array_equal(before[:2], patched[:2])  # the Q-learning agents changed
    np.testing.assert_array_equal(before[2:], patched[2:])  # SARSA's did not
    monkeypatch.undo()
    np.testing.assert_array_equal(before, _run(strategy=strategy))


def test_a_patched_explorer_method_gets_a_new_program(monkeypatch, strategy):
    before = _run(strategy=strategy)
    monkeypatch.setattr(explorers.EpsilonGreedy, "select",
                        lambda self, q, tables, context, uniforms: jnp.int32(0))
    patched = _run(strategy=strategy)
    assert not np.array_equal(before[:2], patched[:2])
    np.testing.assert_array_equal(before[2:], patched[2:])


def test_a_patched_helper_function_is_fixed_when_traced_until_forgotten(monkeypatch):
    """A module-level function the built-ins call (here the categorical draw behind every
    choice of select_action) is read when the program is traced, as under jax.jit."""
    before = _run()
    monkeypatch.setattr(selection, "sample_categorical",
                        lambda weights, u: jnp.int32(weights.shape[0] - 1))
    np.testing.assert_array_equal(before, _run())  # this process's program, traced before
    programs.forget_traced_programs()
    assert not np.array_equal(before, _run())
    monkeypatch.undo()
    programs.forget_traced_programs()
    np.testing.assert_array_equal(before, _run())


def test_a_changed_class_attribute_gets_a_new_program(monkeypatch):
    """Class attributes (not only methods) are read when a program is traced."""
    before = _run()
    monkeypatch.setattr(explorers.EpsilonGreedy, "select",
                        lambda self, q, tables, context, uniforms: jnp.int32(self.first))
    monkeypatch.setattr(explorers.EpsilonGreedy, "first", 0, raising=False)
    zero = _run()
    monkeypatch.setattr(explorers.EpsilonGreedy, "first", 6)
    six = _run()
    assert not np.array_equal(before[:2], zero[:2])
    assert not np.array_equal(zero[:2], six[:2])


def test_the_trace_key_follows_jax_configuration():
    call = programs.Call(lambda x: x + 1, (np.float32(1.0),))
    with jax.enable_x64(True):
        wide = call.trace_key()
    assert wide != call.trace_key()
    assert call.trace_key() == programs.Call(call.function, call.args).trace_key()


def test_a_patched_environment_constant_is_seen(monkeypatch):
    before = _run()
    monkeypatch.setattr(table_core, "STEP_REWARD", -0.5)
    patched = _run()
    assert (patched <= before).all() and (patched < before).any()


PLUGIN = '''
import jax.numpy as jnp
from vdbejax.methods import Explorer, explorer, greedy

@explorer("reload_probe", parameter="bonus")
class ReloadProbe(Explorer):
    bonus: float = 0.0
    num_uniforms = 1

    def select(self, q, tables, context, uniforms):
        return greedy(q + jnp.arange(q.shape[0]) * {scale}, uniforms[0])
'''


def test_a_reloaded_module_gets_a_new_program(tmp_path, monkeypatch):
    path = tmp_path / "reload_probe_module.py"
    path.write_text(textwrap.dedent(PLUGIN.format(scale="0.0")))
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("reload_probe_module")
    try:
        settings = [Setting("qlearning", "reload_probe")]
        before = _run(settings=settings)
        path.write_text(textwrap.dedent(PLUGIN.format(scale="-10.0")))  # always action 0
        importlib.reload(module)
        after = _run(settings=settings)
        assert not np.array_equal(before, after)
    finally:
        sys.modules.pop("reload_probe_module", None)
        explorers_registry = importlib.import_module("vdbejax.methods.registry").EXPLORERS
        explorers_registry.pop("reload_probe", None)


def test_the_table_of_compiled_programs_is_bounded(monkeypatch):
    monkeypatch.setattr(programs, "MAX_PROGRAMS", 2)
    monkeypatch.setattr(programs, "_TABLE", type(programs._TABLE)())  # all misses here
    _run(settings=[Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "softmax", 1.0),
                   Setting("qlearning", "vdbe", 1.0)])
    assert programs.cached_programs() == 2  # 3 kinds' loops (and init) compiled, 2 kept


def test_the_key_tells_classes_with_the_same_fields_apart():
    import jax

    from vdbejax._pytree import pytree_dataclass

    @pytree_dataclass
    class A:
        x: jax.Array

    @pytree_dataclass
    class B:
        x: jax.Array

    def double(tree):
        return jax.tree.map(lambda v: v * 2, tree)

    run = programs.Programs()
    a = run.get(double, (A(jnp.ones(2)),))(A(jnp.ones(2)))
    b = run.get(double, (B(jnp.ones(2)),))(B(jnp.ones(2)))
    assert type(a) is A and type(b) is B
