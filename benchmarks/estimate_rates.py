"""Check the constants of ``vdbejax.runs.estimate`` against real runs of ``vdbejax run``.

For each shape (settings × seeds × episodes) it runs ``vdbejax run`` in a fresh process,
then reports the training time (``meta.json``'s ``elapsed_seconds``), the rest of the
command's wall time (statistics, figures, files: what ``statistics_seconds`` forecasts),
and the estimate's two numbers beside them. The training bound must lie below the
training time; the statistics forecast should be within a factor of about two of the rest
less the process's start-up (imports and compiling, ≈ 5 s on the 2-core machine).

    python -m benchmarks.estimate_rates [--shapes 1x1x1000000,2x50x20000,46x20x1000]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from vdbejax.runs.estimate import estimate_run


def measure(settings: int, seeds: int, episodes: int) -> dict:
    axis = ",".join(f"{0.3 * (k + 1) / settings:.4g}" for k in range(settings))
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run"
        command = [sys.executable, "-m", "vdbejax", "run", "--out", str(out), "--learners",
                   "qlearning", "--explorers", "egreedy", "--axis", f"epsilon={axis}",
                   "--seeds", str(seeds), "--episodes", str(episodes), "--quiet"]
        started = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        wall = time.perf_counter() - started
        meta = json.loads((out / "meta.json").read_text())
    ran = len(meta["settings"])
    estimate = estimate_run(ran, seeds, episodes)
    return {"shape": f"{ran}x{seeds}x{episodes}", "wall": wall,
            "training": meta["elapsed_seconds"], "rest": wall - meta["elapsed_seconds"],
            "training_bound": estimate.training_seconds,
            "statistics_forecast": estimate.statistics_seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--shapes", default="1x1x1000000,2x50x20000,8x20x1000")
    args = parser.parse_args()
    print("| shape | wall s | training s | training bound s | rest s | statistics forecast s |")
    print("| --- | --- | --- | --- | --- | --- |")
    for shape in args.shapes.split(","):
        settings, seeds, episodes = (int(x) for x in shape.split("x"))
        row = measure(settings, seeds, episodes)
        print(f"| {row['shape']} | {row['wall']:.1f} | {row['training']:.1f} |"
              f" {row['training_bound']:.2f} | {row['rest']:.1f} |"
              f" {row['statistics_forecast']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
