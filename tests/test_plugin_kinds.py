"""Kinds of agent stay apart: plug-in classes with the same fields never share a program."""
import jax
import jax.numpy as jnp
import numpy as np

from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods import Explorer, Setting, Table, explorer, make_agent, select_action
from vdbejax.runs import run_grid


def test_classes_with_the_same_fields_have_different_tree_structures():
    # jax.tree_util.register_dataclass gives Q-learning and SARSA (same fields) equal
    # structures, so JAX's caches could run one's program for the other (it happened,
    # intermittently); vdbejax's pytree dataclasses keep the class in the structure.
    q = make_agent(Setting("qlearning", "egreedy", 0.1))
    sarsa = make_agent(Setting("sarsa", "egreedy", 0.1))
    assert jax.tree.structure(q) != jax.tree.structure(sarsa)


def test_each_kind_runs_its_own_rule_inside_a_mixed_grid():
    mdp = make_mdp(max_steps=30)
    settings = [Setting("qlearning", "softmax", 0.1), Setting("sarsa", "softmax", 0.1),
                Setting("qlearning", "vdbe", 1.0), Setting("sarsa", "vdbe", 1.0)]
    grid = run_grid(mdp, settings, num_seeds=3, num_episodes=40, seed=5)
    for c, setting in enumerate(settings):
        alone = run_grid(mdp, [setting], num_seeds=3, num_episodes=40, seed=5)
        np.testing.assert_array_equal(grid.returns[c], alone.returns[0])
    # Same hyperparameters and keys, other learner: other curves.
    assert not np.array_equal(grid.returns[0], grid.returns[1])


# ------------------------------------------------------------------ one program, every kind
@explorer("kinds_test_visits", parameter="epsilon0")
class _VisitEpsilon(Explorer):  # a user's plug-in with a table of its own
    epsilon0: float = 0.5

    def tables(self):
        return {"state_visits": Table("state", 0.0)}

    def select(self, q, tables, context, uniforms):
        return select_action(q, self.epsilon0 / jnp.sqrt(tables["state_visits"] + 1.0), None,
                             uniforms)

    def update(self, tables, action, delta_q, context):
        return {"state_visits": tables["state_visits"] + 1.0}


def _grid_with_every_table_kind():
    """Kinds with learner tables (Double Q's second Q), explorer tables per state (VDBE's
    ε(s)) and per pair (count bonus), a learner that reads π (Expected SARSA), a learner
    that redraws its next action (the authors' SARSA) and a user's plug-in."""
    return [Setting("qlearning", "vdbe", 1.0), Setting("double_qlearning", "softmax", 0.1),
            Setting("expected_sarsa", "count_bonus", 0.5),
            Setting("sarsa", "vdbe_softmax", 1.0, {"next_action": "redrawn"}),
            Setting("qlearning", "kinds_test_visits", 0.5), Setting("sarsa", "egreedy", 0.1)]


def test_one_program_serves_every_kind_with_the_bits_of_one_program_per_kind(monkeypatch):
    from vdbejax.engine import kinds, programs, sequential

    mdp = make_mdp(max_steps=40)
    settings = _grid_with_every_table_kind()
    calls = []
    real = programs.compile_all
    monkeypatch.setattr(programs, "compile_all",
                        lambda c, threads=1: calls.extend(c) or real(c, threads))
    switched = run_grid(mdp, settings, num_seeds=5, num_episodes=30, seed=2, threads=2)
    loops = [c for c in calls if c.function is sequential._run_sequential]
    assert switched.meta["strategy"] == "sequential"
    assert len(loops) == 1  # every kind, every item: one program
    # Blocks of at most 4 kinds: the six kinds get two programs of three, the same bits.
    monkeypatch.setattr(kinds, "MAX_SWITCH_KINDS", 4)
    calls.clear()
    blocks = run_grid(mdp, settings, num_seeds=5, num_episodes=30, seed=2, threads=2)
    loops = [c for c in calls if c.function is sequential._run_sequential]
    assert len(loops) == 2 and all(len(c.args[1]) == 3 for c in loops)
    assert blocks.returns.tobytes() == switched.returns.tobytes()
    assert blocks.lengths.tobytes() == switched.lengths.tobytes()
    monkeypatch.setattr(sequential, "can_switch", lambda kinds: False)
    calls.clear()
    per_kind = run_grid(mdp, settings, num_seeds=5, num_episodes=30, seed=2, threads=2)
    assert len([c for c in calls if c.function is sequential._run_sequential]) >= len(settings)
    np.testing.assert_array_equal(switched.returns, per_kind.returns)
    np.testing.assert_array_equal(switched.lengths, per_kind.lengths)
    lockstep = run_grid(mdp, settings, num_seeds=5, num_episodes=30, seed=2,
                        strategy="lockstep")
    np.testing.assert_array_equal(switched.returns, lockstep.returns)


def test_a_table_name_written_two_ways_gets_one_program_per_kind():
    from vdbejax.engine.kinds import can_switch, table_forms

    vdbe = make_agent(Setting("qlearning", "vdbe", 1.0))
    double_q = make_agent(Setting("double_qlearning", "egreedy", 0.1))
    assert table_forms((vdbe, double_q)) is not None and can_switch((vdbe, double_q))
    assert not can_switch((vdbe,))  # one kind: its own program

    class Clash:  # an explorer table named like the learner's second Q
        def __init__(self, agent, name):
            self.learner, self.explorer = agent.learner, _Renamed(agent.explorer, name)

    learner_table = next(iter(double_q.learner.tables()))
    assert table_forms((double_q, Clash(vdbe, learner_table))) is None


class _Renamed:
    def __init__(self, explorer, name):
        self._explorer, self._name = explorer, name

    def tables(self):
        (spec,) = self._explorer.tables().values()
        return {self._name: spec}


def test_many_kinds_are_split_into_programs_of_at_most_sixteen():
    from vdbejax.engine.kinds import MAX_SWITCH_KINDS, switch_block_size

    assert MAX_SWITCH_KINDS == 16
    sizes = {n: switch_block_size(n) for n in (1, 8, 16, 17, 36, 100)}
    assert sizes == {1: 1, 8: 8, 16: 16, 17: 9, 36: 12, 100: 15}
    for n, size in sizes.items():  # blocks of about equal size, none empty
        blocks = -(-n // size)
        assert size <= MAX_SWITCH_KINDS and n - (blocks - 1) * size >= 1
