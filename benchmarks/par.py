"""Par with numba-2t, measured in one run: the paper grid's warm vdbejax times beside
the harness's 2-thread Numba peer (``numba-2t``), optionally before and after a change.

    python -m benchmarks.par [--rounds 3] [--calls 4] [--threads 2] [--baseline DIR]
                             [--json-out F]

A first round, not counted, fills JAX's and Numba's caches. Then each round runs, one
after another (run nothing else on the machine meanwhile), for this tree and, with
``--baseline``, for another checkout of vdbejax (``git worktree add DIR REV``):

* ``harness``: that tree's :mod:`benchmarks.compare` vdbejax worker, a fresh process,
  caches warm;
* ``in-process``: :mod:`benchmarks.in_process` in a fresh process on that tree's
  vdbejax, ``run_grid`` called ``--calls`` times; calls 2 on are the warm in-process time,
  split into getting the programs (found by their trace key after the first call) and the rest
  (running);

and once per round ``numba-2t``: :mod:`benchmarks.compare`'s ``numba_parallel`` worker
(its wall includes loading its compiled loop from Numba's cache, as the harness reports
it). It prints every round and a table of medians with the ratios numba-2t / vdbejax
(above 1: vdbejax is faster; par is 1).
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks import compare

ROOT = compare.ROOT
#: What each round measures of a tree, in the table's order.
METRICS = ("harness", "in-process", "programs", "running")
LABELS = {"harness": "harness warm worker (fresh process)",
          "in-process": "run_grid again in one process (calls 2 on)",
          "programs": "… of which getting the programs",
          "running": "… the rest (running)"}


def _harness(kind: str, tree: Path, args: argparse.Namespace) -> float:
    """Wall seconds of one of ``tree``'s :mod:`benchmarks.compare` workers."""
    worker_args = argparse.Namespace(
        tmp=args.tmp, episodes=args.episodes, seeds=args.seeds, python_seeds=1,
        mushroom_seeds=1, threads=args.threads, jax_cache=args.jax_cache,
        mdp_factory=compare.DEFAULT_FACTORY, strategy="auto")
    return float(compare._spawn(kind, worker_args, root=tree)["wall"])


def _in_process(tree: Path, args: argparse.Namespace) -> list[dict[str, float]]:
    """Each call's wall and programs seconds: this tree's :mod:`benchmarks.in_process`
    run on ``tree``'s vdbejax."""
    env = compare.pythonpath_env(tree, {"VDBEJAX_CACHE_DIR": args.jax_cache})
    argv = ["in_process", "--calls", str(args.calls), "--seeds", str(args.seeds),
            "--episodes", str(args.episodes), "--threads", str(args.threads), "--json"]
    script = (f"import runpy, sys; sys.argv = {argv!r}; "
              f"runpy.run_path({str(ROOT / 'benchmarks' / 'in_process.py')!r}, "
              "run_name='__main__')")
    out = subprocess.run([sys.executable, "-c", script], check=True, env=env, cwd=tree,
                         capture_output=True, text=True).stdout
    return list(json.loads(out.strip().splitlines()[-1])["calls"])


def measure(trees: dict[str, Path], args: argparse.Namespace) -> dict[str, list[float]]:
    """Every round's times, keyed ``"<tree>:<metric>"`` and ``"numba-2t"`` (the first,
    warming round left out)."""
    for tree in trees.values():
        _harness("vdbejax", tree, args)
    _harness("numba_parallel", ROOT, args)
    rounds: dict[str, list[float]] = {"numba-2t": []}
    for r in range(args.rounds):
        said = []
        for name, tree in trees.items():
            times: dict[str, list[float]] = {metric: [] for metric in METRICS}
            times["harness"].append(_harness("vdbejax", tree, args))
            for call in _in_process(tree, args)[1:]:
                times["in-process"].append(call["wall"])
                times["programs"].append(call["programs"])
                times["running"].append(call["wall"] - call["programs"])
            for metric, values in times.items():
                rounds.setdefault(f"{name}:{metric}", []).extend(values)
            said.append(f"{name}: harness {times['harness'][0]:.2f} s, in-process "
                        + ", ".join(f"{w:.2f}" for w in times["in-process"]) + " s")
        rounds["numba-2t"].append(_harness("numba_parallel", ROOT, args))
        print(f"round {r + 1}: " + "; ".join(said)
              + f"; numba-2t {rounds['numba-2t'][-1]:.2f} s", flush=True)
    return rounds


def report(rounds: dict[str, list[float]]) -> str:
    """The table of medians, each with numba-2t / vdbejax (markdown); a column per tree."""
    median = {key: statistics.median(values) for key, values in rounds.items()}
    numba = median["numba-2t"]
    trees = list(dict.fromkeys(key.split(":")[0] for key in rounds if ":" in key))
    lines = ["| vdbejax | " + " | ".join(trees) + " |",
             "| --- |" + " --- |" * len(trees)]
    for metric in METRICS:
        cells = []
        for tree in trees:
            value = median[f"{tree}:{metric}"]
            cells.append(f"{value:.2f} s" if metric == "programs"
                         else f"{value:.2f} s ({numba / value:.2f}×)")
        lines.append(f"| {LABELS[metric]} | " + " | ".join(cells) + " |")
    lines.append(f"| numba-2t (harness worker) | {numba:.2f} s |" + " |" * (len(trees) - 1))
    lines += ["", "(×: numba-2t / vdbejax, medians; above 1 vdbejax is faster)"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3,
                        help="counted rounds, after one that warms the caches (default 3)")
    parser.add_argument("--calls", type=int, default=4,
                        help="run_grid calls per in-process round (at least 2)")
    parser.add_argument("--seeds", type=int, default=20, help="agents per setting (default 20)")
    parser.add_argument("--episodes", type=int, default=1000, help="default 1000")
    parser.add_argument("--threads", type=int, default=2,
                        help="threads of vdbejax and of numba-2t's loop (default 2)")
    parser.add_argument("--baseline", default=None,
                        help="another checkout of vdbejax, measured beside this one")
    parser.add_argument("--jax-cache", default=None,
                        help="JAX's cache directory (default: a new one, warmed first)")
    parser.add_argument("--json-out", default=None, help="also write every time as JSON")
    args = parser.parse_args(argv)
    for name in ("rounds", "seeds", "episodes", "threads"):
        if getattr(args, name) < 1:
            parser.error(f"--{name}={getattr(args, name)} is invalid: must be >= 1")
    if args.calls < 2:
        parser.error(f"--calls={args.calls} is invalid: must be >= 2 (call 1 is not warm)")
    trees = {"tip": ROOT}
    if args.baseline is not None:
        baseline = Path(args.baseline).resolve()
        if not (baseline / "vdbejax" / "__init__.py").is_file():
            parser.error(f"--baseline={args.baseline!r} is invalid: must be a checkout of "
                         "vdbejax (a folder with vdbejax/__init__.py)")
        trees = {"baseline": baseline, "tip": ROOT}
    with tempfile.TemporaryDirectory(prefix="vdbejax-par-") as tmp:
        args.tmp = tmp
        args.jax_cache = args.jax_cache or str(Path(tmp) / "jax-cache")
        rounds = measure(trees, args)
    print(report(rounds))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(rounds, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
