"""Typed summary rows: built by summarize, written to summary.csv and parsed back once;
the claims as a list of one function per claim."""
import dataclasses
import math

import matplotlib.pyplot as plt
import numpy as np
import pytest
from synthetic_grid import BEST, synthetic_grid

from vdbejax.paper.claims import paper_claims
from vdbejax.results import plotting
from vdbejax.results.analysis import summarize, summary_columns
from vdbejax.results.claim_scoring import score_claims, score_rows
from vdbejax.results.summary import (
    SUMMARY_COLUMNS,
    SummaryRow,
    read_summary,
    summary_row,
    summary_rows,
    write_summary,
)
from vdbejax.studies import scaling


@pytest.fixture(scope="module")
def grid():
    return synthetic_grid()


@pytest.fixture(scope="module")
def rows(grid):
    return summarize(grid)


def test_summarize_builds_typed_rows(rows):
    assert all(isinstance(r, SummaryRow) for r in rows)
    r = rows[0]
    assert isinstance(r.config, int) and isinstance(r.convergence_episode, float)
    # A median over agents: a whole episode or halfway between two.
    assert all(x.convergence_episode == np.inf or (2 * x.convergence_episode).is_integer()
               for x in rows)
    assert all(0 <= x.agents_converged <= 4 and x.convergence_budget == 120 for x in rows)
    assert isinstance(r.nonfinite_agents, int)
    assert all(isinstance(v, float) for v in (r.final_return, r.final_ci_low, r.final_ci_high,
                                              r.final_iqm, r.convergence_ci_low,
                                              r.convergence_ci_high, r.truncated_fraction,
                                              r.mean_length))
    assert isinstance(r.param, float) and r.hyperparameters == "{}"
    assert r.episodes_cut is None and r.agents_cut is None  # not a capped task
    assert [r.config for r in rows] == list(range(len(rows)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.final_return = 0.0


def test_a_row_reads_as_the_former_dict(rows):
    r = rows[3]
    view = dict(r)
    assert list(view) == SUMMARY_COLUMNS[:4] + ["hyperparameters"] + SUMMARY_COLUMNS[4:]
    assert view == r.as_dict()
    assert r["final_return"] == r.final_return and r.get("episodes_cut") is None
    assert "episodes_cut" not in r and len(r) == len(view)
    assert "no_such_column" not in r and r.get("no_such_column") is None
    default = dataclasses.replace(r, param=None)
    assert default["param"] == "" and default.param is None


def test_csv_round_trip(grid, rows, tmp_path):
    path = tmp_path / "summary.csv"
    write_summary(path, rows, summary_columns(grid))
    back = read_summary(path)
    assert len(back) == len(rows)
    for a, b in zip(rows, back):
        assert (a.config, a.learner, a.explorer, a.param, a.convergence_episode,
                a.nonfinite_agents) == (b.config, b.learner, b.explorer, b.param,
                                        b.convergence_episode, b.nonfinite_agents)
        for name in ("final_return", "final_ci_low", "final_ci_high", "final_iqm",
                     "convergence_ci_low", "convergence_ci_high", "truncated_fraction",
                     "mean_length"):
            assert getattr(b, name) == pytest.approx(getattr(a, name), rel=1e-5, abs=1e-9)
    # Written again, the parsed rows give the same bytes (6 significant digits survive).
    again = tmp_path / "again.csv"
    write_summary(again, back, summary_columns(grid))
    assert again.read_bytes() == path.read_bytes()


def test_capped_and_default_rows_round_trip(grid, tmp_path):
    capped = dataclasses.replace(grid, meta={**grid.meta, "step_cap": True})
    rows = summarize(capped)
    assert all(isinstance(r.episodes_cut, int) and isinstance(r.agents_cut, int) for r in rows)
    rows = [dataclasses.replace(rows[0], param=None, hyperparameters='{"alpha":0.3}'), *rows[1:]]
    columns = SUMMARY_COLUMNS[:4] + ["hyperparameters"] + SUMMARY_COLUMNS[4:] + [
        "episodes_cut", "agents_cut"]
    write_summary(tmp_path / "summary.csv", rows, columns)
    back = read_summary(tmp_path / "summary.csv")
    assert back[0].param is None and back[0].hyperparameters == '{"alpha":0.3}'
    assert [(r.episodes_cut, r.agents_cut) for r in back] == [
        (r.episodes_cut, r.agents_cut) for r in rows]


def test_parsing_strings_numbers_and_older_summaries(rows):
    strings = {k: str(v) for k, v in rows[5].items()}
    assert summary_row(strings) == rows[5]  # str(float) round-trips exactly
    assert summary_row(rows[5]) is rows[5]
    assert summary_rows([rows[5], dict(rows[6])]) == [rows[5], rows[6]]
    # The first summaries had neither the IQM, the convergence interval nor truncation.
    old = {k: v for k, v in strings.items()
           if k not in ("final_iqm", "convergence_ci_low", "convergence_ci_high",
                        "truncated_fraction", "hyperparameters")}
    parsed = summary_row(old)
    assert parsed.final_iqm is None and parsed.convergence_ci_low is None
    assert parsed.truncated_fraction is None and parsed.hyperparameters == "{}"
    assert "convergence_ci_low" not in parsed
    assert math.isnan(summary_row({**strings, "truncated_fraction": "nan"}).truncated_fraction)
    assert summary_row({**strings, "param": "None"}).param is None


@pytest.mark.parametrize("change, message", [
    ({"final_return": ""}, "column 'final_return' is missing"),
    ({"convergence_episode": "0.5"}, "convergence_episode='0.5' must be a number ≥ 1 or inf"),
    ({"final_ci_low": "low"}, "final_ci_low='low' must be a number"),
])
def test_invalid_rows_are_refused(rows, change, message):
    with pytest.raises(ValueError, match=message):
        summary_row({**dict(rows[0]), **change})


def test_a_damaged_summary_file_is_named(tmp_path):
    path = tmp_path / "summary.csv"
    path.write_text("config,learner,explorer,param,final_return\n0,qlearning,egreedy,0.1,0.5\n")
    with pytest.raises(ValueError, match="summary.csv' is damaged: .*'final_ci_low'"):
        read_summary(path)


def paper_scores(rows):
    return score_rows(rows, paper_claims(), BEST).claims


def test_the_papers_claims_score_alike_from_the_result_and_from_its_rows(grid, rows):
    paper = paper_claims()
    assert len(paper) == 6
    results = paper_scores(rows)
    assert [r.number for r in results] == list(range(1, 7))
    assert score_claims(grid, paper, rows, best_return=BEST).claims == results
    # summary.csv's strings score the same.
    strings = [{k: str(v) for k, v in r.items()} for r in rows]
    assert paper_scores(strings) == results


def test_claims_skip_absent_settings(rows):
    sarsa_softmax = [r for r in rows if r.learner == "sarsa" and r.explorer == "softmax"]
    scored = paper_scores(sarsa_softmax)
    assert [c.number for c in scored] == [2, 6]
    assert paper_scores([]) == []


def test_claim_5_falls_back_to_the_point_without_an_interval(rows):
    old = [dataclasses.replace(r, convergence_episode=150.0, convergence_ci_low=None,
                               convergence_ci_high=None) for r in rows]
    claim = next(c for c in paper_scores(old) if c.number == 5)
    first = claim.checks[0].description
    assert "convergence_episode 150 [150, 150] ends within" in first


def test_sensitivity_without_convergence_intervals(rows):
    old = [dataclasses.replace(r, convergence_ci_low=None, convergence_ci_high=None)
           for r in rows]
    fig = plotting.sensitivity(old, best_return=BEST)
    axes = np.array(fig.axes).reshape(2, 4)
    assert axes[0, 0].containers[0].has_yerr and not axes[1, 0].containers[0].has_yerr
    plt.close(fig)


def test_best_parameters_reads_typed_and_csv_rows(rows):
    strings = [{k: str(v) for k, v in r.items()} for r in rows]
    chosen = scaling.best_parameters(rows)
    assert chosen == scaling.best_parameters(strings)
    assert set(chosen) == {"egreedy", "softmax", "vdbe", "vdbe_softmax"}
    with pytest.raises(ValueError, match="no param"):
        scaling.best_parameters([dataclasses.replace(rows[0], param=None)])


def test_a_setting_that_never_learns_is_censored_in_summary_claims_and_plot(grid, rows,
                                                                            tmp_path):
    censored = [r for r in rows if r.convergence_episode == math.inf]
    assert censored and len(censored) < len(rows)
    for r in censored:  # half or more of its agents never reach a normalised score of 0.9
        assert r.agents_converged <= 2 and r.convergence_budget == grid.num_episodes
    path = tmp_path / "summary.csv"
    write_summary(path, rows, summary_columns(grid))
    text = {line.split(",")[0]: line for line in path.read_text().splitlines()[1:]}
    assert all(",inf," in text[str(r.config)] for r in censored)
    assert [r.config for r in read_summary(path) if r.convergence_episode == math.inf] == [
        r.config for r in censored]
    never = [dataclasses.replace(r, convergence_episode=math.inf)
             if r.explorer == "vdbe" and r.learner == "qlearning" else r for r in rows]
    claim_3 = next(c for c in paper_scores(never) if c.number == 3)
    assert "qlearning/vdbe/sigma=0.01 final_return" in claim_3.measured
    assert "qlearning/vdbe/sigma=0.01 convergence_episode > 120" in claim_3.measured
    swept = [r for r in censored if r.param is not None]
    fig = plotting.sensitivity(rows, best_return=BEST)
    labels = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    assert bool(swept) == any(plotting.CENSORED_LABEL in label for label in labels)
    plt.close(fig)
