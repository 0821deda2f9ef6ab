"""Every claim check fed hand-made summaries on each side of its threshold and with
intervals that straddle it (undecided), with the heavy-tailed cases; replicates' counts
and the headline rule."""
import dataclasses

import pytest

from vdbejax.methods.agents import paper_settings
from vdbejax.paper.claims import paper_claims
from vdbejax.paper.report import render_report
from vdbejax.results.claim_scoring import score_rows
from vdbejax.results.claim_spec import ABOUT, NEAR, TIE
from vdbejax.results.summary import SummaryRow
from vdbejax.results.verdicts import stable_count

BEST = 0.86
SIGMAS = (0.001, 0.01, 0.1, 1.0, 10.0, 100.0)  # the paper's VDBE σ
EPS = 0.002  # well inside TIE (0.01) and NEAR (0.05), well above float noise
HALF = 0.005  # half the width of every final return's interval (unless a test sets it)
CLEAR = HALF + EPS  # a value this far from a bound has its interval on one side of it


def paper_scores(rows, best, replicates=None):
    """The paper's claims file scored on summary rows (the pooled ones, with replicates')."""
    return score_rows(rows, paper_claims(), best, replicates).claims


def rows(values=None):
    """The paper's 46 settings, every one ending at the best return at episode 300;
    ``values[(learner, explorer, param)] = {field: value}`` overrides (``final`` sets the
    mean and the IQM, with an interval of ±``HALF``; ``conv`` the convergence episode and
    its interval, of zero width)."""
    out = []
    for config, s in enumerate(paper_settings()):
        change = dict((values or {}).get((s.learner, s.explorer, s.param), {}))
        final = change.pop("final", BEST)
        conv = change.pop("conv", 300)
        row = SummaryRow(config=config, learner=s.learner, explorer=s.explorer, param=s.param,
                         final_return=final, final_ci_low=final - HALF,
                         final_ci_high=final + HALF, final_iqm=final, convergence_episode=conv,
                         convergence_ci_low=float(conv), convergence_ci_high=float(conv),
                         truncated_fraction=0.0, mean_length=20.0, nonfinite_agents=0)
        out.append(dataclasses.replace(row, **change))
    return out


def egreedy(learner, finals):
    return {(learner, "egreedy", e): {"final": f} for e, f in finals.items()}


def check(table, number, text):
    claim = next(c for c in paper_scores(table, BEST) if c.number == number)
    (found,) = [c for c in claim.checks if text in c.description]
    return found.passed


# ε-greedy finals where 0.05 and 0.1 are best and the best is about 0.7 / 0.6.
Q_EPS = {0.01: 0.5, 0.05: 0.7, 0.1: 0.65, 0.15: 0.4, 0.2: 0.3}
S_EPS = {0.01: 0.4, 0.05: 0.6, 0.1: 0.55, 0.15: 0.3, 0.2: 0.2}


def claim1_table(q=Q_EPS, s=S_EPS, extra=None):
    return rows({**egreedy("qlearning", q), **egreedy("sarsa", s), **(extra or {})})


def test_claim_1_best_epsilon_each_side_and_undecided():
    assert check(claim1_table(), 1, "Q-learning: the best ε are") is True
    # ε = 0.01's interval above that of 0.1 (0.65): fails; below it: holds; overlapping:
    # undecided, whichever way the point values lean.
    q = "Q-learning: the best ε"
    assert check(claim1_table({**Q_EPS, 0.01: 0.65 + 2 * CLEAR}), 1, q) is False
    assert check(claim1_table({**Q_EPS, 0.01: 0.65 - 2 * CLEAR}), 1, q) is True
    assert check(claim1_table({**Q_EPS, 0.01: 0.65 + EPS}), 1, q) is None
    assert check(claim1_table({**Q_EPS, 0.01: 0.65 - EPS}), 1, q) is None


def test_claim_1_a_heavy_tail_leaves_the_best_epsilon_undecided():
    # One looping agent sinks 0.05's mean and widens its interval over the others': the
    # intervals cannot rank it, whatever its IQM.
    tail = {("qlearning", "egreedy", 0.05): {"final": -4.0, "final_iqm": 0.7,
                                            "final_ci_low": -14.0, "final_ci_high": 0.86}}
    assert check(claim1_table(extra=tail), 1, "Q-learning: the best ε are") is None
    wide = {("qlearning", "egreedy", 0.01): {"final": 0.5, "final_iqm": 0.8,
                                            "final_ci_low": -14.0, "final_ci_high": 0.86}}
    assert check(claim1_table(extra=wide), 1, "Q-learning: the best ε are") is None


@pytest.mark.parametrize("learner, stated", [("qlearning", 0.7), ("sarsa", 0.6)])
def test_claim_1_about_bound_is_two_sided(learner, stated):
    base = dict(Q_EPS if learner == "qlearning" else S_EPS)
    name = "Q-learning" if learner == "qlearning" else "SARSA"

    def passes(best):
        finals = {**base, 0.05: best, 0.1: best - 0.05}
        table = claim1_table(**({"q": finals} if learner == "qlearning" else {"s": finals}))
        return check(table, 1, f"{name}: best ε's final return")

    low, high = (1 - ABOUT) * stated, (1 + ABOUT) * stated
    assert passes(low + CLEAR) is True and passes(high - CLEAR) is True
    # Above "about" fails; so does a collapsed curve far below it (−0.68 < 0.6 is no pass).
    assert passes(high + CLEAR) is False
    assert passes(low - CLEAR) is False and passes(-0.68) is False
    assert passes(low) is None and passes(high) is None  # the interval straddles an end


def test_claim_2_best_tau_and_near():
    assert check(rows(), 2, "Q-learning: the best τ are") is None  # all at 0.86: no order
    apart = {("qlearning", "softmax", t): {"final": 0.5} for t in (0.01, 0.1, 1.0, 10.0)}
    assert check(rows(apart), 2, "Q-learning: the best τ are") is True
    above = {**apart, ("qlearning", "softmax", 0.01): {"final": BEST},
             ("qlearning", "softmax", 0.001): {"final": BEST - 2 * CLEAR}}
    assert check(rows(above), 2, "Q-learning: the best τ are") is False
    # The heavy-tailed τ = 1e-4: worst mean, wide interval, low IQM: not decided
    # best, and its mean's interval straddles "near 0.86".
    loop = {**apart, ("qlearning", "softmax", 0.0001): {
        "final": -4.18, "final_iqm": 0.5, "final_ci_low": -14.3, "final_ci_high": 0.86}}
    assert check(rows(loop), 2, "Q-learning: the best τ are") is None
    assert check(rows(loop), 2, "Q-learning: τ ∈") is None
    near = BEST - NEAR
    for final, outcome in ((near + CLEAR, True), (near - CLEAR, False), (near, None)):
        assert check(rows({("sarsa", "softmax", 0.001): {"final": final}}), 2,
                     "SARSA: τ ∈") is outcome


def vdbe(learner, param, **fields):
    return {(learner, "vdbe", param): fields}


def test_claim_3_good_sigma_near_each_side():
    near = BEST - NEAR
    for final, outcome in ((near + CLEAR, True), (near - CLEAR, False), (near, None)):
        assert check(rows(vdbe("sarsa", 1.0, final=final)), 3, "SARSA: every σ ≥ 1") is outcome


def test_claim_3_low_sigma_ends_lower_or_later_is_not_vacuous():
    low = {**vdbe("qlearning", 0.01, final=BEST - 2 * CLEAR),
           **vdbe("qlearning", 0.001, final=0.0)}
    assert check(rows(low), 3, "Q-learning: every σ < 0.1") is True
    # Intervals overlapping the good σ's and converging at the same episode: undecided.
    tied = {**low, **vdbe("qlearning", 0.01, final=BEST - EPS)}
    assert check(rows(tied), 3, "Q-learning: every σ < 0.1") is None
    # ... but converging after every good σ (intervals apart): holds.
    later = {**low, **vdbe("qlearning", 0.01, final=BEST - EPS, conv=301)}
    assert check(rows(later), 3, "Q-learning: every σ < 0.1") is True
    # Ending higher and converging earlier than a good σ: fails.
    early = {**low, **vdbe("qlearning", 0.01, final=BEST + 2 * CLEAR, conv=200)}
    assert check(rows(early), 3, "Q-learning: every σ < 0.1") is False
    # The good σ collapsed too: a low σ ending as low is not decided "lower".
    collapsed = {(lr, "vdbe", p): {"final": -1.0} for lr in ("qlearning", "sarsa")
                 for p in SIGMAS}
    assert check(rows(collapsed), 3, "SARSA: every σ < 1") is None


@pytest.mark.parametrize("sarsa, passed", [(-1.073 - 2 * CLEAR, True), (-1.073 - EPS, None),
                                           (-1.073 + EPS, None), (-1.073 + 2 * CLEAR, False)])
def test_claim_3_worst_with_sarsa_from_the_intervals(sarsa, passed):
    table = rows({**vdbe("qlearning", 0.001, final=-1.073), **vdbe("sarsa", 0.001, final=sarsa)})
    assert check(table, 3, "too-low σ is worst with SARSA") is passed


def test_claim_4_each_sigma_near_each_side():
    near = BEST - NEAR
    key = ("sarsa", "vdbe_softmax", 0.1)
    for final, outcome in ((near + CLEAR, True), (near - CLEAR, False), (near, None)):
        assert check(rows({key: {"final": final}}), 4, "SARSA σ=0.1 ends") is outcome


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


def test_claim_5_about_episodes_with_an_interval_across_the_range_is_undecided():
    wide = {(lr, "vdbe", p): {"convergence_ci_low": 250.0, "convergence_ci_high": 400.0}
            for lr in ("qlearning", "sarsa") for p in SIGMAS}
    assert check(claim5(PAPER, wide), 5, "Q-learning: best vdbe converges after about") is None


def test_claim_5_no_later_than_a_rival_is_decided_by_the_intervals():
    # The example: VDBE-Softmax at 121 against softmax's 120, intervals overlapping:
    # neither "no later" nor "later" — undecided, not unticked.
    overlap = {(lr, e, p): {"convergence_ci_low": c - 3.0, "convergence_ci_high": c + 3.0}
               for lr, e, p, c in ((s.learner, s.explorer, s.param, 121 if s.explorer ==
                                    "vdbe_softmax" else 120) for s in paper_settings())
               if e in ("softmax", "vdbe_softmax")}
    table = claim5({**PAPER, "vdbe_softmax": 121, "softmax": 120}, overlap)
    assert check(table, 5, "SARSA: VDBE-Softmax ends near the best return") is None
    assert check(claim5({**PAPER, "softmax": 280}), 5, "SARSA: VDBE-Softmax ends near") is False
    assert check(claim5(PAPER), 5, "SARSA: VDBE-Softmax ends near") is True


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
    assert check(claim5(PAPER, apart), 5,
                 "Q-learning: best vdbe converges after about 350") is False


def test_claim_5_egreedy_worse_return_from_the_intervals():
    def passes(final):
        extra = {("qlearning", "egreedy", 0.05): {"final": final}}
        return check(claim5(PAPER, extra), 5, "ε-greedy converges about as fast")

    assert passes(BEST - 2 * CLEAR) is True and passes(BEST - EPS) is None
    assert passes(BEST + 2 * CLEAR) is False


def test_claim_6_each_side():
    near = BEST - NEAR
    low = {("sarsa", "vdbe", p): {"final": near - CLEAR} for p in SIGMAS}
    assert check(rows(low), 6, "SARSA: best vdbe (") is False
    assert check(rows({**low, ("sarsa", "vdbe", 10.0): {"final": near + CLEAR}}), 6,
                 "SARSA: best vdbe (") is True
    assert check(rows({**low, ("sarsa", "vdbe", 10.0): {"final": near}}), 6,
                 "SARSA: best vdbe (") is None
    assert check(rows(), 6, "SARSA: ε-greedy's best") is False  # at 0.86: not lower
    assert check(rows(egreedy("sarsa", {e: near - CLEAR for e in S_EPS})), 6,
                 "SARSA: ε-greedy's best") is True
    assert check(rows(egreedy("sarsa", {e: near for e in S_EPS})), 6,
                 "SARSA: ε-greedy's best") is None


LOW_EGREEDY = {**egreedy("qlearning", Q_EPS), **egreedy("sarsa", S_EPS)}


def test_replicates_count_each_check_and_set_the_headline():
    pooled = good = rows(LOW_EGREEDY)  # claim 6 reproduced
    # Every SARSA VDBE σ collapsed: claim 6 loses a check.
    bad = rows({**LOW_EGREEDY, **{("sarsa", "vdbe", p): {"final": 0.0}
                                  for p in SIGMAS}})
    for n_bad, headline in ((0, None), (1, None), (2, "unstable")):
        replicates = [bad] * n_bad + [good] * (5 - n_bad)
        claims = {c.number: c for c in paper_scores(pooled, BEST, replicates=replicates)}
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
    claims = paper_scores(rows(LOW_EGREEDY), BEST, replicates=replicates)
    meta = {"num_seeds": 100, "agents_per_replicate": 20, "num_episodes": 1000, "seed": 0}
    report = render_report(claims, meta, BEST)
    assert "5 replicates × 20 agents (pooled 100)" in report
    assert "(4 of 5 when all do)" in report
    assert "Claim 6: its verdict flips: partly in 2, reproduced in 3." in report
    assert "holds in 3 of 5: SARSA: best vdbe (" in report
    assert "## Claim 6: unstable (pooled reproduced; 3 of 5 replicates agree)" in report
    steady = render_report(paper_scores(rows(), BEST, replicates=[rows()] * 5), meta, BEST)
    assert "None: every check holds in all replicates that decide it or in none." in steady


def test_undecided_checks_are_reported_and_do_not_make_a_claim_unstable():
    # Claim 6 decided on the pooled agents; in two replicates (smaller runs) SARSA's best
    # VDBE straddles "near": undecided there, which neither agrees nor flips.
    good = rows(LOW_EGREEDY)
    near = BEST - NEAR
    small = rows({**LOW_EGREEDY, **{("sarsa", "vdbe", p): {"final": near} for p in SIGMAS}})
    claims = {c.number: c for c in paper_scores(good, BEST, replicates=[small] * 2 + [good] * 3)}
    assert claims[6].replicate_verdicts.count("undecided") == 2
    assert claims[6].verdict == claims[6].pooled_verdict == "reproduced"
    check6 = next(k for k in claims[6].checks if "SARSA: best vdbe (" in k.description)
    assert (check6.replicates_passed, check6.replicates_undecided) == (3, 2)
    assert not check6.flips
    # Undecided on the pooled agents: the claim is undecided and the report says why.
    pooled = paper_scores(small, BEST)
    claim6 = next(c for c in pooled if c.number == 6)
    assert claim6.verdict == "undecided" and claim6.undecided_count == 1
    meta = {"num_seeds": 20, "num_episodes": 1000, "seed": 0}
    report = render_report(pooled, meta, BEST)
    assert "claim 6 (1)" in report and "**Undecided.** " in report
    assert "this run (20 agents per setting) is too small to decide them" in report
    assert "  - [?] SARSA: best vdbe (" in report
    assert "[?] undecided (they overlap" in report


def test_replicates_with_other_settings_are_refused():
    fewer = [r for r in rows() if r.explorer != "vdbe"]
    with pytest.raises(ValueError, match="replicates: replicate 1's rows give"):
        paper_scores(rows(), BEST, replicates=[rows(), fewer])
