"""`vdbejax ablate` with tiny settings: per-variant outputs, the claims × variants table,
reuse of saved results, and one-line errors."""
import json

import pytest

from vdbejax import cli
from vdbejax.methods.agents import AgentOptions
from vdbejax.paper import ablation, ablation_document, ablation_variants
from vdbejax.paper.reproduce import AUTHORS_DETAILS
from vdbejax.runs import RunOptions

VARIANTS = "spec,invalid_fail"


@pytest.fixture(scope="module")
def ablated(tmp_path_factory):
    out = tmp_path_factory.mktemp("docs")
    raw = tmp_path_factory.mktemp("raw")
    notes = out / "notes.md"
    notes.write_text("## Discussion\n\nHand-written text.\n")
    code = cli.main(["ablate", "--out", str(out), "--results", str(raw), "--variants", VARIANTS,
                     "--seeds", "2", "--episodes", "12", "--notes", str(notes), "--quiet"])
    assert code == 0
    return out, raw, notes


def test_outputs_per_variant(ablated):
    out, raw, _ = ablated
    for name in VARIANTS.split(","):
        assert (raw / name / "returns.npz").exists()  # raw arrays stay in --results
        for asset in [*ablation.DOCUMENT_ASSETS, "summary_pooled.csv", "replicates.csv"]:
            assert (out / "ablation" / name / asset).stat().st_size > 0
        assert not (out / "ablation" / name / "returns.npz").exists()


def test_document(ablated):
    out, raw, _ = ablated
    text = (out / "ablation_scorecard.md").read_text()
    assert "## Claims × variants" in text
    assert "| claim | `spec` | `invalid_fail` |" in text
    for n in range(1, 7):
        assert f"\n| {n} | " in text
    # The exact regenerating command is quoted.
    assert f"vdbejax ablate --out {out} --results {raw} --variants {VARIANTS} --seeds 2 --episodes 12" in text
    assert "ablation/spec/fig3.png" in text and "ablation/invalid_fail/sensitivity.png" in text
    assert text.rstrip().endswith("Hand-written text.")
    assert "5 replicates × 2 agents (pooled 10) × 12 episodes" in text  # the default 5
    assert "agree" in text and "unstable" in text  # the cells' legend states the rule
    assert "## Convergence episodes per method family" in text
    assert "## Agents caught in a loop" not in text  # the textbook task has a step limit


def test_reuse_saved_results(ablated):
    out, raw, _ = ablated
    before = json.loads((raw / "spec" / "meta.json").read_text())
    results = ablation.ablate(out, results_dir=raw, variants=ablation_variants.select_variants("spec"),
                              seeds=2, episodes=12, run=RunOptions(progress=False))
    after = json.loads((raw / "spec" / "meta.json").read_text())
    assert after["elapsed_seconds"] == before["elapsed_seconds"]  # reused, not retrained
    assert [r.how for r in results] == ["reused"]  # and said so in the status line
    table = ablation_document.claims_table(results)
    assert [row["claim"] for row in table] == [1, 2, 3, 4, 5, 6]
    assert all(row["spec"] in ("reproduced", "partly", "not reproduced", "unstable",
                               "undecided")
               for row in table)


def test_variants_cover_each_open_detail():
    names = {v.name for v in ablation_variants.VARIANTS}
    assert ablation_variants.VARIANTS[0].options() == {
        "max_steps": 100, "invalid_action": "noop", "reading": "textbook", "details": {},
        "options": AgentOptions(tie_break="random", q_init=0.0, alpha=0.8)}
    assert {v.invalid_action for v in ablation_variants.VARIANTS} == {"noop", "fail"}
    assert {v.tie_break for v in ablation_variants.VARIANTS} == {"random", "first"}
    assert len({v.max_steps for v in ablation_variants.VARIANTS}) >= 3
    assert len({v.q_init for v in ablation_variants.VARIANTS}) >= 3
    assert len(names) == len(ablation_variants.VARIANTS)


@pytest.mark.parametrize("args, message", [
    (["--variants", "nope"], "unknown variant"),
    (["--seeds", "0"], "seeds"),
    (["--notes", "/nonexistent/notes.md"], "notes"),
])
def test_bad_input(tmp_path, capsys, args, message):
    code = cli.main(["ablate", "--out", str(tmp_path / "o"), "--quiet", "--episodes", "5", *args])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and message in err[0]


def test_attribution_mode_switches_one_authors_detail_at_a_time(tmp_path):
    names = "textbook,authors,textbook+failure_update,authors-failure_update"
    code = cli.main(["ablate", "--mode", "attribution", "--out", str(tmp_path), "--results",
                     str(tmp_path / "raw"), "--variants", names, "--seeds", "2", "--episodes",
                     "12", "--quiet"])
    assert code == 0
    text = (tmp_path / "ATTRIBUTION.md").read_text()
    assert "--mode attribution" in text and "which detail of which reading" in text
    assert not (tmp_path / "ablation_scorecard.md").exists()
    assert (tmp_path / "attribution" / "authors" / "report.md").exists()
    assert not (tmp_path / "attribution" / "authors" / "fig3.png").exists()  # reports only
    # ... and the raw results draw none (the document does not show them)
    assert (tmp_path / "raw" / "authors" / "summary.csv").exists()
    assert not list((tmp_path / "raw").rglob("*.png"))
    from vdbejax.results.grid_result import GridResult

    switched = GridResult.load(tmp_path / "raw" / "textbook+failure_update")
    assert switched.meta["details"] == {"failure_update": "overwrite"}
    assert switched.meta["mdp"] == "table_cleaning"
    removed = GridResult.load(tmp_path / "raw" / "authors-failure_update")
    assert removed.meta["mdp"] == "cruz2018" and "failure_update" not in removed.meta["details"]
    assert len(removed.meta["details"]) == len(AUTHORS_DETAILS) - 1
    # Each detail of the authors' code appears once added and once removed.
    variant_names = {v.name for v in ablation_variants.ATTRIBUTION_VARIANTS}
    for detail in AUTHORS_DETAILS:
        assert {f"textbook+{detail}", f"authors-{detail}"} <= variant_names


def test_unknown_mode_is_one_line(capsys):
    assert cli.main(["ablate", "--out", "x", "--mode", "fractal"]) == 2
    assert "mode='fractal'" in capsys.readouterr().err


def test_factorial_variants_are_every_combination_from_each_reading():
    import itertools

    variants = ablation_variants.FACTORIAL_VARIANTS
    assert len(variants) == 2 * 2 * 2 * 3 * 2 and len({v.name for v in variants}) == len(variants)
    for reading in ("textbook", "authors"):
        mine = [v for v in variants if v.reading == reading]
        combos = {(dict(v.details)["failure_update"], dict(v.details)["goal_update"], v.alpha,
                   dict(v.details)["q_init_distribution"]) for v in mine}
        assert combos == set(itertools.product(*ablation_variants.FACTORIAL_FACTORS.values()))
        if reading == "authors":  # the reading's other details stay
            assert all(dict(v.details)["next_action"] == "redrawn" and v.tie_break == "first"
                       for v in mine)
        else:
            assert all(set(dict(v.details)) == set(ablation_variants.FACTORIAL_FACTORS) - {"alpha"}
                       for v in mine)
    assert all("/" not in v.name and ":" not in v.name for v in variants)  # folder names


def test_factorial_mode_and_sections_in_the_document(tmp_path):
    names = "textbook-overwrite-skip-alpha0.3-uniform,authors-td-td-alpha0.8-constant"
    assert cli.main(["ablate", "--mode", "factorial", "--out", str(tmp_path), "--variants",
                     names, "--seeds", "2", "--episodes", "12", "--quiet"]) == 0
    text = (tmp_path / "FACTORIAL.md").read_text()
    assert "--mode factorial" in text and "`authors-td-td-alpha0.8-constant`" in text
    from vdbejax.results.grid_result import GridResult

    grid = GridResult.load(tmp_path / "factorial" / names.split(",")[0])
    assert grid.meta["options"]["alpha"] == pytest.approx(0.3)
    assert grid.meta["details"]["goal_update"] == "skip"
    # ablation_scorecard.md's sections: a variants × claims table per other mode, with "Most".
    results = ablation.ablate(tmp_path / "doc", results_dir=tmp_path / "raw",
                              variants=ablation_variants.select_variants("spec"), seeds=2, episodes=12,
                              run=RunOptions(progress=False))
    section = ("Factorial", "intro text", "factorial", [
        ablation.run_variant(v, tmp_path / "factorial" / v.name, seeds=2, episodes=12,
                             replicates=5, figures=False)  # the command's: reused
        for v in ablation_variants.select_variants(names, "factorial")])
    doc = ablation_document.render_document(results, "ablation", "cmd", sections=[section])
    assert "## Factorial" in doc and "intro text" in doc
    assert "[report](factorial/authors-td-td-alpha0.8-constant/report.md)" in doc
    assert "Most claims fully reproduced" in doc


def test_a_variant_left_half_written_by_a_killed_run_is_continued(tmp_path):
    from vdbejax.results.folder_lock import MARKER_FILE, mark
    from vdbejax.results.grid_result import GridResult

    (variant,) = ablation_variants.select_variants("spec")
    folder = tmp_path / "spec"
    first = ablation.run_variant(variant, folder, seeds=2, episodes=12)
    assert first.how == "trained"
    whole = GridResult.load(folder)
    for damage in ("marker", "meta.json is a list"):
        mark(folder, "results")  # as a run killed while writing its result files leaves it
        if damage == "meta.json is a list":
            (folder / "meta.json").write_text("[]")
        again = ablation.run_variant(variant, folder, seeds=2, episodes=12)
        assert not (folder / MARKER_FILE).exists(), damage
        assert [c.verdict for c in again.claims] == [c.verdict for c in first.claims]
        assert (GridResult.load(folder).returns == whole.returns).all(), damage


def test_loop_table_gives_each_looping_setting_its_rate_and_interval(tmp_path):
    import dataclasses

    from vdbejax.paper.ablation_document import _loop_table
    from vdbejax.results import io
    from vdbejax.results.stats import wilson_interval
    from vdbejax.results.summary import SummaryRow

    io.save_json(tmp_path / "meta.json", {"num_seeds": 100})
    row = SummaryRow(config=0, learner="sarsa", explorer="softmax", param=0.0001,
                     final_return=-3.0, final_ci_low=-5.0, final_ci_high=0.8,
                     convergence_episode=5, truncated_fraction=0.1, mean_length=900.0,
                     nonfinite_agents=0, episodes_cut=800, agents_cut=11)
    quiet = dataclasses.replace(row, config=1, param=0.001, agents_cut=0)
    result = ablation_variants.VariantResult(ablation_variants.VARIANTS[1], [row, quiet], [], 0.86, tmp_path)
    low, high = wilson_interval(11, 100)
    lines = _loop_table([result], [result.summary])
    assert f"| `authors` | SARSA softmax 0.0001 | 11/100 | 11.0% [{low:.1%}, {high:.1%}] |" in lines
    assert not any("0.001 |" in line for line in lines)
    assert _loop_table([result], [[dataclasses.replace(row, agents_cut=None,
                                                       episodes_cut=None)]]) == []


@pytest.mark.parametrize("flags", [["--seeds", "0"], ["--episodes", "0"], ["--seed", "-1"],
                                   ["--replicates", "0"], ["--memory-budget", "1Q"]])
def test_a_refused_ablate_leaves_no_folder_behind(tmp_path, capsys, flags):
    from vdbejax import cli

    out = tmp_path / "doc"
    assert cli.main(["ablate", "--out", str(out), *flags]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("error:") and "\n" not in line
    assert not out.exists()
