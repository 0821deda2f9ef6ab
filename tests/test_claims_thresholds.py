"""Every claim check fed hand-made summaries on each side of its threshold, with the tied
and heavy-tailed cases; replicates' counts and the headline rule."""
import dataclasses

import pytest

from vdbejax.methods.agents import paper_settings
from vdbejax.paper.claims import ABOUT, NEAR, TIE, evaluate_claims, stable_count
from vdbejax.paper.report import render_report
from vdbejax.results.summary import SummaryRow

BEST = 0.86
SIGMAS = (0.001, 0.01, 0.1, 1.0, 10.0, 100.0)  # the paper's VDBE σ
EPS = 0.002  # well inside TIE (0.01) and NEAR (0.05), well above float noise


def rows(values=None):
    """The paper's 46 settings, every one ending at the best return at episode 300;
    ``values[(learner, explorer, param)] = {field: value}`` overrides (``final`` sets the
    mean and the IQM, ``conv`` the convergence episode and its interval)."""
    out = []
    for config, s in enumerate(paper_settings()):
        change = dict((values or {}).get((s.learner, s.explorer, s.param), {}))
        final = change.pop("final", BEST)
        conv = change.pop("conv", 300)
        row = SummaryRow(config=config, learner=s.learner, explorer=s.explorer, param=s.param,
                         final_return=final, final_ci_low=final - 0.01,
                         final_ci_high=final + 0.01, final_iqm=final, convergence_episode=conv,
                         convergence_ci_low=float(conv), convergence_ci_high=float(conv),
                         truncated_fraction=0.0, mean_length=20.0, nonfinite_agents=0)
        out.append(dataclasses.replace(row, **change))
    return out


def egreedy(learner, finals):
    return {(learner, "egreedy", e): {"final": f} for e, f in finals.items()}


def check(table, number, text):
    claim = next(c for c in evaluate_claims(table, BEST) if c.number == number)
    (found,) = [c for c in claim.checks if text in c.description]
    return found.passed


# ε-greedy finals where 0.05 and 0.1 are best and the best is about 0.7 / 0.6.
Q_EPS = {0.01: 0.5, 0.05: 0.7, 0.1: 0.65, 0.15: 0.4, 0.2: 0.3}
S_EPS = {0.01: 0.4, 0.05: 0.6, 0.1: 0.55, 0.15: 0.3, 0.2: 0.2}


def claim1_table(q=Q_EPS, s=S_EPS, extra=None):
    return rows({**egreedy("qlearning", q), **egreedy("sarsa", s), **(extra or {})})


def test_claim_1_best_epsilon_each_side_and_tie():
    assert check(claim1_table(), 1, "Q-learning: the best ε are")
    # ε = 0.01 above the worse of the two by more than a tie: fails; within a tie: holds.
    assert not check(claim1_table({**Q_EPS, 0.01: 0.65 + TIE + EPS}), 1, "Q-learning: the best ε")
    assert check(claim1_table({**Q_EPS, 0.01: 0.65 + TIE - EPS}), 1, "Q-learning: the best ε")


def test_claim_1_best_epsilon_is_ranked_by_iqm_not_a_heavy_tail():
    # One looping agent sinks 0.05's mean (and widens its interval) but not its IQM.
    tail = {("qlearning", "egreedy", 0.05): {"final": -4.0, "final_iqm": 0.7,
                                            "final_ci_low": -14.0, "final_ci_high": 0.86}}
    assert check(claim1_table(extra=tail), 1, "Q-learning: the best ε are")
    # A wide interval does not make a setting best: 0.01's IQM is above, so it fails.
    wide = {("qlearning", "egreedy", 0.01): {"final": 0.5, "final_iqm": 0.8,
                                            "final_ci_low": -14.0, "final_ci_high": 0.86}}
    assert not check(claim1_table(extra=wide), 1, "Q-learning: the best ε are")


@pytest.mark.parametrize("learner, stated", [("qlearning", 0.7), ("sarsa", 0.6)])
def test_claim_1_about_bound_is_two_sided(learner, stated):
    base = dict(Q_EPS if learner == "qlearning" else S_EPS)
    name = "Q-learning" if learner == "qlearning" else "SARSA"

    def passes(best):
        finals = {**base, 0.05: best, 0.1: best - 0.05}
        table = claim1_table(**({"q": finals} if learner == "qlearning" else {"s": finals}))
        return check(table, 1, f"{name}: best ε's final return")

    for inside in ((1 - ABOUT) * stated + EPS, (1 + ABOUT) * stated - EPS):
        assert passes(inside)
    # Above "about" fails; so does a collapsed curve far below it (−0.68 < 0.6 is no pass).
    assert not passes((1 + ABOUT) * stated + EPS)
    assert not passes((1 - ABOUT) * stated - EPS) and not passes(-0.68)


def test_claim_2_best_tau_and_near():
    assert check(rows(), 2, "Q-learning: the best τ are")
    above = {("qlearning", "softmax", 0.01): {"final": BEST},
             ("qlearning", "softmax", 0.001): {"final": BEST - TIE - EPS}}
    assert not check(rows(above), 2, "Q-learning: the best τ are")
    tied = {("qlearning", "softmax", 0.001): {"final": BEST - TIE + EPS}}
    assert check(rows(tied), 2, "Q-learning: the best τ are")
    # The heavy-tailed τ = 1e-4: worst mean, wide interval, low IQM: not best.
    loop = {("qlearning", "softmax", 0.0001): {"final": -4.18, "final_iqm": 0.5,
                                              "final_ci_low": -14.3, "final_ci_high": 0.86}}
    assert not check(rows(loop), 2, "Q-learning: the best τ are")
    assert not check(rows(loop), 2, "Q-learning: τ ∈")  # its mean is not near 0.86
    near = BEST - NEAR
    assert check(rows({("sarsa", "softmax", 0.001): {"final": near + EPS}}), 2, "SARSA: τ ∈")
    assert not check(rows({("sarsa", "softmax", 0.001): {"final": near - EPS}}), 2,
                     "SARSA: τ ∈")


def vdbe(learner, param, **fields):
    return {(learner, "vdbe", param): fields}


def test_claim_3_good_sigma_near_each_side():
    near = BEST - NEAR
    assert check(rows(vdbe("sarsa", 1.0, final=near + EPS)), 3, "SARSA: every σ ≥ 1")
    assert not check(rows(vdbe("sarsa", 1.0, final=near - EPS)), 3, "SARSA: every σ ≥ 1")


def test_claim_3_low_sigma_ends_lower_or_later_is_not_vacuous():
    low = {**vdbe("qlearning", 0.01, final=BEST - TIE - EPS),
           **vdbe("qlearning", 0.001, final=0.0)}
    assert check(rows(low), 3, "Q-learning: every σ < 0.1")
    # Tied with the good σ and converging no later: not "lower or later".
    tied = {**low, **vdbe("qlearning", 0.01, final=BEST - TIE + EPS)}
    assert not check(rows(tied), 3, "Q-learning: every σ < 0.1")
    # Tied but converging after every good σ: holds.
    later = {**low, **vdbe("qlearning", 0.01, final=BEST - TIE + EPS, conv=301)}
    assert check(rows(later), 3, "Q-learning: every σ < 0.1")
    # The good σ collapsed too: a low σ ending as low is not "lower".
    collapsed = {(lr, "vdbe", p): {"final": -1.0} for lr in ("qlearning", "sarsa")
                 for p in SIGMAS}
    assert not check(rows(collapsed), 3, "SARSA: every σ < 1")


@pytest.mark.parametrize("sarsa, passed", [(-1.07, True), (-1.073 + TIE - EPS, True),
                                           (-1.073 + TIE + EPS, False), (-1.2, True)])
def test_claim_3_worst_with_sarsa_counts_a_tie(sarsa, passed):
    table = rows({**vdbe("qlearning", 0.001, final=-1.073), **vdbe("sarsa", 0.001, final=sarsa)})
    assert check(table, 3, "too-low σ is worst with SARSA") is passed


def test_claim_4_each_sigma_near_each_side():
    near = BEST - NEAR
    key = ("sarsa", "vdbe_softmax", 0.1)
    assert check(rows({key: {"final": near + EPS}}), 4, "SARSA σ=0.1 ends")
    assert not check(rows({key: {"final": near - EPS}}), 4, "SARSA σ=0.1 ends")


def claim5(conv, extra=None):
    """Every learner's explorers converging at ``conv[explorer]`` (all settings)."""
    values = {(s.learner, s.explorer, s.param): {"conv": conv[s.explorer]}
              for s in paper_settings()}
    values.update({(lr, "egreedy", e): {**values[(lr, "egreedy", e)], "final": 0.6}
                   for lr in ("qlearning", "sarsa") for e in Q_EPS})
    for key, fields in (extra or {}).items():
        values[key] = {**values[key], **fields}
    return rows(values)


PAPER = {"vdbe_softmax": 290, "softmax": 350, "vdbe": 350, "egreedy": 300}


@pytest.mark.parametrize("factor, passed", [(1 - ABOUT + 0.01, True), (1 + ABOUT - 0.01, True),
                                            (1 - ABOUT - 0.01, False), (1 + ABOUT + 0.01, False)])
def test_claim_5_about_episodes_each_side(factor, passed):
    table = claim5({**PAPER, "vdbe": round(350 * factor)})
    assert check(table, 5, "Q-learning: best vdbe converges after about 350") is passed


def test_claim_5_best_vdbe_tie_goes_to_the_first_to_converge():
    # σ = 0.01 and σ = 0.1 tied at the top (within TIE): the earlier, σ = 0.1 (episode
    # 323), is the best VDBE, not σ = 0.01 (553).
    tied = {("qlearning", "vdbe", 0.01): {"conv": 553},
            ("qlearning", "vdbe", 0.1): {"conv": 323, "final": BEST - TIE + EPS}}
    for p in (0.001, 1.0, 10.0, 100.0):
        tied[("qlearning", "vdbe", p)] = {"final": 0.5}
    assert check(claim5(PAPER, tied), 5, "Q-learning: best vdbe converges after about 350")
    # Beyond a tie the higher return wins, however late it converges.
    apart = {**tied, ("qlearning", "vdbe", 0.1): {"conv": 323, "final": BEST - TIE - EPS}}
    assert not check(claim5(PAPER, apart), 5,
                     "Q-learning: best vdbe converges after about 350")


def test_claim_5_egreedy_worse_return_is_beyond_a_tie():
    def passes(final):
        extra = {("qlearning", "egreedy", 0.05): {"final": final}}
        return check(claim5(PAPER, extra), 5, "ε-greedy converges about as fast")

    assert passes(BEST - TIE - EPS) and not passes(BEST - TIE + EPS)


def test_claim_6_each_side():
    near = BEST - NEAR
    low = {("sarsa", "vdbe", p): {"final": near - EPS} for p in SIGMAS}
    assert not check(rows(low), 6, "SARSA: best vdbe (")
    assert check(rows({**low, ("sarsa", "vdbe", 10.0): {"final": near + EPS}}), 6,
                 "SARSA: best vdbe (")
    assert not check(rows(), 6, "SARSA: ε-greedy's best")  # ε-greedy at 0.86 is not lower
    assert check(rows(egreedy("sarsa", {e: near - EPS for e in S_EPS})), 6,
                 "SARSA: ε-greedy's best")


LOW_EGREEDY = {**egreedy("qlearning", Q_EPS), **egreedy("sarsa", S_EPS)}


def test_replicates_count_each_check_and_set_the_headline():
    pooled = good = rows(LOW_EGREEDY)  # claim 6 reproduced
    # Every SARSA VDBE σ collapsed: claim 6 loses a check.
    bad = rows({**LOW_EGREEDY, **{("sarsa", "vdbe", p): {"final": 0.0}
                                  for p in SIGMAS}})
    for n_bad, headline in ((0, None), (1, None), (2, "unstable")):
        replicates = [bad] * n_bad + [good] * (5 - n_bad)
        claims = {c.number: c for c in evaluate_claims(pooled, BEST, replicates=replicates)}
        claim6 = claims[6]
        assert claim6.replicate_verdicts.count("partly") == n_bad
        assert claim6.agreeing == 5 - n_bad
        assert claim6.verdict == (headline or claim6.pooled_verdict)
        check6 = next(k for k in claim6.checks if "SARSA: best vdbe (" in k.description)
        assert (check6.replicates_passed, check6.replicates) == (5 - n_bad, 5)
        assert check6.flips is (n_bad > 0)
    assert stable_count(5) == 4 and stable_count(1) == 1 and stable_count(3) == 3


def test_report_names_the_flips_and_states_the_rule():
    bad = rows({**LOW_EGREEDY, **{("sarsa", "vdbe", p): {"final": 0.0}
                                  for p in SIGMAS}})
    replicates = [bad] * 2 + [rows(LOW_EGREEDY)] * 3
    claims = evaluate_claims(rows(LOW_EGREEDY), BEST, replicates=replicates)
    meta = {"num_seeds": 100, "agents_per_replicate": 20, "num_episodes": 1000, "seed": 0}
    report = render_report(claims, meta, BEST)
    assert "5 replicates × 20 agents (pooled 100)" in report
    assert "at least 4 of the 5 replicates" in report
    assert "Claim 6: its verdict flips: partly in 2, reproduced in 3." in report
    assert "holds in 3 of 5: SARSA: best vdbe (" in report
    assert "## Claim 6: unstable (pooled reproduced; 3 of 5 replicates agree)" in report
    steady = render_report(evaluate_claims(rows(), BEST, replicates=[rows()] * 5), meta, BEST)
    assert "None: every check holds in all replicates or in none." in steady


def test_replicates_with_other_settings_are_refused():
    fewer = [r for r in rows() if r.explorer != "vdbe"]
    with pytest.raises(ValueError, match="replicates: replicate 1's rows give"):
        evaluate_claims(rows(), BEST, replicates=[rows(), fewer])
