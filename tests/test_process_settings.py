"""What importing vdbejax and calling its command line change in a caller's process: JAX's
persistent compilation cache (on unless configured or opted out) and nothing else; the
CLI's SIGTERM handler only in its own process."""
import os
import signal
import subprocess
import sys

import pytest

from vdbejax import cli

PROBE = ("import jax\n{before}\nimport vdbejax\n"
         "from vdbejax.envs.table_cleaning import make_mdp\nmake_mdp()\n"
         "print(jax.config.jax_compilation_cache_dir)\n")


def _cache_dir(tmp_path, before="", **env):
    clean = {k: v for k, v in os.environ.items()
             if k not in ("JAX_COMPILATION_CACHE_DIR", "VDBEJAX_CACHE_DIR",
                          "VDBEJAX_SET_JAX_CACHE_DIR")}
    done = subprocess.run([sys.executable, "-c", PROBE.format(before=before)],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env={**clean, **env})
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


def test_the_cache_is_on_by_default_in_python(tmp_path):
    folder = tmp_path / "cache"
    assert _cache_dir(tmp_path, VDBEJAX_CACHE_DIR=str(folder)) == str(folder)
    assert any(folder.iterdir())  # the environment's step program was stored


def test_opting_out_leaves_jax_alone(tmp_path):
    assert _cache_dir(tmp_path, VDBEJAX_CACHE_DIR="off") == "None"


def test_a_users_own_cache_is_kept(tmp_path):
    mine = str(tmp_path / "mine")
    assert _cache_dir(tmp_path, JAX_COMPILATION_CACHE_DIR=mine,
                      VDBEJAX_CACHE_DIR=str(tmp_path / "ours")) == mine
    before = f"jax.config.update('jax_compilation_cache_dir', {mine!r})"
    assert _cache_dir(tmp_path, before=before, VDBEJAX_CACHE_DIR=str(tmp_path / "ours")) == mine


def test_jax_imported_and_used_first_still_gets_the_cache(tmp_path):
    folder = tmp_path / "cache"
    before = "import jax.numpy as jnp; jnp.ones(3).sum().block_until_ready()"
    assert _cache_dir(tmp_path, before=before, VDBEJAX_CACHE_DIR=str(folder)) == str(folder)


def test_a_child_process_decides_afresh(tmp_path):
    """A parent's choice travels in JAX's environment variable: a child that opts out (or
    picks another folder) is not bound by it."""
    parent = ("import os, subprocess, sys\nimport vdbejax\n"
              "env = dict(os.environ, VDBEJAX_CACHE_DIR='off')\n"
              "code = 'import jax, vdbejax; print(jax.config.jax_compilation_cache_dir)'\n"
              "print(subprocess.run([sys.executable, '-c', code], env=env, text=True,"
              " capture_output=True).stdout.strip())\n")
    done = subprocess.run([sys.executable, "-c", parent], capture_output=True, text=True,
                          timeout=120, env=dict(os.environ, VDBEJAX_CACHE_DIR=str(tmp_path)))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "None"


@pytest.mark.skipif(not hasattr(signal, "SIGTERM"), reason="no SIGTERM")
def test_cli_main_with_argv_leaves_the_callers_sigterm_handler(tmp_path):
    def mine(signum, frame):
        pass

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        assert cli.main(["run", "--out", str(tmp_path), "--learners", "qlearning",
                         "--explorers", "egreedy", "--seeds", "1", "--episodes", "2",
                         "--quiet", "--no-figures"]) == 0
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_the_command_lines_own_handler_is_restored_on_exit(monkeypatch, tmp_path):
    seen = []
    monkeypatch.setattr(sys, "argv", ["vdbejax", "run", "--out", str(tmp_path), "--learners",
                                      "qlearning", "--explorers", "egreedy", "--seeds", "1",
                                      "--episodes", "2", "--quiet", "--no-figures"])
    original = cli.COMMANDS["run"]
    monkeypatch.setitem(cli.COMMANDS, "run", (original[0], lambda args: (
        seen.append((signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT))),
        original[1](args))))
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    monkeypatch.setattr("vdbejax.cli.paper_commands.freeze_imports", lambda: None)
    assert cli.main() == 0
    assert seen == [(cli._stop, cli._stop)]  # installed while the command ran
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_a_damaged_compilation_cache_entry_is_compiled_again_with_the_same_results(tmp_path):
    # The "damaged executable-cache entry": JAX's cache is the only program store
    # left; a damaged entry is recompiled (JAX warns), never run, and the numbers agree.
    import numpy as np

    cache = tmp_path / "cache"
    env = {**{k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"},
           "VDBEJAX_CACHE_DIR": str(cache)}

    def run(name):
        out = tmp_path / name
        done = subprocess.run(
            [sys.executable, "-m", "vdbejax", "run", "--out", str(out), "--learners",
             "qlearning", "--explorers", "egreedy", "--axis", "epsilon=0.1", "--seeds", "2",
             "--episodes", "10", "--quiet", "--no-figures"],
            capture_output=True, text=True, timeout=300, env=env)
        assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
        with np.load(out / "returns.npz") as data:
            return data["returns"], done.stderr

    clean, _ = run("clean")
    entries = [entry for entry in cache.iterdir() if entry.is_file()]
    assert entries
    for entry in entries:
        entry.write_bytes(b"\x00 damaged " * 8)
    again, err = run("damaged")
    assert np.array_equal(clean, again)
    assert "Error reading persistent compilation cache entry" in err
