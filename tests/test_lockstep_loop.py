"""The lockstep loop writes its tables in place: its optimized HLO copies no buffer of a
table's size per iteration (issue 46), for every kind whose step updates rows."""
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
    body = loop_body(block_program_hlo(Setting(learner, explorer), LANES), LANES, 7)
    assert body["table_copies"] == [], body
    assert body["fusions"] > 0


def test_loop_body_finds_a_copy_of_a_table():
    hlo = ("ENTRY %main () -> f32[] {\n  %w = (f32[64]) while(%t), condition=%c, body=%b\n}\n"
           "%b (p: (f32[64])) -> (f32[64]) {\n  %g = f32[64]{0} get-tuple-element(%p), index=0\n"
           "  %copy.1 = f32[64]{0} copy(%g)\n  %f = f32[4]{0} fusion(%copy.1), kind=kLoop\n}\n")
    body = loop_body(hlo, lanes=4, actions=2)
    assert body["table_copies"] == [{"dtype": "f32", "shape": "64", "bytes": 256}]
    assert body["fusions"] == 1
