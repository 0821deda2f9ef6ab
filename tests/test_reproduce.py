"""`vdbejax reproduce` end to end (small --seeds/--episodes), every output file checked."""
import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import vdbejax
from vdbejax.methods.agents import PAPER_PARAMETERS, paper_settings
from vdbejax.runs import RunOptions

SEEDS, EPISODES = 2, 30
REPLICATES = 5  # reproduce's default
AGENTS = SEEDS * REPLICATES


def run_cli(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "vdbejax", *args], capture_output=True, text=True,
                          cwd=cwd, env=env)


@pytest.fixture(scope="module")
def compile_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("jax-cache")


@pytest.fixture(scope="module")
def cli_out(tmp_path_factory, compile_cache):
    out = tmp_path_factory.mktemp("paper")
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["VDBEJAX_CACHE_DIR"] = str(compile_cache)
    done = run_cli("reproduce", "--out", str(out), "--seeds", str(SEEDS), "--episodes", str(EPISODES),
                   env=env)
    assert done.returncode == 0, done.stderr
    return out, done


def test_cli_fills_the_persistent_compilation_cache(cli_out, compile_cache):
    assert any(compile_cache.iterdir())


def test_paper_grid_has_46_settings():
    settings = paper_settings()
    assert len(settings) == 46
    assert sum(len(v) for v in PAPER_PARAMETERS.values()) == 23


def test_returns_npz(cli_out):
    out, _ = cli_out
    with np.load(out / "returns.npz") as data:
        assert data["returns"].shape == (46, AGENTS, EPISODES)
        assert data["lengths"].shape == (46, AGENTS, EPISODES)
        assert np.issubdtype(data["returns"].dtype, np.floating)
        assert np.issubdtype(data["lengths"].dtype, np.integer)
        assert data["lengths"].min() >= 1 and data["lengths"].max() <= 100
        assert np.all(data["returns"] <= 0.86 + 1e-5)


def test_configs_csv(cli_out):
    out, _ = cli_out
    rows = list(csv.DictReader(open(out / "configs.csv")))
    assert list(rows[0]) == ["config", "learner", "explorer", "param"]
    assert [int(r["config"]) for r in rows] == list(range(46))
    assert {r["learner"] for r in rows} == {"qlearning", "sarsa"}
    assert {r["explorer"] for r in rows} == {"egreedy", "softmax", "vdbe", "vdbe_softmax"}
    for row, setting in zip(rows, paper_settings()):
        assert (row["learner"], row["explorer"], float(row["param"])) == (
            setting.learner, setting.explorer, setting.param)


@pytest.mark.parametrize("name, agents", [("summary.csv", slice(0, SEEDS)),
                                          ("summary_pooled.csv", slice(None))])
def test_summary_csv(cli_out, name, agents):
    # summary.csv: replicate 0 (the first SEEDS agents); summary_pooled.csv: all agents.
    out, _ = cli_out
    rows = list(csv.DictReader(open(out / name)))
    assert len(rows) == 46
    with np.load(out / "returns.npz") as data:
        returns = data["returns"]
    for row in rows:
        c = int(row["config"])
        final = returns[c, agents, -100:].mean()
        assert float(row["final_return"]) == pytest.approx(final, abs=1e-4)
        assert float(row["final_ci_low"]) <= float(row["final_return"]) + 1e-6 <= float(row["final_ci_high"]) + 2e-6
        # The median over agents: an episode or halfway between two, or censored ("inf").
        episode = row["convergence_episode"]
        assert episode == "inf" or (1 <= float(episode) <= EPISODES
                                    and (2 * float(episode)).is_integer())


def test_fig3_png(cli_out):
    out, _ = cli_out
    data = (out / "fig3.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    image = matplotlib.image.imread(out / "fig3.png")
    assert image.shape[0] > 300 and image.shape[1] > 800  # a 2 × 4 panel figure


def test_report_md(cli_out):
    out, done = cli_out
    report = (out / "report.md").read_text()
    for number in range(1, 7):
        assert f"## Claim {number}:" in report
    assert "Paper:" in report and "Measured:" in report
    for line in done.stdout.splitlines()[:6]:
        assert line.split(": ")[1] in {"reproduced", "partly", "not reproduced", "unstable",
                                       "undecided"}
    assert "elapsed" in done.stdout
    meta = json.loads((out / "meta.json").read_text())
    assert meta["num_seeds"] == AGENTS and meta["num_episodes"] == EPISODES
    assert meta["replicates"] == REPLICATES and meta["agents_per_replicate"] == SEEDS
    assert f"{REPLICATES} replicates × {SEEDS} agents (pooled {AGENTS})" in report
    assert "holds in" in report and f"of {REPLICATES} replicates" in report
    rows = list(csv.DictReader(open(out / "replicates.csv")))
    assert len(rows) == 46 * REPLICATES
    assert sorted({int(r["replicate"]) for r in rows}) == list(range(REPLICATES))
    assert not (out / "checkpoint.npz").exists()


def test_python_api_matches_cli(cli_out, tmp_path):
    out, _ = cli_out
    rep = vdbejax.reproduce(tmp_path, seeds=SEEDS, episodes=EPISODES,
                            run=RunOptions(progress=False))
    with np.load(out / "returns.npz") as data:
        np.testing.assert_array_equal(rep.result.returns, data["returns"])
    assert len(rep.claims) == 6 and rep.best_return == pytest.approx(0.86)


@pytest.mark.parametrize(
    "args, message",
    [
        (["reproduce"], "--out"),
        (["reproduce", "--out", "x", "--q-init", "-inf"], "--option=VALUE"),
        (["reproduce", "--out", "x", "--no-such-option"], "--no-such-option"),
        (["explode"], "invalid choice"),
    ],
)
def test_cli_usage_errors_are_one_line_exit_2(tmp_path, args, message):
    done = run_cli(*args, cwd=tmp_path)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0]


def test_no_figures_writes_the_same_numbers_without_pngs(cli_out, tmp_path, compile_cache):
    out, _ = cli_out
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["VDBEJAX_CACHE_DIR"] = str(compile_cache)
    done = run_cli("reproduce", "--out", str(tmp_path), "--seeds", str(SEEDS), "--episodes",
                   str(EPISODES), "--no-figures", "--quiet", env=env)
    assert done.returncode == 0, done.stderr
    assert not list(tmp_path.glob("*.png"))
    for name in ("summary.csv", "report.md", "configs.csv"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes(), name
    with np.load(tmp_path / "returns.npz") as a, np.load(out / "returns.npz") as b:
        np.testing.assert_array_equal(a["returns"], b["returns"])


def test_one_replicate_is_the_first_replicate_of_five(cli_out, tmp_path, compile_cache):
    # --replicates 1 writes a single run's files: its agents are, bit for bit, replicate 0
    # of the default run, and its summary.csv is that run's (replicate 0's) summary.csv.
    out, _ = cli_out
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["VDBEJAX_CACHE_DIR"] = str(compile_cache)
    done = run_cli("reproduce", "--out", str(tmp_path), "--seeds", str(SEEDS), "--episodes",
                   str(EPISODES), "--replicates", "1", "--no-figures", "--quiet", env=env)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "configs.csv", "manifest.json", "meta.json", "report.md", "returns.npz", "summary.csv"]
    assert (tmp_path / "summary.csv").read_bytes() == (out / "summary.csv").read_bytes()
    with np.load(tmp_path / "returns.npz") as one, np.load(out / "returns.npz") as five:
        for name in ("returns", "lengths"):
            np.testing.assert_array_equal(one[name], five[name][:, :SEEDS])
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert "replicates" not in meta and meta["num_seeds"] == SEEDS
    report = (tmp_path / "report.md").read_text()
    assert f"{SEEDS} agents × {EPISODES} episodes" in report and "replicates" not in report


@pytest.mark.parametrize("root", [1, 2])
def test_a_new_root_seed_reports_each_verdicts_stability(tmp_path, root):
    # Another root seed: every claim states how many replicates agree, and each verdict or
    # check that differs between replicates is named under "Flips between replicates".
    rep = vdbejax.reproduce(tmp_path, seeds=SEEDS, episodes=EPISODES, seed=root, replicates=3,
                            figures=False, run=RunOptions(progress=False))
    report = (tmp_path / "report.md").read_text()
    assert f"root seed {root}" in report and "(3 of 3 when all do)" in report
    for claim in rep.claims:
        assert len(claim.replicate_verdicts) == 3
        assert f"## Claim {claim.number}: {claim.verdict} (pooled {claim.pooled_verdict};" \
               f" {claim.agreeing} of 3 replicates agree)" in report
        # Replicates too small to decide a claim neither agree nor flip.
        decided = [v for v in claim.replicate_verdicts if v != "undecided"]
        flips = len(set(decided)) > 1
        assert (f"- Claim {claim.number}: its verdict flips" in report) is flips
        stable = (claim.pooled_verdict == "undecided" or not decided
                  or decided.count(claim.pooled_verdict) >= len(decided))
        assert claim.verdict == (claim.pooled_verdict if stable else "unstable")
        for check in claim.checks:
            assert f"{check.description} — holds in {check.replicates_passed} of 3" in report
            if check.flips:
                assert f": {check.description}\n" in report


def test_the_report_names_settings_whose_agents_all_end_at_one_value_and_why():
    from vdbejax.methods import Setting
    from vdbejax.paper.report import TRAP_DOCS, one_value_settings, render_report
    from vdbejax.results.grid_result import GridResult

    settings = [Setting("sarsa", "vdbe", 1.0), Setting("sarsa", "vdbe", 10.0),
                Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "egreedy", 0.1)]
    returns = np.full((4, 3, 120), -0.01 * 100, np.float32)  # looping until the limit
    lengths = np.full(returns.shape, 100, np.int32)
    returns[2], lengths[2] = 0.86, 15  # every agent at the best return: it learned
    returns[3] = np.linspace(-1, 0.5, 3, dtype=np.float32)[:, None]  # a spread
    lengths[3] = 40
    meta = {"mdp": "table_cleaning", "max_steps": 100, "step_limit_cuts": "sometimes"}
    result = GridResult(settings, returns, lengths, np.zeros((4, 3), bool), meta)
    [stuck] = one_value_settings(result, best_return=0.86)
    assert (stuck.learner, stuck.explorer, stuck.params) == ("sarsa", "vdbe", (1.0, 10.0))
    assert stuck.final_return == float(np.float32(-1.0)) and stuck.truncated == 1.0
    report = render_report([], meta, 0.86, [stuck])
    assert ("- SARSA with VDBE (sigma = 1, 10): every agent ends at exactly -1.000; 100% of"
            " their last episodes cut at the step limit of 100.") in report
    assert TRAP_DOCS in report and "The SARSA trap" in report
    assert "all end at one value" not in render_report([], meta, 0.86)
