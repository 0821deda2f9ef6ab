"""The built wheel works alone: installed into a fresh virtual environment outside the
repository, its commands run from an empty folder (no source checkout to lean on: task
tables, plug-ins and defaults all come from the installed package).

The wheel is installed without dependency resolution and the fresh environment sees this
test environment's third-party packages (jax, numpy, matplotlib) through a ``.pth`` file:
what is checked is the wheel's own content, and the test stays offline and fast.
"""
from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """``bin/`` of a fresh virtual environment holding only the wheel."""
    work = tmp_path_factory.mktemp("wheel")
    # Built from a copy: setuptools leaves build/ in the source tree, whose stale modules
    # (deleted since) would otherwise go into the wheel; the checkout stays untouched.
    source = work / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".git", ".ci-venv", ".venv", "build", "dist", "*.egg-info", "out", "site",
        "__pycache__", ".pytest_cache"))
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps",
                            "--quiet", "-w", str(work / "dist")],
                           capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, built.stderr
    wheel = next((work / "dist").glob("vdbejax-*.whl"))
    env_dir = work / "env"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_path("
                              "'purelib'))"], capture_output=True, text=True,
                             check=True).stdout.strip()
    # The dependencies of this environment (its site-packages is not a site dir there, so
    # its editable install of vdbejax is not picked up).
    Path(purelib, "dependencies.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    done = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install",
                           "--no-deps", "--quiet", str(wheel)],
                          capture_output=True, text=True, timeout=600)
    if done.returncode != 0 and "no such option: --python" in done.stderr:  # pip < 22.3
        done = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet",
                               "--target", purelib, str(wheel)],
                              capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return env_dir / "bin"


def _run(bin_dir: Path, folder: Path, *args: str) -> subprocess.CompletedProcess:
    folder.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run([str(bin_dir / "vdbejax"), *args], cwd=folder, capture_output=True,
                          text=True, env=env, timeout=900)


def test_the_package_comes_from_the_wheel(installed, tmp_path):
    where = subprocess.run([str(installed / "python"), "-c",
                            "import vdbejax; print(vdbejax.__file__, vdbejax.__version__)"],
                           cwd=tmp_path, capture_output=True, text=True, check=True).stdout
    assert str(installed.parent) in where and str(ROOT) not in where


def test_reproduce_run_scale_and_ablate_from_an_empty_folder(installed, tmp_path):
    done = _run(installed, tmp_path / "a", "reproduce", "--out", "paper", "--seeds", "2",
                "--episodes", "50")
    assert done.returncode == 0, done.stderr
    for name in ("returns.npz", "summary.csv", "report.md", "fig3.png", "meta.json"):
        assert (tmp_path / "a" / "paper" / name).is_file(), name

    done = _run(installed, tmp_path / "b", "run", "--out", "mine", "--learners", "qlearning",
                "--explorers", "count_bonus,egreedy", "--seeds", "2", "--episodes", "20",
                "--quiet")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "b" / "mine" / "returns.npz").is_file()

    done = _run(installed, tmp_path / "c", "scale", "--out", "scaling", "--quick", "--quiet")
    assert done.returncode == 0, done.stderr
    assert any((tmp_path / "c" / "scaling").iterdir())

    done = _run(installed, tmp_path / "d", "ablate", "--help")
    assert done.returncode == 0 and "--notes" in done.stdout, done.stderr
    done = _run(installed, tmp_path / "d", "reproduce", "--out", "x", "--reading", "authors",
                "--seeds", "1", "--episodes", "2", "--no-figures")
    assert done.returncode == 0, done.stderr  # the authors' task table ships in the wheel
