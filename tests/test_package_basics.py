"""Package basics: license, self-contained docs, version, meta.json versions, numpy scalars
as counts, and 32-bit ranges for seeds and sizes (one-line errors, nothing written)."""
from __future__ import annotations

import importlib.metadata
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import vdbejax
from vdbejax import cli
from vdbejax.envs import make_tabular_mdp, solvers
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.envs.table_cleaning.env import ACTION_NAMES
from vdbejax.methods import Setting
from vdbejax.methods.agents import PAPER_PARAMETERS
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import provenance, run_grid
from vdbejax.validation import INT32_MAX, UINT32_MAX, check_int

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def run_cli(*args: str, cache: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env["VDBEJAX_CACHE_DIR"] = str(cache)
    return subprocess.run([sys.executable, "-m", "vdbejax", *args], capture_output=True,
                          text=True, env=env, timeout=300)


# ------------------------------------------------------------------------- license
def test_license_is_the_mit_text():
    assert PYPROJECT["license"] == "MIT"
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License")
    assert "Copyright (c) 2026 the vdbejax authors" in text
    assert "Permission is hereby granted, free of charge" in text
    assert 'THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND' in text


# ---------------------------------------------------------------------------- docs
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def relative_links(markdown: Path) -> list[str]:
    targets = LINK.findall(markdown.read_text())
    return [t for t in targets if not re.match(r"^[a-z][a-z0-9+.-]*:", t) and not t.startswith("#")]


@pytest.mark.parametrize("document", ["README.md", "docs/task.md"])
def test_every_relative_link_resolves_inside_the_repository(document):
    markdown = ROOT / document
    links = relative_links(markdown)
    if document == "README.md":
        assert "docs/task.md" in links
    for link in links:
        target = (markdown.parent / link.split("#")[0]).resolve()
        assert target.is_relative_to(ROOT), f"{document}: {link} points outside the repository"
        assert target.exists(), f"{document}: {link} does not exist"


def test_docs_never_send_users_outside_the_repository():
    for document in ("README.md", "docs/task.md"):
        assert "shared/spec" not in (ROOT / document).read_text(), document


def _flat(text: str) -> str:
    return " ".join(text.split())


def test_task_document_matches_the_code():
    text = _flat((ROOT / "docs/task.md").read_text())
    mdp = make_mdp()
    # Encoding, reachable states, starts.
    assert f"{mdp.num_states} codes" in text and mdp.num_states == 108
    assert f"{len(solvers.reachable_states(mdp))} non-terminal states are reachable" in text
    starts = [int(s) for s in solvers.start_states(mdp)]
    assert f"(codes {starts[0]} and {starts[1]})" in text
    # Actions, in index order.
    assert ", ".join(f"`{i} {name}`" for i, name in enumerate(ACTION_NAMES)) in text
    # Shortest solution and best return, by search.
    assert set(solvers.steps_to_goal(mdp)[solvers.start_states(mdp)].tolist()) == {15}
    assert "**15 actions**" in text
    assert f"{solvers.best_return(mdp):.2f}" == "0.86" and "**0.86**" in text
    goblet_left = starts[0]  # code 24: goblet on the left
    assert ", ".join(ACTION_NAMES[a] for a in solvers.shortest_solution(mdp, goblet_left)) in text
    # Swept values.
    for values in PAPER_PARAMETERS.values():
        assert "{" + ", ".join(f"{v:g}" for v in values) + "}" in text, values
    assert "**46 settings**" in text
    # Options with their defaults.
    for option, default in [("invalid_action", '`"noop"`'), ("max_steps", "100"),
                            ("q_init", "0"), ("tie_break", '`"random"`')]:
        assert f"| `{option}` | {default} |" in text, option
    assert "truncation" in text.lower() and "not* a terminal state" in text
    # The six claims and the second reading.
    assert all(f"{n}. **" in text for n in range(1, 7))
    assert "## The authors' code" in text and "`softmax_numerics`" in text
    assert "not yet implemented" not in text.lower()


# ------------------------------------------------------------------------- version
def test_version_comes_from_the_installed_metadata():
    assert vdbejax.__version__ == importlib.metadata.version("vdbejax") == PYPROJECT["version"]


def test_version_falls_back_to_the_pyproject_value_when_not_installed():
    code = ("import importlib.metadata as m\n"
            "def missing(name):\n    raise m.PackageNotFoundError(name)\n"
            "m.version = missing\n"
            "import vdbejax\nprint(vdbejax.__version__)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, VDBEJAX_CACHE_DIR="off"))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "0.2.0" == PYPROJECT["version"]


def test_every_place_the_version_appears_agrees():
    """The release's version: pyproject.toml, the source tree's fallback, CITATION.cff, the
    CHANGELOG's newest released section (below "Unreleased", which collects the changes since:
    empty on the day of a release, growing until the next)."""
    version = PYPROJECT["version"]
    init = (ROOT / "vdbejax" / "__init__.py").read_text(encoding="utf-8")
    assert f'__version__ = "{version}"' in init
    citation = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert re.search(rf'^version: "{re.escape(version)}"$', citation, re.M), citation
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    sections = re.findall(r"^## (.+)$", changelog, re.M)
    assert sections[0] == "Unreleased" and sections[1].startswith(f"{version} — "), sections


def test_cli_version(tmp_path):
    done = run_cli("--version", cache=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"vdbejax {vdbejax.__version__}\n"


def test_help_shows_no_restructuredtext_markup():
    parser = cli.build_parser()
    texts = [parser.format_help()]
    subparsers = next(a for a in parser._actions if a.choices and "reproduce" in a.choices)
    texts += [sub.format_help() for sub in subparsers.choices.values()]
    for text in texts:
        assert "``" not in text, text
    assert "--version" in texts[0]


# ----------------------------------------------------------- numpy scalars, meta.json
@pytest.fixture(scope="module")
def numpy_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("numpy_run")
    result = run_grid(make_mdp(), [Setting("qlearning", "egreedy", np.float32(0.1))],
                      num_seeds=np.int64(2), num_episodes=np.int64(3), seed=np.int32(1),
                      chunk_episodes=np.int64(2))
    result.save(out)
    return result, out


def test_numpy_scalars_as_counts_and_seed(numpy_run):
    result, out = numpy_run
    meta = json.loads((out / "meta.json").read_text())
    assert (meta["num_seeds"], meta["num_episodes"], meta["seed"]) == (2, 3, 1)
    assert all(type(result.meta[k]) is int for k in ("num_seeds", "num_episodes", "seed"))
    assert result.returns.shape == (1, 2, 3)
    plain = run_grid(make_mdp(), result.settings, num_seeds=2, num_episodes=3, seed=1,
                     chunk_episodes=2)  # the same run with plain ints
    np.testing.assert_array_equal(result.returns, plain.returns)
    assert plain.meta["fingerprint"] == result.meta["fingerprint"]
    np.testing.assert_array_equal(GridResult.load(out).returns, result.returns)


def expected_commit() -> str | None:
    if shutil.which("git") is None:
        return None
    done = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return done.stdout.strip() if done.returncode == 0 else None


def test_meta_json_records_versions(numpy_run):
    _, out = numpy_run
    meta = json.loads((out / "meta.json").read_text())
    import jax

    assert meta["jax_version"] == jax.__version__
    assert meta["vdbejax_version"] == vdbejax.__version__
    assert meta["numpy_version"] == np.__version__
    assert meta["python_version"] == platform.python_version()
    assert meta["platform"] == platform.platform()
    assert meta["git_commit"] == expected_commit()
    if meta["git_commit"] is not None:
        assert re.fullmatch(r"[0-9a-f]{40}", meta["git_commit"])


def test_git_commit_is_computed_once_per_process():
    provenance.git_commit()
    hits = provenance.git_commit.cache_info().hits
    provenance.git_commit()
    assert provenance.git_commit.cache_info().hits == hits + 1


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_git_commit_is_none_outside_a_clone_and_for_an_untracked_copy(tmp_path, monkeypatch):
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))
    package = tmp_path / "plain" / "vdbejax"
    package.mkdir(parents=True)
    monkeypatch.setattr(provenance, "__file__", str(package / "runs" / "provenance.py"))
    assert provenance.git_commit.__wrapped__() is None  # not a git clone
    # A copy inside some other repository (a virtualenv in a clone) that does not track it.
    repo = tmp_path / "other"
    package = repo / "site-packages" / "vdbejax"
    package.mkdir(parents=True)
    (repo / "README").write_text("x")
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    for args in (["init", "-q"], ["add", "README"], ["commit", "-q", "-m", "x"]):
        subprocess.run(git + args, cwd=repo, check=True, capture_output=True)
    monkeypatch.setattr(provenance, "__file__", str(package / "runs" / "provenance.py"))
    assert provenance.git_commit.__wrapped__() is None


# ------------------------------------------------------------------ 32-bit ranges
def test_check_int_maximum():
    assert check_int("seed", UINT32_MAX, 0, UINT32_MAX) == UINT32_MAX
    value = check_int("num_seeds", np.int64(5), 1, INT32_MAX)
    assert value == 5 and type(value) is int
    with pytest.raises(ValueError) as error:
        check_int("seed", 2**32, 0, UINT32_MAX)
    assert str(error.value) == ("seed=4294967296 is invalid: must be an integer >= 0 and"
                                " <= 4294967295")
    with pytest.raises(ValueError, match=r"^seed=-1 is invalid: must be an integer >= 0 and <= "):
        check_int("seed", -1, 0, UINT32_MAX)
    with pytest.raises(ValueError, match=r"^n=2.5 is invalid: must be an integer >= 1$"):
        check_int("n", 2.5)  # no maximum: the message is unchanged


@pytest.mark.parametrize("name, value", [
    ("seed", 2**32), ("seed", 10**20), ("num_seeds", 2**31), ("num_episodes", 2**31),
    ("chunk_episodes", 2**31), ("seed", np.uint64(2**32)),
])
def test_run_options_beyond_32_bits_are_rejected(name, value):
    # Checked when the run options are made and by prepare_grid (run_grid's, reproduce's,
    # run_sweep's first step), so a missing bound cannot start allocating 2**31 agents.
    from vdbejax.runs import RunOptions, prepare_grid

    with pytest.raises(ValueError) as error:
        if name == "chunk_episodes":
            RunOptions(chunk_episodes=value)
        else:
            work = {"num_seeds": 1, "num_episodes": 1, "seed": 0, name: value}
            prepare_grid(make_mdp(), [Setting("qlearning", "egreedy", 0.1)], **work)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{name}=") and "is invalid" in message


@pytest.mark.parametrize("seed", [2**32, 10**20])
def test_run_grid_rejects_a_seed_beyond_32_bits(seed):
    with pytest.raises(ValueError, match=rf"^seed={seed} is invalid: must be an integer >= 0"
                                         r" and <= 4294967295$"):
        run_grid(make_mdp(), [Setting("qlearning", "egreedy", 0.1)], num_seeds=1,
                 num_episodes=1, seed=seed)


def test_largest_seed_is_accepted_and_differs_from_seed_0():
    settings = [Setting("qlearning", "egreedy", 0.1)]
    grids = [run_grid(make_mdp(), settings, num_seeds=1, num_episodes=5, seed=s)
             for s in (0, UINT32_MAX)]
    assert grids[1].meta["seed"] == UINT32_MAX
    assert not np.array_equal(grids[0].lengths, grids[1].lengths) or not np.array_equal(
        grids[0].returns, grids[1].returns)


def test_max_steps_beyond_int32_is_rejected():
    for make in (lambda: make_mdp(max_steps=2**31),
                 lambda: make_tabular_mdp([[0]], [[0.0]], [[True]], [1.0], max_steps=2**31)):
        with pytest.raises(ValueError, match=r"^max_steps=2147483648 is invalid: must be an"
                                             r" integer >= 1 and <= 2147483647$"):
            make()
    assert int(make_mdp(max_steps=INT32_MAX).max_steps) == INT32_MAX


@pytest.mark.parametrize("args, name", [
    (["reproduce", "--seed", "4294967296"], "seed"),
    (["reproduce", "--seed", "99999999999999999999"], "seed"),
    (["reproduce", "--max-steps", "99999999999"], "max_steps"),
    (["run", "--task", "cruz2018", "--learners", "qlearning", "--explorers", "egreedy",
      "--max-steps", "99999999999"], "max_steps"),
])
def test_cli_out_of_range_is_one_line_and_writes_nothing(tmp_path, args, name):
    out = tmp_path / "out"
    done = run_cli(*args, "--out", str(out), "--seeds", "1", "--episodes", "2", "--quiet",
                   cache=tmp_path / "cache")
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"error: {name}=") and "is invalid" in lines[0], done.stderr
    assert "Traceback" not in done.stderr
    assert not out.exists() or not any(out.iterdir())


# ------------------------------------------------------------------ lazy imports
def test_import_and_version_do_not_import_jax():
    code = ("import sys, vdbejax, vdbejax.cli; assert 'jax' not in sys.modules, 'jax imported';"
            " vdbejax.run_grid; assert 'jax' in sys.modules; print(vdbejax.__version__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "run_grid" in dir(vdbejax)
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        vdbejax.nonexistent  # noqa: B018


def test_cli_main_with_an_argv_leaves_the_callers_garbage_collector_alone(tmp_path, monkeypatch):
    """Only the process's own command line (``main()`` without ``argv``) freezes the
    imported objects; a caller's process (this test run) keeps its collector."""
    import gc

    from vdbejax import cli
    from vdbejax.paper import reproduce as reproduce_module

    def stop(*args, **kwargs):
        raise ValueError("stopped=1 is invalid: this test runs nothing")

    monkeypatch.setattr(reproduce_module, "reproduce", stop)
    frozen = gc.get_freeze_count()
    assert cli.main(["reproduce", "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert gc.get_freeze_count() == frozen


