"""The engine's programs (vdbejax.engine.programs) are keyed by the lowered program: the
same code reuses its compiled program, and a patched learner, explorer, helper, environment
constant or reloaded module runs its new code, never a stale program."""
import importlib
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax.engine import programs, run_agents
from vdbejax.envs.table_cleaning import env as table_env
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.experiment import grid_agents
from vdbejax.methods import explorers, learners, selection
from vdbejax.methods.agents import Setting

SETTINGS = [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0)]


def _run(mdp=None, settings=SETTINGS, **options):
    params, keys = grid_agents(settings, 2)
    return run_agents(mdp or make_mdp(), params, keys, 5, chunk_episodes=5, **options).returns


@pytest.fixture(params=["sequential", "lockstep"])
def strategy(request):
    return request.param


def test_the_same_code_reuses_its_compiled_programs(monkeypatch, strategy):
    # An empty table of its own: a full one (other tests) would hide a program compiled
    # again under a new key.
    monkeypatch.setattr(programs, "_TABLE", type(programs._TABLE)())
    first = _run(strategy=strategy)
    compiled = dict(programs._TABLE)
    assert compiled
    again = _run(strategy=strategy)
    assert programs._TABLE.keys() == compiled.keys()  # traced again, nothing new compiled
    assert all(programs._TABLE[key] is program for key, program in compiled.items())
    np.testing.assert_array_equal(first, again)


def test_runs_of_a_few_more_or_fewer_episodes_share_their_programs(monkeypatch, strategy):
    # The chunk buffers' length is a power of two (at least 8): 5 and 7 episodes are one
    # program, with the episodes of each run as it alone gives them.
    monkeypatch.setattr(programs, "_TABLE", type(programs._TABLE)())
    params, keys = grid_agents(SETTINGS, 2)
    five = run_agents(make_mdp(), params, keys, 5, strategy=strategy)
    compiled = dict(programs._TABLE)
    seven = run_agents(make_mdp(), params, keys, 7, strategy=strategy)
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


def test_a_patched_helper_function_is_seen(monkeypatch):
    """A module-level function the built-ins call (here the categorical draw behind every
    choice of select_action)."""
    before = _run()
    monkeypatch.setattr(selection, "sample_categorical",
                        lambda weights, u: jnp.int32(weights.shape[0] - 1))
    assert not np.array_equal(before, _run())


def test_a_patched_environment_constant_is_seen(monkeypatch):
    before = _run()
    monkeypatch.setattr(table_env, "STEP_REWARD", -0.5)
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
        explorers_registry = importlib.import_module("vdbejax.methods.api").EXPLORERS
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
