"""The claims format's vocabulary for sets of settings and convergence (ranges and lists of
values in selector tables, ``{every = S}``, ``no_higher_than``, ``worse_than``,
``converges_first``, ``text``, ``requires``), on results built by hand; and the paper's
claims file, which uses it."""
import math
import tomllib

import numpy as np
import pytest

from vdbejax.methods import Setting
from vdbejax.paper.claims import CLAIMS_FILE, paper_claims
from vdbejax.results.claim_scoring import best_row, score_claims, score_rows
from vdbejax.results.claim_spec import Bounds, Every, parse_claims, select
from vdbejax.results.summary import SummaryRow

SIGMAS = (0.01, 0.1, 1.0, 10.0)
BEST = 1.0


def grid(levels, conv=None, seeds=40, episodes=200, spread=0.02):
    """VDBE settings σ ∈ SIGMAS: constant returns around ``levels`` (± spread) from episode
    ``conv[i]`` on (−1 before it: the convergence episode moves with it)."""
    from vdbejax.results.grid_result import GridResult

    rng = np.random.default_rng(0)
    settings = [Setting("qlearning", "vdbe", s) for s in SIGMAS[:len(levels)]]
    level = np.asarray(levels)[:, None] + spread * rng.standard_normal((len(levels), seeds))
    returns = np.repeat(level[..., None], episodes, -1).astype(np.float32)
    for i, start in enumerate(conv or [0] * len(levels)):
        returns[i, :, :start] = -1.0
    meta = {"best_return": BEST, "random_return": -1.0, "num_seeds": seeds,
            "num_episodes": episodes, "max_steps": 10}
    shape = returns.shape
    return GridResult(settings, returns, np.full(shape, 5, np.int32),
                      np.zeros(shape[:2], bool), meta)


def outcomes(result, *checks):
    scored = score_claims(result, parse_claims([{"claim": "c", "checks": list(checks)}]))
    return [c.passed for c in scored.claims[0].checks], scored.claims[0]


VDBE = {"learner": "qlearning", "explorer": "vdbe"}


def test_ranges_and_lists_of_values_select_settings():
    settings = grid([0.9] * 4).settings
    ranged = parse_claims([{"claim": "c", "checks": [
        {"setting": {"every": {**VDBE, "sigma": {"at_least": 0.1, "below": 10}}},
         "near_best": True}]}])[0].checks[0].setting
    assert isinstance(ranged, Every)
    assert dict(ranged.among)["sigma"] == Bounds(at_least=0.1, below=10.0)
    assert select(ranged.among, settings) == [1, 2]
    listed = parse_claims([{"claim": "c", "checks": [
        {"setting": {"every": {"sigma": [0.01, 10]}}, "above": 0}]}])[0].checks[0].setting
    assert isinstance(listed, Every) and select(listed.among, settings) == [0, 3]
    assert select((("sigma", Bounds(above=1.0)),), settings) == [3]


def test_every_holds_only_where_each_setting_holds():
    result = grid([0.99, 0.99, 0.5, 0.99])
    every = {"every": {**VDBE, "sigma": {"at_least": 0.1}}}
    passed, claim = outcomes(result, {"setting": every, "near_best": True},
                             {"setting": {"every": {**VDBE, "sigma": [0.01, 0.1]}},
                              "near_best": True},
                             {"setting": "qlearning/vdbe/sigma=0.1",
                              "higher_than": {"every": {**VDBE, "sigma": [1.0]}}})
    assert passed == [False, True, True]
    # Every setting's interval is shown, in the run's order.
    assert claim.checks[0].description.count("final_return") == 3


def test_no_higher_than_and_worse_than():
    # σ = 0.01 ends low; σ = 0.1 ends high but converges late; σ = 1 and 10 high and early.
    result = grid([0.2, 0.99, 0.99, 0.99], conv=[0, 150, 10, 20])
    low = {"every": {**VDBE, "sigma": {"below": 1}}}
    high = {"every": {**VDBE, "sigma": {"at_least": 1}}}
    passed, claim = outcomes(
        result, {"setting": low, "worse_than": high},
        {"setting": high, "worse_than": low},
        {"setting": {"worst": {**VDBE, "sigma": {"below": 1}}, "by": "final_return"},
         "no_higher_than": "qlearning/vdbe/sigma=1"},
        {"setting": "qlearning/vdbe/sigma=1", "no_higher_than": "qlearning/vdbe/sigma=0.01"})
    assert passed == [True, False, True, False]
    # worse_than shows the latest of the others to converge.
    assert "their latest: qlearning/vdbe/sigma=10 convergence_episode" in \
        claim.checks[0].description


def test_converges_first_leaves_out_rivals_that_do_not_end_near_the_best():
    mine = "qlearning/vdbe/sigma=1"
    check = {"setting": mine, "converges_first": ["qlearning/vdbe/sigma=0.1",
                                                   "qlearning/vdbe/sigma=0.01"]}
    # The early rival σ = 0.01 ends far from the best return: it does not compete.
    assert outcomes(grid([0.2, 0.99, 0.99], conv=[0, 150, 10]), check)[0] == [True]
    assert outcomes(grid([0.99, 0.99, 0.99], conv=[0, 150, 10]), check)[0] == [False]
    assert outcomes(grid([0.2, 0.99, 0.5], conv=[0, 150, 10]), check)[0] == [False]
    # Converging alike, their intervals overlap: undecided.
    passed, claim = outcomes(grid([0.2, 0.99, 0.99], conv=[0, 10, 10]), check)
    assert passed == [None], claim.checks[0].description
    passed, claim = outcomes(grid([0.2, 0.99, 0.99], conv=[0, 150, 10]), check)
    assert "(not near best)" in claim.checks[0].description


def test_text_words_a_check_and_requires_leaves_it_out():
    result = grid([0.99, 0.99])
    claims = parse_claims([{"claim": "c", "checks": [
        {"text": "σ = 0.01 is good", "setting": "qlearning/vdbe/sigma=0.01", "near_best": True},
        {"optional": True, "requires": [{"explorer": "softmax"}],
         "setting": "qlearning/vdbe/sigma=0.1", "near_best": True}]}])
    (claim,) = score_claims(result, claims).claims
    assert len(claim.checks) == 1
    assert claim.checks[0].description.startswith("σ = 0.01 is good (qlearning/vdbe/sigma=0.01")


@pytest.mark.parametrize("check, message", [
    ({"setting": {"every": {"sigma": {"at_leest": 1}}}, "near_best": True},
     r"claims\[0\].checks\[0\]: setting.every.sigma=\{'at_leest': 1\} is invalid: a range"),
    ({"setting": {"sigma": {"below": "x"}}, "near_best": True},
     r"setting.sigma.below='x' is invalid: must be a finite number"),
    ({"setting": {"every": {"sigma": 1}, "by": "final_return"}, "near_best": True},
     r"\{every = S\} takes no other key"),
    ({"setting": {"every": {"sigma": 1}}, "beats": "a/b/c=1"},
     r"setting=.* is invalid with beats: name one setting"),
    ({"setting": "a/b/c=1", "worse_than": "a/b/c=2", "metric": "final_iqm"},
     r"metric='final_iqm' is invalid with worse_than"),
    ({"setting": "a/b/c=1", "converges_first": []},
     r"converges_first=\[\] is invalid: must be a non-empty list"),
    ({"setting": "a/b/c=1", "near_best": True, "requires": ["a/b/c=2"]},
     r"requires=\['a/b/c=2'\] is invalid: .* with optional = true"),
    ({"setting": "a/b/c=1", "near_best": True, "text": ""},
     r"text='' is invalid: must be the check in words"),
    ({"all": [{"setting": "a/b/c=1", "near_best": True, "text": "x"}]},
     r"'text' is invalid inside a combination"),
])
def test_bad_vocabulary_is_one_line(check, message):
    with pytest.raises(ValueError, match=message) as error:
        parse_claims([{"claim": "c", "checks": [check]}])
    assert "\n" not in str(error.value)


def test_an_every_that_selects_nothing_is_refused_before_training():
    claims = parse_claims([{"claim": "c", "checks": [
        {"setting": {"every": {**VDBE, "sigma": {"above": 100}}}, "near_best": True}]}])
    with pytest.raises(ValueError, match=r"claim 1 \('c'\): claims\[0\].checks\[0\]:"
                                         r" setting.every=.* no setting of the run"):
        score_claims(grid([0.9, 0.9]), claims)


def test_best_row_is_the_ranked_selectors_rule():
    def row(config, iqm, conv):
        return SummaryRow(config=config, learner="qlearning", explorer="vdbe",
                          param=SIGMAS[config], final_return=iqm, final_ci_low=iqm,
                          final_ci_high=iqm, final_iqm=iqm, convergence_episode=conv,
                          convergence_ci_low=conv, convergence_ci_high=conv,
                          truncated_fraction=0.0, mean_length=5.0, nonfinite_agents=0)
    # Within 0.01 of the highest IQM the first to converge wins, then the better ranked.
    assert best_row([row(0, 0.90, 50), row(1, 0.895, 20), row(2, 0.80, 5)]).config == 1
    assert best_row([row(0, 0.90, 50), row(1, 0.88, 20)]).config == 0
    assert best_row([row(0, 0.90, math.inf), row(1, 0.899, math.inf)]).config == 0


def test_the_papers_claims_file_parses_and_ships_as_package_data():
    claims = paper_claims()
    assert [len(c.checks) for c in claims] == [4, 4, 5, 12, 9, 8]
    assert all(check.optional and check.text for c in claims for check in c.checks)
    assert CLAIMS_FILE.parent.name == "paper" and CLAIMS_FILE.suffix == ".toml"
    with open("pyproject.toml", "rb") as f:
        data = tomllib.load(f)["tool"]["setuptools"]["package-data"]
    assert CLAIMS_FILE.name in data["vdbejax.paper"]


def test_a_malformed_copy_of_the_papers_claims_is_one_line(tmp_path):
    text = CLAIMS_FILE.read_text()
    broken = text.replace('metric = "convergence_episode"', 'metric = "convergence"', 1)
    assert broken != text
    data = tomllib.loads(broken)["claims"]
    with pytest.raises(ValueError) as error:
        parse_claims(data)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith("claims[4].checks[1]: metric='convergence' is invalid")
    # A setting the paper's grid lacks is named with its claim before anything is scored.
    moved = tomllib.loads(text.replace("sigma = 100", "sigma = 1000", 1))["claims"]
    moved[3]["checks"][5].pop("optional")
    rows = [SummaryRow(config=0, learner="qlearning", explorer="vdbe_softmax", param=100.0,
                       final_return=0.86, final_ci_low=0.85, final_ci_high=0.86,
                       final_iqm=0.86, convergence_episode=100.0, convergence_ci_low=90.0,
                       convergence_ci_high=110.0, truncated_fraction=0.0, mean_length=5.0,
                       nonfinite_agents=0)]
    with pytest.raises(ValueError, match=r"^claim 4 \('VDBE-Softmax: good for every σ tried"
                                         r".*'\): claims\[3\].checks\[5\]: setting=.*sigma ="
                                         r" 1000.* no setting of the run"):
        score_rows(rows, parse_claims(moved), 0.86)
