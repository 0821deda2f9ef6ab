"""Claims as data (vdbejax.results.claim_spec, claim_scoring): the format, its one-line
errors, and verdicts decided by intervals only — on results built by hand, so that every
interval is known."""
import numpy as np
import pytest

from vdbejax.methods import Setting
from vdbejax.results.claim_scoring import score_claims
from vdbejax.results.claim_spec import check_claims, parse_claims
from vdbejax.results.grid_result import GridResult

EPSILONS = (0.0, 0.01, 0.1)


def grid(levels, seeds=40, episodes=120, spread=0.05, replicates=1, seed=0):
    """Settings egreedy ε ∈ EPSILONS with constant returns around ``levels`` (± spread)."""
    rng = np.random.default_rng(seed)
    settings = [Setting("qlearning", "egreedy", e) for e in EPSILONS[:len(levels)]]
    n = seeds * replicates
    per_agent = np.asarray(levels)[:, None] + spread * rng.standard_normal((len(levels), n))
    returns = np.repeat(per_agent[..., None], episodes, -1).astype(np.float32)
    meta = {"best_return": 1.0, "random_return": 0.0, "num_seeds": n,
            "num_episodes": episodes, "max_steps": 10}
    if replicates > 1:
        meta.update(replicates=replicates, agents_per_replicate=seeds)
    shape = returns.shape
    return GridResult(settings, returns, np.full(shape, 5, np.int32),
                      np.zeros(shape[:2], bool), meta)


def claims(*checks, sentence="a claim"):
    return parse_claims([{"claim": sentence, "checks": list(checks)}])


def verdicts(result, *checks):
    scored = score_claims(result, claims(*checks)).claims[0]
    return [c.passed for c in scored.checks], scored.verdict


G0, G01, G1 = ("qlearning/egreedy/epsilon=0", "qlearning/egreedy/epsilon=0.01",
               "qlearning/egreedy/epsilon=0.1")


def test_numbers_settings_and_axes_decided_by_intervals():
    result = grid([0.2, 0.5, 0.9])
    passed, verdict = verdicts(
        result,
        {"setting": G1, "above": 0.8},
        {"setting": G0, "below": 0.3},
        {"setting": G01, "about": 0.5, "tolerance": 0.1},
        {"setting": {"epsilon": 0.1}, "near_best": True, "near": 0.2},
        {"setting": G1, "higher_than": G01},
        {"setting": G0, "lower_than": {"learner": "qlearning", "epsilon": 0.01}},
        {"setting": G1, "beats": G0, "probability_above": 0.9},
        {"axis": "epsilon", "among": {"explorer": "egreedy"}, "best": [0.1]},
        {"axis": "epsilon", "among": {"explorer": "egreedy"}, "rank": 2, "value": 0.01},
        {"setting": G1, "metric": "final_iqm", "above": 0.8},
        {"setting": G1, "metric": "normalised_score", "above": 0.8},
        {"any": [{"setting": G0, "above": 0.8}, {"setting": G1, "above": 0.8}]},
        {"not": {"setting": G0, "above": 0.8}})
    assert passed == [True] * 13 and verdict == "reproduced"
    passed, verdict = verdicts(result, {"setting": G1, "below": 0.8},
                               {"setting": G0, "higher_than": G1},
                               {"axis": "epsilon", "among": {"explorer": "egreedy"},
                                "best": [0.0]})
    assert passed == [False, False, False] and verdict == "not reproduced"
    passed, verdict = verdicts(result, {"setting": G1, "above": 0.8},
                               {"setting": G0, "above": 0.8})
    assert verdict == "partly"


def test_overlapping_intervals_never_decide_a_check():
    # Two settings whose means differ (0.50 vs 0.52) by less than their intervals' width:
    # "higher", "lower", "no later", P(A > B) and the best value are all undecided.
    result = grid([0.50, 0.52], seeds=20, spread=0.2)
    rows = score_claims(result, claims({"setting": G01, "above": 0})).claims[0]
    assert rows.checks[0].passed is True
    x = result.returns[:, :, -1].mean(1)
    assert x[1] > x[0]  # a difference exists, inside the intervals
    passed, verdict = verdicts(
        result,
        {"setting": G01, "higher_than": G0}, {"setting": G0, "lower_than": G01},
        {"setting": G01, "beats": G0}, {"setting": G01, "metric": "final_iqm",
                                        "higher_than": G0},
        {"axis": "epsilon", "among": {"explorer": "egreedy"}, "best": [0.01]},
        {"axis": "epsilon", "among": {"explorer": "egreedy"}, "rank": 1, "value": 0.01},
        {"setting": G01, "about": 0.52, "tolerance": 0.01})
    assert passed == [None] * 7 and verdict == "undecided"


def test_replicates_count_and_headline():
    result = grid([0.2, 0.5, 0.9], seeds=30, replicates=3)
    scores = score_claims(result, claims({"setting": G1, "higher_than": G0}))
    claim = scores.claims[0]
    assert len(scores.replicates) == 3
    assert claim.replicate_verdicts == ["reproduced"] * 3 and claim.verdict == "reproduced"
    assert claim.checks[0].replicates_passed == 3


def test_claims_csv_gives_estimates_intervals_and_bounds_their_own_columns(tmp_path):
    from vdbejax.results import io
    from vdbejax.results.claim_report import CLAIMS_COLUMNS, write_claims

    result = grid([0.2, 0.5, 0.9], seeds=30, replicates=2)
    scores = score_claims(result, claims(
        {"setting": G1, "above": 0.8}, {"setting": G1, "higher_than": G0},
        {"setting": G1, "beats": G0, "probability_above": 0.9},
        {"setting": G1, "near_best": True, "near": 0.2},
        {"not": {"setting": G0, "above": 0.8}}))
    write_claims(tmp_path, scores, result.meta, "")
    rows = io.read_csv(tmp_path / "claims.csv")
    assert list(rows[0]) == CLAIMS_COLUMNS and len(rows) == 5 * 3
    assert [r["replicate"] for r in rows[::5]] == ["", "0", "1"]
    above, versus, beats, near, combined = rows[:5]
    finals = result.returns[:, :, -1]
    assert (above["metric"], above["setting"], float(above["bound"])) == (
        "final_return", G1, 0.8)
    assert float(above["estimate"]) == pytest.approx(finals[2].mean(), abs=1e-5)
    assert float(above["low"]) < float(above["estimate"]) < float(above["high"])
    assert above["other_setting"] == above["other_estimate"] == ""
    assert (versus["other_setting"], versus["bound"]) == (G0, "")
    assert float(versus["other_estimate"]) == pytest.approx(finals[0].mean(), abs=1e-5)
    assert float(versus["other_low"]) < float(versus["other_high"]) < float(versus["low"])
    assert (beats["metric"], beats["other_setting"], beats["bound"]) == (
        "probability_of_improvement", G0, "0.9")
    assert float(beats["estimate"]) == 1.0
    assert float(near["bound"]) == pytest.approx(0.8)  # the best return 1 less near 0.2
    assert combined["metric"] == combined["estimate"] == "" and combined["outcome"] == "holds"
    # A replicate's row reads that replicate's agents.
    assert float(rows[5]["estimate"]) == pytest.approx(finals[2, :30].mean(), abs=1e-5)


def late(result, config, until):
    """``result`` with setting ``config``'s agents at 0 before episode ``until``."""
    result.returns[config, :, :until] = 0.0
    return result


def test_a_ranked_selector_picks_the_best_or_worst_setting_by_its_results():
    result = grid([0.2, 0.9, 0.95])
    egreedy = {"explorer": "egreedy"}
    scores = score_claims(result, claims(
        {"setting": {"best": egreedy}, "above": 0.5},
        {"setting": {"worst": egreedy, "by": "final_return"}, "below": 0.5},
        {"setting": {"best": {"epsilon": 0.01}}, "lower_than": {"best": {"epsilon": 0.1}}}))
    assert [c.reading.setting for c in scores.claims[0].checks] == [G1, G0, G01]
    assert scores.claims[0].verdict == "reproduced"
    # Within TIE (0.01) of the best IQM, the setting that converges first is the best.
    tied = late(grid([0.2, 0.9, 0.905], episodes=300), 2, 60)
    picked = score_claims(tied, claims({"setting": {"best": egreedy}, "above": 0.5}))
    assert picked.claims[0].checks[0].reading.setting == G01
    apart = late(grid([0.2, 0.9, 0.95], episodes=300), 2, 60)
    picked = score_claims(apart, claims({"setting": {"best": egreedy}, "above": 0.5}))
    assert picked.claims[0].checks[0].reading.setting == G1


def test_a_factor_scales_the_other_settings_estimate():
    # ε = 0 converges about 10 episodes after ε = 0.01 (59 and 49, intervals apart).
    result = late(late(grid([0.99, 0.99], episodes=200, spread=0.005), 0, 40), 1, 30)
    earlier = {"setting": G0, "no_later_than": G01}
    assert verdicts(result, earlier)[0] == [False]
    scored = score_claims(result, claims({**earlier, "factor": 2})).claims[0].checks[0]
    assert scored.passed is True and "no later than 2 ×" in scored.description
    assert scored.reading.other_estimate.value == 2 * score_claims(
        result, claims(earlier)).claims[0].checks[0].reading.other_estimate.value


def test_optional_checks_are_left_out_where_their_settings_are_absent():
    result = grid([0.2, 0.9])  # no ε = 0.1
    absent = {"setting": G1, "above": 0.5}
    stated = parse_claims([
        {"claim": "one", "checks": [{**absent, "optional": True}]},
        {"claim": "two", "checks": [{"setting": G01, "above": 0.5},
                                    {"not": {**absent}, "optional": True},
                                    {"setting": {"best": {"epsilon": 0.1}}, "above": 0.5,
                                     "optional": True}]}])
    scores = score_claims(result, stated)
    assert [(c.number, len(c.checks), c.verdict) for c in scores.claims] == [
        (2, 1, "reproduced")]
    with pytest.raises(ValueError, match="names no setting"):
        score_claims(result, claims(absent))
    with pytest.raises(ValueError, match="'optional' is invalid inside a combination"):
        claims({"not": {**absent, "optional": True}})
    # Present, an optional check is scored as any other.
    full = score_claims(grid([0.2, 0.9, 0.95]), stated)
    assert [len(c.checks) for c in full.claims] == [1, 3]


@pytest.mark.parametrize("check, message", [
    ({"setting": {"best": {"explorer": "softmax"}}, "above": 1},
     r"setting.best=\{explorer = 'softmax'\} is invalid: it names no setting"),
    ({"setting": {"best": {"explorer": "egreedy"}, "by": "speed"}, "above": 1},
     "setting.by='speed' is invalid: allowed are final_return"),
    ({"setting": {"best": G0, "worst": G1}, "above": 1}, "a ranked selector is"),
    ({"setting": {"best": {"explorer": "egreedy"}}, "higher_than": G0},
     "higher_than=.* is invalid: it may be the setting checked"),
    ({"setting": {"worst": {"explorer": "egreedy"}, "by": "optimal_actions"}, "above": 1},
     "setting.by='optimal_actions' is invalid: the run does not record it"),
    ({"setting": G0, "higher_than": G1, "factor": 0}, "factor=0 is invalid: must be a number > 0"),
    ({"setting": G0, "above": 1, "factor": 2}, "'factor' is invalid with above"),
])
def test_bad_ranked_selectors_and_factors_are_one_line(check, message):
    result = grid([0.2, 0.5, 0.9], seeds=4, episodes=3)
    with pytest.raises(ValueError, match=message) as error:
        check_claims(claims(check, sentence="s"), result.settings, ())
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("check, message", [
    ({"setting": "qlearning/egreedy/epsilon=0.5", "above": 1},
     r"claims\[0\]\.checks\[0\]: setting=qlearning/egreedy/epsilon=0.5 is invalid: it names"
     " no setting"),
    ({"setting": G1, "metric": "speed", "above": 1},
     r"claims\[0\]\.checks\[0\]: metric='speed' is invalid: allowed are final_return"),
    ({"setting": G1, "metric": "optimal_actions", "above": 0.5},
     "metric='optimal_actions' is invalid: the run does not record it .*--record-optimal"),
    ({"setting": G1, "higher_than": {"epsilon": 0.1}},
     "higher_than=.* is invalid: it is the setting checked"),
    ({"setting": G1, "about": 0.9, "tolerance": "ten"},
     "tolerance='ten' is invalid: must be a finite number"),
    ({"axis": "alpha", "among": {"explorer": "egreedy"}, "best": [0.1]},
     "axis='alpha' is invalid: setting qlearning/egreedy/epsilon=0 has no value of it"),
    ({"setting": G1}, r"needs exactly one comparison"),
    ({"setting": G1, "above": 1, "colour": "red"}, "unknown key 'colour'"),
])
def test_bad_claims_are_one_line(check, message):
    result = grid([0.2, 0.5, 0.9], seeds=4, episodes=3)
    with pytest.raises(ValueError, match=message) as error:
        check_claims(claims(check, sentence="s"), result.settings, ())
    assert "\n" not in str(error.value)


STUDY = """
task = "testbed:10"
instances = "per-agent"
learners = ["sample_average"]
explorers = ["egreedy"]
seeds = 30
episodes = 40
record_optimal = true
[axes]
epsilon = [0, 0.1]
"""
CLAIM = """
[[claims]]
claim = "both end below one optimal action per pull"
[[claims.checks]]
setting = {epsilon = 0.1}
metric = "optimal_actions"
below = 1.01
[[claims.checks]]
setting = "sample_average/egreedy/epsilon=0"
metric = "optimal_actions"
below = 1.01
"""


def test_a_study_scores_its_claims_where_its_results_are(tmp_path, capsys):
    from vdbejax import cli
    from vdbejax.results import io

    config, out = tmp_path / "study.toml", tmp_path / "out"
    config.write_text(STUDY + CLAIM)
    assert cli.main(["run", "--config", str(config), "--out", str(out), "--quiet",
                     "--no-figures"]) == 0
    assert "claim 1: reproduced — both end below" in capsys.readouterr().out
    report = (out / "claims.md").read_text()
    assert "stated before training" in report and "## Claim 1: reproduced" in report
    rows = io.read_csv(out / "claims.csv")
    assert [(r["check"], r["agents"], r["outcome"]) for r in rows] == [
        ("1", "all agents", "holds"), ("2", "all agents", "holds")]
    assert [(r["metric"], r["setting"], r["bound"]) for r in rows] == [
        ("optimal_actions", "sample_average/egreedy/epsilon=0.1", "1.01"),
        ("optimal_actions", "sample_average/egreedy/epsilon=0", "1.01")]
    assert all(float(r["low"]) <= float(r["estimate"]) <= float(r["high"]) < 1.01
               for r in rows)
    meta = io.load_json(out / "meta.json")
    assert meta["claims_digest"] and meta["sweep"]["claims"][0]["claim"].startswith("both")
    # Claims written after the run: scored without training, and said so.
    later = tmp_path / "later.toml"
    later.write_text(CLAIM.replace("below = 1.01", "above = 2", 1))
    (out / "claims.md").unlink()
    assert cli.main(["plot", "--results", str(out), "--claims", str(later)]) == 0
    report = (out / "claims.md").read_text()
    assert "written after the run" in report and "## Claim 1: partly" in report
    assert cli.main(["export", str(out), "--tables", "claims"]) == 0
    exported = io.read_csv(out / "claims_long.csv")
    assert "partly" in {r["claim_verdict"] for r in exported}
    assert exported[0]["metric"] == "optimal_actions" and exported[0]["bound"] == "2"


@pytest.mark.parametrize("claim, message", [
    (CLAIM.replace("epsilon = 0.1", "epsilon = 0.3"), "claim 1 .*setting=.* names no setting"),
    (CLAIM.replace('"optimal_actions"', '"speed"', 1), "metric='speed'"),
    (CLAIM.replace("below = 1.01", "higher_than = {epsilon = 0.1}", 1),
     "is the setting checked"),
])
def test_a_bad_claim_in_a_study_is_one_line_before_training(tmp_path, capsys, claim, message):
    from vdbejax import cli

    config, out = tmp_path / "study.toml", tmp_path / "out"
    config.write_text(STUDY + claim)
    assert cli.main(["run", "--config", str(config), "--out", str(out), "--quiet"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and __import__("re").search(message, lines[0]), lines
    assert not out.exists()
    config.write_text(STUDY.replace("record_optimal = true", "") + CLAIM)
    assert cli.main(["run", "--config", str(config), "--out", str(out), "--quiet"]) == 2
    assert "--record-optimal" in capsys.readouterr().err and not out.exists()


def test_the_testbed_example_states_the_books_claims(tmp_path, capsys):
    """examples/testbed.toml, small: its claims are valid for its settings and scored (the
    full 2,000 testbeds reproduce all four: docs/claims.md)."""
    from pathlib import Path

    from vdbejax import cli
    from vdbejax.results import io

    example = Path(__file__).resolve().parents[1] / "examples" / "testbed.toml"
    out = tmp_path / "testbed"
    assert cli.main(["run", "--config", str(example), "--out", str(out), "--seeds", "40",
                     "--episodes", "60", "--quiet", "--no-figures"]) == 0
    rows = io.read_csv(out / "claims.csv")
    assert sorted({r["claim"] for r in rows}) == ["1", "2", "3", "4"] and len(rows) == 9
    assert "stated before training" in (out / "claims.md").read_text()
