"""The lockstep loop writes its tables in place: its optimized HLO copies no buffer of a
table's size per iteration (issue 46), for every kind whose step updates rows."""
import numpy as np
import pytest

from benchmarks.lockstep import block_program_hlo, loop_body
from vdbejax.methods.agents import Setting

LANES = 16  # more than the unrolled lanes: gathers and scatters, as at scale
KINDS = [("qlearning", e) for e in ("egreedy", "softmax", "vdbe", "vdbe_softmax",
                                    "max_boltzmann", "ucb1", "count_bonus")] + [
    (learner, "vdbe") for learner in ("sarsa", "expected_sarsa", "double_qlearning",
                                      "q_lambda", "ucb_h", "ucbvi", "psrl")]


@pytest.mark.parametrize(("learner", "explorer"), KINDS)
def test_the_lockstep_loop_copies_no_table(learner, explorer):
    body = loop_body(block_program_hlo([Setting(learner, explorer)], LANES), LANES, 7)
    assert body["table_copies"] == [], body
    assert body["fusions"] > 0


def test_a_batch_of_mixed_kinds_copies_no_table():
    """A kind per lane (the paper's eight kinds in one batch) still writes in place."""
    kinds = [Setting(learner, explorer) for learner in ("qlearning", "sarsa")
             for explorer in ("egreedy", "softmax", "vdbe", "vdbe_softmax")]
    body = loop_body(block_program_hlo(kinds, LANES), LANES, 7)
    assert body["table_copies"] == [], body
    assert body["fusions"] > 0


def test_loop_body_finds_a_copy_of_a_table():
    hlo = ("ENTRY %main () -> f32[] {\n  %w = (f32[64]) while(%t), condition=%c, body=%b\n}\n"
           "%b (p: (f32[64])) -> (f32[64]) {\n  %g = f32[64]{0} get-tuple-element(%p), index=0\n"
           "  %copy.1 = f32[64]{0} copy(%g)\n  %f = f32[4]{0} fusion(%copy.1), kind=kLoop\n}\n")
    body = loop_body(hlo, lanes=4, actions=2)
    assert body["table_copies"] == [{"dtype": "f32", "shape": "64", "bytes": 256}]
    assert body["fusions"] == 1


def test_auto_strategy_rule():
    from vdbejax.engine import auto_strategy

    assert auto_strategy(46_000, backend="cpu") == (
        "sequential", "cpu, 46000 agents (sequential is the faster on a CPU)")
    assert auto_strategy(1, backend="gpu") == ("lockstep", "backend gpu")
    assert auto_strategy(1, backend="cpu", sharded=True)[0] == "lockstep"


def test_a_batch_holds_every_agent_on_accelerators_within_int32_indices():
    import jax

    from vdbejax.engine import MAX_SAFE_BATCH, default_max_batch, init_agents
    from vdbejax.engine.lanes import FLAT_INDEX_MAX
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.envs.tabular import make_tabular_mdp
    from vdbejax.runs import grid_agents

    def lanes(mdp, seeds, backend, chunk=128):
        params, keys = grid_agents([Setting("qlearning", "egreedy", 0.1)], seeds)
        agents = jax.eval_shape(init_agents, mdp, params, keys)
        return default_max_batch(agents, params, chunk, backend)

    small = make_mdp()
    assert lanes(small, 5000, "cpu") == MAX_SAFE_BATCH and lanes(small, 5000, "gpu") == 5000
    assert lanes(small, 5000, "gpu", chunk=2**30) == 1  # episode buffers of 2**30 each
    # A Q-table of 2**20 values per agent: 2**11 - 1 agents index within int32.
    start = np.zeros(2**14)
    start[0] = 1.0
    wide = make_tabular_mdp(np.zeros((2**14, 64), np.int32), np.zeros((2**14, 64)),
                            np.zeros((2**14, 64), bool), start)
    assert lanes(wide, 5000, "gpu") == FLAT_INDEX_MAX // 2**20 == 2**11 - 1


def test_kinds_mix_by_default_on_accelerators_only():
    from vdbejax.engine import mixes_kinds

    assert (mixes_kinds("cpu"), mixes_kinds("gpu"), mixes_kinds("tpu")) == (False, True, True)


def test_the_lockstep_and_auto_rule_benchmarks_run(capsys):
    import json

    from benchmarks import auto_rule, lockstep

    assert lockstep.main(["--seeds", "1", "--episodes", "3", "--lanes", "8", "--repeats", "1",
                          "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    lock, mixed, seq = report["runs"]
    kinds = len(report["kinds"]) - 1  # and the mixed batch
    assert lock["host_round_trips_per_chunk"] >= kinds  # a block per group
    assert lock["agent_steps"] == mixed["agent_steps"] == seq["agent_steps"] > 0  # same work
    # Kind after kind, a chunk takes each kind's iterations; mixed, those of the slowest.
    assert mixed["loop_trips_per_chunk"] < lock["loop_trips_per_chunk"]
    for run in (lock, mixed):  # every iteration runs its fusions
        assert run["fusions_run_per_chunk"] > run["loop_trips_per_chunk"] > 0
    assert auto_rule.main(["--seeds", "1", "--episodes", "3", "--repeats", "1", "--json"]) == 0
    row, = json.loads(capsys.readouterr().out)["rows"]
    assert row["agents"] == 46 and row["auto_over_better"] > 0
